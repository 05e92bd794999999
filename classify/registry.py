"""The classifier kinds train, evaluate, predict and replay know, by name.

One line per built-in kind below; the kinds are declared, with their parameters, in
:mod:`contactkit.classify.svm_kinds` and :mod:`contactkit.classify.nn_kinds`, which (like
this module) import neither scikit-learn nor PyTorch. A lab's own kind is a module with
a :class:`contactkit.classify.kind.ModelKind` and one entry point in its package::

    [project.entry-points."contactkit.models"]
    my-kind = "mylab.kinds:MY_KIND"

or, in-process (a notebook, a test), :func:`register`.
"""

from __future__ import annotations

import importlib.metadata

from contactkit.classify.kind import ModelKind, ModelOptions
from contactkit.classify.nn_kinds import CNN, LSTM, MINIROCKET
from contactkit.classify.svm_kinds import PER_JOINT, SVM, THREE_JOINT
from contactkit.errors import InputError

ENTRY_POINT_GROUP = "contactkit.models"
_KINDS: dict[str, ModelKind] = {kind.name: kind for kind in (
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
    if kind.name in _KINDS and not replace and _KINDS[kind.name] is not kind:
        raise InputError(f"model kind {kind.name!r} is already registered")
    _KINDS[kind.name] = kind
    return kind


def unregister(name: str) -> None:
    """Remove a kind (for tests and notebooks that registered their own)."""
    _KINDS.pop(name, None)


def _load_entry_points() -> None:
    global _entry_points_loaded
    if _entry_points_loaded:
        return
    _entry_points_loaded = True
    for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        kind = entry.load()
        if not isinstance(kind, ModelKind):
            raise InputError(f"entry point {entry.name!r} of {ENTRY_POINT_GROUP} is not a "
                             f"ModelKind ({entry.value})")
        _KINDS.setdefault(kind.name, kind)


def kind_names() -> list[str]:
    """Return the names of every known kind, built-in first."""
    _load_entry_points()
    return list(_KINDS)


def get_kind(name: str) -> ModelKind:
    """Return the kind called ``name``, or raise InputError listing the known ones."""
    _load_entry_points()
    try:
        return _KINDS[name]
    except KeyError:
        raise InputError(f"unknown model {name!r} (expected one of "
                         f"{', '.join(_KINDS)})") from None


def searchable_kinds() -> list[str]:
    """Return the names of the kinds that declare a parameter with a search grid (the
    kinds ``classify gridsearch`` trains)."""
    return [name for name in kind_names() if any(p.grid for p in get_kind(name).params)]


def make_estimator(kind: str, feature_names: list[str], seed: int = 0, **params) -> object:
    """Return an unfitted estimator of the named kind, checked; ``params`` are the kind's
    own parameters (``c``, ``epochs``, ...; :attr:`ModelKind.params`)."""
    return get_kind(kind).estimator(ModelOptions(kind=kind, seed=seed, params=params),
                                    feature_names)
