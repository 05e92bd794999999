"""What a classifier kind is: the pieces train, evaluate, predict and replay need.

A :class:`ModelKind` names its input (an :class:`InputKind`: scalar features of the
interaction window, or timeseries grids), a factory for the unfitted estimator, its
own parameters (declarations with constraints, :class:`contactkit.util.params.Param`),
its file format, the types its files may build, and its online predictor. The kinds
are declared beside their estimators (``svm_kinds.py`` for ``models.py``,
``nn_kinds.py`` for ``networks.py`` and ``nn.py``), without importing scikit-learn or
PyTorch, and listed in :mod:`contactkit.classify.kinds.registry`; a lab adds one from its own
package through the ``contactkit.models`` entry-point group.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from contactkit.errors import InputError
from contactkit.util.params import Interval, Param, check_params

if TYPE_CHECKING:
    import numpy as np

    from contactkit.util.progress import ProgressCallback

SEED = Param("seed", int, 0, "Random seed (same seed, same result).",
             constraints=(Interval(0, None),))
"""The seed every kind takes: it fixes initialisation, shuffling and evaluation splits."""


@dataclass(frozen=True)
class ModelOptions:
    """What a kind builds its input and its estimator from.

    ``timeseries`` and ``window`` default to the kind's own choice (None); ``scalars``
    are the scalar features of the features input, ``window_s`` the window length [s]
    and ``steps`` the time steps of a grid input. ``params`` are the kind's own
    parameters by name (:attr:`ModelKind.params`: ``c`` of an SVM, ``epochs`` of a
    network); one not given takes its declared default.
    """

    kind: str
    timeseries: tuple[str, ...] | None = None
    scalars: tuple[str, ...] = ("range",)
    window: str | None = None
    window_s: float = 0.5
    steps: int = 300
    seed: int = 0
    params: Mapping[str, Any] = field(default_factory=dict)


def lazy(target: str) -> Callable[..., Any]:
    """Return a function that imports ``module:attribute`` on its first call and calls it,
    so a kind's declaration names its heavy parts (estimators, file formats, online
    predictors) without importing scikit-learn or PyTorch."""
    module, _, attribute = target.partition(":")

    def call(*args: Any, **kwargs: Any) -> Any:
        return getattr(importlib.import_module(module), attribute)(*args, **kwargs)

    call.__qualname__ = call.__name__ = attribute
    call.__doc__ = f"Call {target} (imported on first use)."
    return call


class SessionTransformer(Protocol):
    """A scikit-learn transformer from sessions to one model input each
    (:class:`contactkit.features.extract.SessionFeatures`,
    :class:`contactkit.classify.grids.SessionGrids`)."""

    timeseries: Sequence[str]
    window_s: float

    def fit(self, X: Any, y: Any = None) -> Any: ...

    def config(self) -> dict: ...

    def get_feature_names_out(self, input_features=None) -> np.ndarray: ...

    def session_row(self, session) -> tuple[np.ndarray, list[str], Any]: ...

    def online_rows(self, t: np.ndarray, values: np.ndarray, ends: np.ndarray | list[int]
                    ) -> np.ndarray: ...

    def window_row(self, t: np.ndarray, values: np.ndarray, window: Any,
                   path: Any = None) -> np.ndarray: ...

    @property
    def window_spec(self) -> Any: ...

    def chain_config(self): ...


class InputLoader(Protocol):
    """How an input kind loads dataset directories (see :class:`InputKind`)."""

    def __call__(self, sources: Sequence[Path], transformer: SessionTransformer,
                 workers: int = 1, progress: ProgressCallback | None = None, *,
                 scheduler: str | None = None) -> Any:
        """Return the FeatureSet of ``sources``, computed in ``workers`` processes or on
        the Dask ``scheduler``."""


@dataclass(frozen=True)
class InputKind:
    """How a kind sees a session.

    ``name`` is stored in model files (``input``) and ``meta_key`` holds the
    transformer's configuration there; ``build(options, kind)`` returns the
    configured transformer, ``from_config`` rebuilds it from a model file, and
    ``load(sources, transformer, workers, progress, scheduler=None)`` returns the
    :class:`contactkit.classify.data.FeatureSet` of dataset directories, computed in
    ``workers`` processes or on the Dask ``scheduler``. ``online_config``, where given,
    rebuilds the same input as a lighter object for online use (a replay, live
    events) that need not be a scikit-learn estimator; None: ``from_config``.
    """

    name: str
    meta_key: str
    build: Callable[[ModelOptions, ModelKind], SessionTransformer]
    from_config: Callable[[dict], SessionTransformer]
    load: InputLoader
    online_config: Callable[[dict], SessionTransformer] | None = None

    def online_from_config(self, config: dict) -> SessionTransformer:
        """Return the input for online use that a model file's configuration describes."""
        return (self.online_config or self.from_config)(config)


