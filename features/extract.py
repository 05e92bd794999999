"""From sessions to a feature matrix: timeseries x window x scalar features.

:class:`SessionFeatures` is a scikit-learn transformer: its input ``X`` is a list
of sessions (paths or :class:`schemas.Session`), its output one row of scalar
features per session, with readable names (``range(tau_3)``) from
``get_feature_names_out``. It composes with scalers and classifiers in a
``sklearn.pipeline.Pipeline``. :func:`feature_rows` computes it for many sessions
in parallel processes with a progress callback.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
from sklearn.base import BaseEstimator, TransformerMixin

from contactkit.errors import DATA_ERRORS, problem_text
from contactkit.features.timeseries import ChainConfig, TimeseriesChain, columns_of
from contactkit.features.window_features import WindowFeatures
from contactkit.robots.dynamics import ArmDynamics
from contactkit.schemas import Session
from contactkit.schemas.features import feature_table
from contactkit.schemas.session import read_session_meta
from contactkit.util.parallel import map_ordered, split_problems


class SessionFeatures(TransformerMixin, BaseEstimator, WindowFeatures):
    """Scalar features of each session's interaction window, as a scikit-learn
    transformer (see :class:`contactkit.features.window_features.WindowFeatures` for the
    parameters and the features)."""

    def fit(self, X: Iterable | None, y=None) -> SessionFeatures:
        """Nothing to learn from the sessions: checks the parameters, records the
        per-sample columns the features come from (``channels_``, so scikit-learn sees a
        fitted transformer) and returns self."""
        self._check()
        self.channels_ = self.channels()
        return self

    def transform(self, X: Iterable) -> np.ndarray:
        """Return the (n_sessions, n_features) matrix of scalar features."""
        self._check()
        return np.array([self.session_row(s)[0] for s in X])


@dataclass
class FeatureRows:
    """The scalar features of many sessions: the matrix ``X`` (sessions, features), the
    identifying values of each session (``info``, the keys of
    :data:`contactkit.schemas.features.ID_COLUMNS`), the feature names, and the files
    that failed."""

    X: np.ndarray
    info: list[dict]
    names: list[str]
    problems: list[tuple[str, str]]

    def __len__(self) -> int:
        """Return the number of sessions."""
        return len(self.info)

    def table(self, config: dict) -> pa.Table:
        """Return the rows as a scalar feature table for the feature configuration
        ``config`` (:func:`contactkit.schemas.features.feature_table`)."""
        return feature_table(self.info, self.X, self.names, config)


def _session_feature_row(job: tuple[str, dict, ArmDynamics | None]
                         ) -> tuple[str, tuple[np.ndarray, dict] | None, str | None]:
    path, params, dynamics = job
    extractor = SessionFeatures(**params)
    extractor.dynamics = dynamics  # an attribute, not a parameter: passed on beside them
    try:
        meta, _ = read_session_meta(path)
        values, names, window = extractor.session_row(path)
    except DATA_ERRORS as err:
        return Path(path).name, None, problem_text(err)
    bad = ~np.isfinite(np.asarray(values, dtype=float))
    if bad.any():
        return Path(path).name, None, (
            f"feature {names[int(np.argmax(bad))]} is not finite ({int(bad.sum())} of "
            f"{bad.size} features): values beyond what the robot can do?")
    info = {"file": Path(path).name, "session_id": meta.session_id, "action": meta.action,
           "condition": meta.condition, "pose": meta.pose, "target_pose": meta.target_pose,
           "link": meta.link, "operator": meta.operator, "speed_rad_s": meta.speed_rad_s,
           "window_start_s": window.start_s, "window_end_s": window.end_s,
           "window_method": window.method, "window_found": window.found,
           "planned_at_s": meta.planned_at_s}
    return Path(path).name, (np.asarray(values, dtype=float), info), None


def feature_rows(paths: Sequence[str | Path], extractor: SessionFeatures, workers: int = 1,
                 progress: Callable[[int, int], None] | None = None, *,
                 scheduler: str | None = None) -> FeatureRows:
    """Compute the scalar features of many sessions, in ``workers`` processes (or on the
    Dask ``scheduler``, see :func:`contactkit.util.parallel.map_ordered`); the rows come
    in the order of ``paths`` whatever the number of workers.

    Sessions that fail (bad file, window too short) are listed in ``problems``.
    """
    extractor.fit(None)
    params = extractor.get_params()
    names = list(extractor.get_feature_names_out())
    jobs = [(str(p), params, extractor.dynamics) for p in paths]
    rows, problems = split_problems(map_ordered(_session_feature_row, jobs, workers=workers,
                                                progress=progress, scheduler=scheduler))
    X = np.array([values for values, _ in rows]).reshape(len(rows), len(names))
    return FeatureRows(X, [info for _, info in rows], names, problems)


def timeseries_columns(session: Session, config: ChainConfig | None = None
                       ) -> dict[str, np.ndarray]:
    """Return every timeseries feature of every sample of a session, as flat columns:
    ``t``, then ``q_1``.., ``r_1``.., ``f_x``.., ``m_norm``
    (see :mod:`contactkit.features.timeseries`)."""
    chain = TimeseriesChain.for_session(session.meta, config, session.path)
    series = chain.compute(session.t, session.q, session.dq, session.tau)
    columns = {"t": session.t}
    for name, values in series.items():
        for label, column in zip(columns_of(name), values.T, strict=True):
            columns[label] = np.ascontiguousarray(column)
    return columns
