"""The classifier kinds train, evaluate, predict and replay know, by name.

One line per built-in kind below. A lab's own kind is a module with a
:class:`contactkit.classify.kind.ModelKind` and one entry point in its package::

    [project.entry-points."contactkit.models"]
    my-kind = "mylab.kinds:MY_KIND"

or, in-process (a notebook, a test), :func:`register`.
"""

from __future__ import annotations

import importlib
import importlib.metadata

from contactkit.classify.kind import ModelKind, ModelOptions
from contactkit.schemas import InputError

ENTRY_POINT_GROUP = "contactkit.models"
# Each kind is imported when it is first asked for (get_kind): listing the names, as the
# command line does for its --model choices, imports neither scikit-learn nor torch nor
# any plugin. A value is a kind, or where to load it from ("module:ATTR", or an entry
# point whose name is the kind's name).
_KINDS: dict[str, ModelKind | str | importlib.metadata.EntryPoint] = {
    "svm": "contactkit.classify.svm_kinds:SVM",
    "per-joint": "contactkit.classify.svm_kinds:PER_JOINT",
    "three-joint": "contactkit.classify.svm_kinds:THREE_JOINT",
    "cnn": "contactkit.classify.nn:CNN",
    "lstm": "contactkit.classify.nn:LSTM",
    "minirocket": "contactkit.classify.nn:MINIROCKET",
}
_entry_points_loaded = False


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
    for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        _KINDS.setdefault(entry.name, entry)


def _resolve(name: str) -> ModelKind:
    """Return the kind registered as ``name``, importing it on first use."""
    found = _KINDS[name]
    if isinstance(found, ModelKind):
        return found
    if isinstance(found, str):
        module, _, attr = found.partition(":")
        kind = getattr(importlib.import_module(module), attr)
    else:
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
    """Return the names of every known kind, built-in first (importing none of them)."""
    _load_entry_points()
    return list(_KINDS)


def get_kind(name: str) -> ModelKind:
    """Return the kind called ``name`` (imported on first use), or raise InputError
    listing the known ones."""
    _load_entry_points()
    if name not in _KINDS:
        raise InputError(f"unknown model {name!r} (expected one of {', '.join(_KINDS)})")
    return _resolve(name)


def make_estimator(kind: str, feature_names: list[str], **options) -> object:
    """Return an unfitted estimator of the named kind; ``options`` are
    :class:`contactkit.classify.kind.ModelOptions` fields (``c``, ``seed``, ``epochs``, ...)."""
    model_kind = get_kind(kind)
    settings = ModelOptions(kind=kind, **options)
    model_kind.check_options(settings)
    return model_kind.make(settings, list(feature_names))
