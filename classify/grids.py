"""Timeseries grids: the raw-window input of the networks (thesis section 5.2).

A grid is channels x time: the chosen timeseries features (default for the CNN:
joint positions, velocities and torques, 21 channels; for the LSTM: velocities,
torques and residuals) inside the interaction window, resampled by linear
interpolation onto ``steps`` equally spaced instants (default 300: a 0.5 s window
at 600 Hz, as the thesis's ~21 x 300). The thesis zero-padded windows to the longest
one; resampling does the same job for sessions of different or irregular rates
and keeps one network usable online at any rate.

Each channel is taken relative to its mean over the ``baseline_s`` before the
window (default 0.1 s), so a grid shows what changed, not where the arm stands:
absolute positions and gravity-loaded torques identify the pose, and a network fed
them learns the poses it was trained on (leaving poses A and B out of the static
set in turn, a depth-1 LSTM on dq, tau and r went from 54 % to 76 % balanced
accuracy with this). ``baseline_s=0`` keeps the thesis's absolute values.

Augmentation (thesis section 5.3.5) happens here, before the observer runs:
zero-mean Gaussian torque noise of ``noise_multiplier`` times a per-joint baseline
[Nm], and the observer gain scaled by ``gain_factor`` (0.9 and 1.1 double a set).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin

from contactkit.classify.data import FeatureSet
from contactkit.classify.kinds.inputs import CNN_INPUT
from contactkit.classify.kinds.kind import ModelKind, ModelOptions
from contactkit.errors import DATA_ERRORS, problem_text
from contactkit.features.chain_cache import chain_series
from contactkit.features.observer import DEFAULT_GAIN, ObserverConfig
from contactkit.features.timeseries import ChainConfig, TimeseriesChain, columns_of, expand
from contactkit.features.windows import METHODS, Window, WindowSpec, find_window
from contactkit.robots.dynamics import ArmDynamics
from contactkit.schemas import InputError, Session, read_session
from contactkit.schemas.dataset import session_files
from contactkit.util.parallel import map_ordered, split_problems
from contactkit.util.params import Choice, Interval, Param, check_names, check_settings


@dataclass(frozen=True)
class GridSpec:
    """Which timeseries, which window, how many time steps."""

    timeseries: tuple[str, ...] = CNN_INPUT
    window: str = "planned"
    window_s: float = 0.5
    steps: int = 300
    gain: float = DEFAULT_GAIN
    baseline_s: float = 0.1

    def channels(self) -> list[str]:
        """Return the channel names, for example ``tau_3``."""
        return [c for name in expand(list(self.timeseries)) for c in columns_of(name)]

    def as_dict(self) -> dict:
        """Return the spec as JSON-ready values."""
        doc = asdict(self)
        doc["timeseries"] = list(self.timeseries)
        return doc


@dataclass(frozen=True)
class Augmentation:
    """Torque noise (multiple of ``noise_nm`` per joint) and observer-gain factor."""

    noise_multiplier: float = 0.0
    noise_nm: tuple[float, ...] = (0.0,) * 7
    gain_factor: float = 1.0
    seed: int = 0


def resample_window(t: np.ndarray, values: np.ndarray, start_s: float, length_s: float,
                    steps: int) -> np.ndarray:
    """Return ``values`` (N, C) interpolated at ``steps`` instants from ``start_s`` over
    ``length_s`` [s], as (C, steps); instants outside the recording are zero."""
    grid_t = start_s + np.arange(steps) * (length_s / steps)
    out = np.empty((values.shape[1], steps))
    for c in range(values.shape[1]):
        out[c] = np.interp(grid_t, t, values[:, c], left=0.0, right=0.0)
    return out


def window_grid(t: np.ndarray, values: np.ndarray, start_s: float, spec: GridSpec
                ) -> np.ndarray:
    """Return the grid (channels x ``spec.steps``) of ``values`` (N, C, in the units of
    each channel) over the window from ``start_s`` [s].

    With ``spec.baseline_s`` > 0 every channel is relative to its mean over the
    samples in ``[start_s - baseline_s, start_s)`` (its value at ``start_s`` when
    none lie there), and instants outside the recording are zero change.
    """
    if spec.baseline_s > 0:
        before = (t >= start_s - spec.baseline_s) & (t < start_s)
        if before.any():
            baseline = values[before].mean(axis=0)
        else:
            baseline = np.array([np.interp(start_s, t, values[:, c])
                                 for c in range(values.shape[1])])
        values = values - baseline
    return resample_window(t, values, start_s, spec.window_s, spec.steps)


def session_grid(session: Session, spec: GridSpec,
                 augmentation: Augmentation | None = None,
                 dynamics: ArmDynamics | None = None) -> np.ndarray:
    """Return one session's grid (channels x steps)."""
    return session_grid_and_window(session, spec, augmentation, dynamics)[0]


