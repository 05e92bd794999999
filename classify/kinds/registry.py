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

from contactkit.classify.kinds.kind import ModelKind, ModelOptions
from contactkit.classify.kinds.neural import CNN, LSTM, MINIROCKET
from contactkit.classify.kinds.svm import PER_JOINT, SVM, THREE_JOINT
from contactkit.errors import InputError
from contactkit.util.plugins import Registry

ENTRY_POINT_GROUP = "contactkit.models"


def _check(name: str, target: str, loaded: object) -> ModelKind:
    if not isinstance(loaded, ModelKind):
        raise InputError(f"entry point {name!r} of {ENTRY_POINT_GROUP} is not a "
                         f"ModelKind ({target})")
    return loaded


REGISTRY: Registry[ModelKind] = Registry(
    "model", ENTRY_POINT_GROUP,
    {kind.name: kind for kind in (SVM, PER_JOINT, THREE_JOINT, CNN, LSTM, MINIROCKET)},
    _check)
"""The classifier kinds by name (:class:`contactkit.util.plugins.Registry`)."""
DEFAULT_KIND = SVM.name
"""The kind a command trains when none is named."""
DEFAULT_SEARCHED = LSTM.name
"""The kind the grid search and the augmentation experiment train when none is named."""


def register(kind: ModelKind, *, replace: bool = False) -> ModelKind:
    """Add a kind under its name; return it. A name already taken is refused unless
    ``replace``."""
    return REGISTRY.register(kind.name, kind, replace=replace)


def unregister(name: str) -> None:
    """Remove a kind (for tests and notebooks that registered their own)."""
    REGISTRY.unregister(name)


def kind_names() -> list[str]:
    """Return the names of every known kind, built-in first (loading no plugin)."""
    return REGISTRY.names()


def get_kind(name: str) -> ModelKind:
    """Return the kind called ``name`` (a plugin's loaded on first use), or raise
    InputError listing the known ones."""
    return REGISTRY.get(name)


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
