"""The classifier kinds train, evaluate, predict and replay know, by name.

One line per built-in kind below; the kinds are declared, with their parameters, in
:mod:`contactkit.classify.kinds.svm` and :mod:`contactkit.classify.kinds.neural`, which (like
this module) import neither scikit-learn nor PyTorch. A lab's own kind is a module with
a :class:`contactkit.classify.kinds.kind.ModelKind` and one entry point in its package::

    [project.entry-points."contactkit.models"]
    my-kind = "mylab.kinds:MY_KIND"

or, in-process (a notebook, a test), :func:`register`. Listing the names
(:func:`kind_names`) imports no plugin: an entry point is loaded when its kind is first
asked for (:func:`get_kind`). The commands build their flags from every kind's declared
parameters, so a plugin's kind module should, like the built-in ones, declare without
importing heavy libraries.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from contactkit.classify.kinds.kind import ModelKind, ModelOptions
from contactkit.classify.kinds.neural import CNN, LSTM, MINIROCKET
from contactkit.classify.kinds.svm import PER_JOINT, SVM, THREE_JOINT
from contactkit.errors import InputError

if TYPE_CHECKING:
    import importlib.metadata

ENTRY_POINT_GROUP = "contactkit.models"
_KINDS: dict[str, ModelKind | importlib.metadata.EntryPoint] = {kind.name: kind for kind in (
    SVM,
    PER_JOINT,
    THREE_JOINT,
    CNN,
    LSTM,
    MINIROCKET,
)}
_entry_points_loaded = False
DEFAULT_KIND = SVM.name
"""The kind a command trains when none is named."""
DEFAULT_SEARCHED = LSTM.name
"""The kind the grid search and the augmentation experiment train when none is named."""


def register(kind: ModelKind, *, replace: bool = False) -> ModelKind:
    """Add a kind under its name; return it. A name already taken is refused unless
    ``replace``."""
    _load_entry_points()
    if kind.name in _KINDS and not replace and _resolve(kind.name) is not kind:
        raise InputError(f"model kind {kind.name!r} is already registered")
    _KINDS[kind.name] = kind
    return kind


def unregister(name: str) -> None:
    """Remove a kind (for tests and notebooks that registered their own)."""
    _KINDS.pop(name, None)


def _load_entry_points() -> None:
    """Add the names the ``contactkit.models`` entry points declare, without importing
    them (:func:`get_kind` does, on first use)."""
    global _entry_points_loaded
    if _entry_points_loaded:
        return
    _entry_points_loaded = True
    import importlib.metadata  # some 35 ms, paid only where plugins are looked for

    for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        _KINDS.setdefault(entry.name, entry)


def _resolve(name: str) -> ModelKind:
    """Return the kind registered as ``name``, loading its entry point on first use."""
    found = _KINDS[name]
    if isinstance(found, ModelKind):
        return found
    try:
        kind = found.load()
    except (ImportError, AttributeError) as err:
        raise InputError(f"model kind {name!r} ({found.value}) cannot be loaded: "
                         f"{err}") from err
    if not isinstance(kind, ModelKind):
        raise InputError(f"entry point {found.name!r} of {ENTRY_POINT_GROUP} is not a "
                         f"ModelKind ({found.value})")
    _KINDS[name] = kind
    return kind


def kind_names() -> list[str]:
    """Return the names of every known kind, built-in first (loading no plugin)."""
    _load_entry_points()
    return list(_KINDS)


def get_kind(name: str) -> ModelKind:
    """Return the kind called ``name`` (a plugin's loaded on first use), or raise
    InputError listing the known ones."""
    _load_entry_points()
    if name not in _KINDS:
        raise InputError(f"unknown model {name!r} (expected one of {', '.join(_KINDS)})")
    return _resolve(name)


def searchable_kinds() -> list[str]:
    """Return the names of the kinds that declare a parameter with a search grid (the
    kinds ``classify gridsearch`` trains)."""
    found = []
    for name in kind_names():
        try:
            kind = get_kind(name)
        except InputError:  # a plugin that cannot be loaded has no grid to offer
            continue
        if any(p.grid for p in kind.params):
            found.append(name)
    return found


def make_estimator(kind: str, feature_names: list[str], seed: int = 0, **params) -> object:
    """Return an unfitted estimator of the named kind, checked; ``params`` are the kind's
    own parameters (``c``, ``epochs``, ...; :attr:`ModelKind.params`)."""
    return get_kind(kind).estimator(ModelOptions(kind=kind, seed=seed, params=params),
                                    feature_names)
