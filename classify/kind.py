"""What a classifier kind is: the pieces train, evaluate, predict and replay need.

A :class:`ModelKind` names its input (an :class:`InputKind`: scalar features of the
interaction window, or timeseries grids), a factory for the unfitted estimator, its
file format, the types its files may build, and its online predictor. The kinds
themselves live beside their estimators (``models.py``, ``nn.py``) and are listed in
:mod:`contactkit.classify.registry`; a lab adds one from its own package through the
``contactkit.models`` entry-point group.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from contactkit.schemas import InputError
from contactkit.util.progress import ProgressCallback


@dataclass(frozen=True)
class ModelOptions:
    """Everything a kind may need to build its input and its estimator.

    ``timeseries`` and ``window`` default to the kind's own choice (None). ``c`` is
    the SVM regularisation; ``epochs``, ``depth``, ``width`` and ``dropout`` size the
    networks, ``patience`` is their early stopping (epochs without a better validation
    loss) and ``device`` where they train (auto, cpu or cuda); ``steps`` is the length
    of a grid; ``window_s`` is in seconds.
    """

    kind: str = "svm"
    timeseries: tuple[str, ...] | None = None
    scalars: tuple[str, ...] = ("range",)
    window: str | None = None
    window_s: float = 0.5
    steps: int = 300
    c: float = 1.0
    seed: int = 0
    epochs: int = 100
    depth: int | None = None
    width: float = 2.0
    dropout: float = 0.02
    patience: int = 20
    device: str = "cpu"


class SessionTransformer(Protocol):
    """A scikit-learn transformer from sessions to one model input each
    (:class:`contactkit.features.extract.SessionFeatures`,
    :class:`contactkit.classify.grids.SessionGrids`)."""

    timeseries: Sequence[str]
    window_s: float

    def config(self) -> dict: ...

    def get_feature_names_out(self, input_features=None) -> np.ndarray: ...

    def session_row(self, session) -> tuple[np.ndarray, list[str], Any]: ...

    def online_row(self, t: np.ndarray, values: np.ndarray, k: int) -> np.ndarray: ...

    def window_row(self, t: np.ndarray, values: np.ndarray, window: Any,
                   path: Any = None) -> np.ndarray: ...

    @property
    def window_spec(self) -> Any: ...

    def chain_config(self): ...


@dataclass(frozen=True)
class InputKind:
    """How a kind sees a session.

    ``name`` is stored in model files (``input``) and ``meta_key`` holds the
    transformer's configuration there; ``build(options, kind)`` returns the
    configured transformer, ``from_config`` rebuilds it from a model file, and
    ``load(sources, transformer, workers, progress)`` returns the
    :class:`contactkit.classify.data.FeatureSet` of dataset directories.
    """

    name: str
    meta_key: str
    build: Callable[[ModelOptions, ModelKind], SessionTransformer]
    from_config: Callable[[dict], SessionTransformer]
    load: Callable[[Sequence[Path], SessionTransformer, int, ProgressCallback | None], Any]


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


def no_checks(options: ModelOptions) -> None:
    """Accept any options."""


def predict_proba_of(estimator) -> Callable[[np.ndarray], np.ndarray]:
    """Return the estimator's own ``predict_proba`` (the default online predictor)."""
    return estimator.predict_proba


@dataclass(frozen=True)
class ModelKind:
    """One classifier kind (see the module docstring).

    ``make(options, feature_names)`` returns an unfitted scikit-learn classifier;
    ``check(options)`` raises :class:`InputError` for options the kind cannot use;
    ``requires()`` raises one if an optional library is missing; ``online(estimator)``
    returns the function replay calls on each window; ``trusted_types`` are the
    classes its skops files may build beyond scikit-learn's and numpy's;
    ``parallel_fits`` says evaluation splits are worth separate processes.
    """

    name: str
    summary: str
    input: InputKind
    make: Callable[[ModelOptions, list[str]], Any]
    file_format: ModelFormat
    default_timeseries: tuple[str, ...] = ("dq", "tau", "r")
    default_window: str = "difference"
    check: Callable[[ModelOptions], None] = no_checks
    requires: Callable[[], None] = no_requirements
    online: Callable[[Any], Callable[[np.ndarray], np.ndarray]] = predict_proba_of
    trusted_types: tuple[str, ...] = field(default=())
    parallel_fits: bool = False

    def transformer(self, options: ModelOptions) -> SessionTransformer:
        """Return this kind's input transformer configured by ``options``, checked."""
        transformer = self.input.build(options, self)
        transformer.fit(None)
        return transformer

    def check_options(self, options: ModelOptions) -> None:
        """Raise InputError now, before any data is read, for unusable options or a
        missing optional library."""
        self.requires()
        if options.seed < 0:
            raise InputError(f"seed must be non-negative, got {options.seed}")
        self.check(options)