def session_grid_and_window(session: Session, spec: GridSpec,
                            augmentation: Augmentation | None = None,
                            dynamics: ArmDynamics | None = None
                            ) -> tuple[np.ndarray, Window]:
    """Return one session's grid (channels x steps) and the window it covers, the
    model-based channels with the identified ``dynamics`` (``--dynamics``; None: those
    the session carries, else the nominal model)."""
    session = session.complete()
    tau = session.tau
    gain = spec.gain
    if augmentation is not None:
        rng = np.random.default_rng([augmentation.seed,
                                     zlib.crc32(session.meta.session_id.encode())])
        tau = tau + rng.normal(size=tau.shape) * np.asarray(augmentation.noise_nm) * \
            augmentation.noise_multiplier
        gain *= augmentation.gain_factor
    names = expand(list(spec.timeseries))
    config = ChainConfig(ObserverConfig(gain=gain), dynamics=dynamics)
    needed = list(dict.fromkeys([*names, "tau"]))
    if augmentation is None:
        series = chain_series(session, config, needed)
    else:
        series = TimeseriesChain.for_session(session.meta, config, session.path).compute(
            session.t, session.q, session.dq, tau, needed)
    planned = session.meta.planned_at_s
    if planned is None:
        raise InputError("session has no planned interaction time", session.path)
    window = find_window(session.t, planned, WindowSpec(spec.window, spec.window_s),
                         series["tau"])
    values = np.column_stack([series[n] for n in names])
    return window_grid(session.t, values, window.start_s, spec), window


class SessionGrids(TransformerMixin, BaseEstimator):
    """A scikit-learn transformer from sessions (paths or :class:`Session`) to their
    grids, shape (sessions, channels, steps); the parameters are :class:`GridSpec`'s.
    ``dynamics`` (an attribute, not a parameter: a model file does not carry it) is the
    arm's identified dynamics the chain uses (``--dynamics``), None for those each
    session carries, else the nominal model."""

    dynamics: ArmDynamics | None = None

    def __init__(self, timeseries: Sequence[str] = CNN_INPUT, window: str = "planned",
                 window_s: float = 0.5, steps: int = 300, gain: float = DEFAULT_GAIN,
                 baseline_s: float = 0.1) -> None:
        self.timeseries = timeseries
        self.window = window
        self.window_s = window_s
        self.steps = steps
        self.gain = gain
        self.baseline_s = baseline_s

    @property
    def spec(self) -> GridSpec:
        """The parameters as a :class:`GridSpec`."""
        return GridSpec(tuple(self.timeseries), self.window, float(self.window_s),
                        int(self.steps), float(self.gain), float(self.baseline_s))

    def fit(self, X, y=None) -> SessionGrids:
        """Nothing to learn from the sessions: checks the parameters, records the grid's
        channels (``channels_``, so scikit-learn sees a fitted transformer) and returns
        self."""
        try:
            self.spec.channels()
        except KeyError as err:
            raise InputError(f"unknown timeseries feature {err.args[0]!r}") from err
        if self.steps < 2:
            raise InputError(f"a grid needs at least 2 time steps, got {self.steps}")
        WindowSpec(self.window, self.window_s)
        self.channels_ = self.spec.channels()
        return self

    def config(self) -> dict:
        """Return the parameters as JSON-ready values (stored with models)."""
        return self.spec.as_dict()

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        """Return the channel names, for example ``tau_3``."""
        return np.array(self.spec.channels(), dtype=object)

    def channels(self) -> list[str]:
        """Return the per-sample columns of a grid, for example ``tau_3``."""
        return self.spec.channels()

    def chain_config(self) -> ChainConfig:
        """The feature-chain settings."""
        return ChainConfig(ObserverConfig(gain=self.gain), dynamics=self.dynamics)

    def transform(self, X) -> np.ndarray:
        """Return the (sessions, channels, steps) grids."""
        return np.stack([self.session_row(s)[0] for s in X])

    @property
    def window_spec(self) -> WindowSpec:
        """The window settings as a :class:`WindowSpec` (found on the torque)."""
        return WindowSpec(self.window, self.window_s)

    def window_row(self, t: np.ndarray, values: np.ndarray, window: Window,
                   path: str | Path | None = None) -> np.ndarray:
        """Return the grid of ``window`` from per-sample ``values`` (N, channels) at times
        ``t`` [s] around it (from ``baseline_s`` before it to its end)."""
        return window_grid(t, values, window.start_s, self.spec)

    def session_row(self, session: Session | str | Path
                    ) -> tuple[np.ndarray, list[str], Window]:
        """Return (grid, channel names, window) for one session."""
        if not isinstance(session, Session):
            session = read_session(session)
        grid, window = session_grid_and_window(session, self.spec, dynamics=self.dynamics)
        return grid, self.spec.channels(), window

    def online_rows(self, t: np.ndarray, values: np.ndarray, ends: np.ndarray | list[int]
                    ) -> np.ndarray:
        """Return the grids (len(ends), ...) of the ``window_s`` seconds ending at each
        sample of ``ends``, from per-sample ``values`` (N, channels) at times ``t`` [s];
        a grid uses samples up to its end (and the baseline before its window) only."""
        spec = self.spec
        grids = []
        for k in np.asarray(ends, dtype=np.intp).tolist():
            first = int(np.searchsorted(t, t[k] - spec.window_s, side="right"))
            start = int(np.searchsorted(t, t[k] - spec.window_s - spec.baseline_s,
                                        side="left"))
            start = max(0, min(start, first) - 1)
            grids.append(window_grid(t[start:k + 1], values[start:k + 1],
                                     t[k] - spec.window_s, spec))
        return np.stack(grids)