@dataclass(frozen=True)
class ModelFormat:
    """A model file format: its suffix, a writer ``save(path, estimator, meta,
    sample_shape, overwrite)`` and a reader ``load(path, trusted_types) -> (estimator,
    meta)``, where ``trusted_types(meta)`` names the types the file's kind may build (a
    format that builds no Python objects ignores it)."""

    name: str
    suffix: str
    save: Callable[[Path, object, dict, tuple[int, ...], bool], Path]
    load: Callable[[Path, Callable[[dict], Sequence[str]]], tuple[object, dict]]


def no_requirements() -> None:
    """Nothing to check: the kind needs only the base install."""


def no_checks(params: dict[str, Any]) -> None:
    """Accept any parameters that meet their declarations."""


def predict_proba_of(estimator) -> Callable[[np.ndarray], np.ndarray]:
    """Return the estimator's own ``predict_proba`` (the default online predictor)."""
    return estimator.predict_proba


@dataclass(frozen=True)
class ModelKind:
    """One classifier kind (see the module docstring).

    ``params`` declare the kind's own parameters, with their types, defaults, help and
    constraints (as scikit-learn's ``_parameter_constraints``); the command line's
    options and the grid search's space are generated from them, and they are checked
    here before any data is read. Every kind takes :data:`SEED` besides.
    ``make(options, feature_names)`` returns an unfitted scikit-learn classifier from
    options whose ``params`` are complete and checked; ``check(params)`` raises
    :class:`InputError` for what a declaration cannot say (a GPU that is missing);
    ``requires()`` raises one if an optional library is missing; ``online(estimator)``
    returns the function replay calls on each window; ``trusted_types`` are the classes
    its skops files may build beyond scikit-learn's and numpy's; ``parallel_fits`` says
    evaluation splits are worth separate processes. A declaration module imports
    neither scikit-learn nor PyTorch: ``make``, ``online`` and the file format's
    functions import them when called (see :func:`lazy`).
    """

    name: str
    summary: str
    input: InputKind
    make: Callable[[ModelOptions, list[str]], Any]
    file_format: ModelFormat
    params: tuple[Param, ...] = ()
    default_timeseries: tuple[str, ...] = ("dq", "tau", "r")
    default_window: str = "difference"
    check: Callable[[dict[str, Any]], None] = no_checks
    requires: Callable[[], None] = no_requirements
    online: Callable[[Any], Callable[[np.ndarray], np.ndarray]] = predict_proba_of
    trusted_types: tuple[str, ...] = field(default=())
    parallel_fits: bool = False

    def transformer(self, options: ModelOptions) -> SessionTransformer:
        """Return this kind's input transformer configured by ``options``, checked."""
        transformer = self.input.build(options, self)
        transformer.fit(None)
        return transformer

    def check_options(self, options: ModelOptions) -> ModelOptions:
        """Return ``options`` with every parameter of the kind (declared defaults for those
        not given), checked; raise InputError now, before any data is read, for an
        unusable value, a parameter the kind does not declare, or a missing optional
        library."""
        if options.kind != self.name:
            raise InputError(f"options for a {options.kind} model given to {self.name}")
        self.requires()
        SEED.check(options.seed, f"model {self.name!r}")
        params = check_params(self.params, options.params, f"model {self.name!r}")
        self.check(params)
        return replace(options, params=params)

    def estimator(self, options: ModelOptions, feature_names: Sequence[str]) -> Any:
        """Return the unfitted estimator ``options`` describe, for inputs with columns (or
        grid channels) ``feature_names``, after :meth:`check_options`."""
        return self.make(self.check_options(options), list(feature_names))