def _grid_job(job: tuple[str, GridSpec, Augmentation | None, ArmDynamics | None]
              ) -> tuple[str, tuple[np.ndarray, dict] | None, str | None]:
    path, spec, augmentation, dynamics = job
    try:
        session = read_session(path)
        meta = session.meta
        info = {"file": Path(path).name, "session_id": meta.session_id, "action": meta.action,
                "condition": meta.condition, "pose": meta.pose, "target_pose": meta.target_pose,
                "operator": meta.operator,
                "speed_rad_s": np.nan if meta.speed_rad_s is None else meta.speed_rad_s}
        return Path(path).name, (session_grid(session, spec, augmentation, dynamics), info), None
    except DATA_ERRORS as err:
        return Path(path).name, None, problem_text(err)


def session_paths(sources: Sequence[Path]) -> list[str]:
    """Return the session files of the dataset directories ``sources``; an InputError
    names a source that is not a directory, or says that none holds a session."""
    paths = []
    for source in sources:
        if not Path(source).is_dir():
            raise InputError("no such dataset directory (networks read sessions, not "
                             "feature tables)", source)
        paths += [str(p) for p in session_files(source)]
    if not paths:
        raise InputError("no session files (*.parquet) in these directories")
    return paths


def load_grids(sources: Sequence[Path], spec: GridSpec, workers: int = 1,
               augmentation: Augmentation | None = None,
               progress: Callable[[int, int], None] | None = None, *,
               scheduler: str | None = None,
               dynamics: ArmDynamics | None = None) -> FeatureSet:
    """Compute the grids of every session of the dataset directories (in ``workers``
    processes or on the Dask ``scheduler``), with the identified ``dynamics`` (None:
    those each session carries, else the nominal model).

    Returns a :class:`contactkit.classify.data.FeatureSet` whose X is (sessions, channels, steps),
    so labels, groups and the limited context work as for scalar features.
    """
    jobs = [(p, spec, augmentation, dynamics) for p in session_paths(sources)]
    good, problems = split_problems(map_ordered(_grid_job, jobs, workers=workers,
                                                progress=progress, scheduler=scheduler))
    if not good:
        raise InputError("no session could be processed")
    info = {key: np.array([r[1][key] for r in good],
                          dtype=float if key == "speed_rad_s" else object)
            for key in good[0][1]}
    return FeatureSet(np.stack([r[0] for r in good]), spec.channels(), info, spec.as_dict(),
                      problems)


def grids_for(options: ModelOptions, kind: ModelKind) -> SessionGrids:
    """Return the grid input ``options`` describe, with the kind's defaults."""
    return SessionGrids(timeseries=tuple(options.timeseries or kind.default_timeseries),
                        window=options.window or kind.default_window,
                        window_s=options.window_s, steps=options.steps)


GRID_SETTINGS = (
    Param("timeseries", list, list(GridSpec.timeseries)),
    Param("window", str, GridSpec.window, constraints=(Choice(METHODS),)),
    Param("window_s", float, GridSpec.window_s, unit="s",
          constraints=(Interval(0, None, "neither"),)),
    Param("steps", int, GridSpec.steps, constraints=(Interval(2, None),)),
    Param("gain", float, GridSpec.gain, unit="1/s", constraints=(Interval(0, None, "neither"),)),
    Param("baseline_s", float, GridSpec.baseline_s, unit="s", constraints=(Interval(0, None),)),
)
"""The stored settings of a grid input (:class:`GridSpec`'s fields), for
:func:`grids_from_config`."""


def grids_from_config(config: dict, owner: str = "grid settings") -> SessionGrids:
    """Return the grid input a model file's configuration describes (files without a
    ``baseline_s`` kept absolute values); a one-line InputError naming ``owner`` (no
    file) for a document that is not an object, lacks its timeseries, or holds an
    unknown setting, a value of the wrong type, out of range or not finite, or an
    unknown timeseries feature (:meth:`SessionGrids.fit`'s checks)."""
    config = check_settings(GRID_SETTINGS, config, owner)
    check_names(config.get("timeseries"), "timeseries", owner)
    config["timeseries"] = tuple(config["timeseries"])
    config.setdefault("baseline_s", 0.0)
    grids = SessionGrids(**config)
    try:
        return grids.fit(None)
    except InputError as err:
        raise InputError(f"{owner}: {err.problem}") from err


def load_grid_set(sources: Sequence[Path], grids: SessionGrids, workers: int = 1,
                  progress: Callable[[int, int], None] | None = None, *,
                  scheduler: str | None = None) -> FeatureSet:
    """Return the grids ``grids`` describes of every session of the dataset directories
    ``sources`` (see :func:`load_grids`), in ``workers`` processes or on the Dask
    ``scheduler``."""
    return load_grids(sources, grids.spec, workers, progress=progress, scheduler=scheduler,
                      dynamics=grids.dynamics)
