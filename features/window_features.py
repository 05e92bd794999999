"""Scalar features of windows of a session: the interaction window, or the windows a
replay classifies online (:class:`WindowFeatures`).

This module imports neither scikit-learn nor the parallel extraction, so a replay and
live events load it alone; :class:`contactkit.features.extract.SessionFeatures` is the
same as a scikit-learn transformer over sessions.
"""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from contactkit.features.chain_cache import chain_series
from contactkit.features.names import ALL_TIMESERIES
from contactkit.features.observer import ObserverConfig
from contactkit.features.scalars import SCALARS, scalar_blocks, scalar_features
from contactkit.features.sliding import SLIDING_SCALARS, window_scalar_blocks
from contactkit.features.timeseries import ChainConfig, columns_of, expand
from contactkit.features.window_stream import streamed_window_values
from contactkit.features.windows import CALIBRATIONS, METHODS, Window, WindowSpec, find_window
from contactkit.robots.dynamics import ArmDynamics
from contactkit.schemas import InputError, Session, read_session
from contactkit.schemas.session import ROW_GROUP_ROWS, read_session_meta
from contactkit.util.params import Choice, Interval, Param, check_names, check_settings

DEFAULT_TIMESERIES = ("dq", "tau", "r")
STREAMED_ABOVE_ROWS = ROW_GROUP_ROWS
"""Session files with more samples (about 65 s at 1 kHz) are read batch by batch for
their window's features, without the chain cache; shorter ones are read whole."""
DEFAULT_SCALARS = ("range",)
ONLINE_BLOCK_VALUES = 1 << 20
"""Window values gathered at once by :meth:`WindowFeatures.online_rows` (8 MB)."""


class WindowFeatures:
    """Scalar features of a session's interaction window, and of every window a replay
    classifies online, without scikit-learn
    (:class:`contactkit.features.extract.SessionFeatures` is this as a scikit-learn
    transformer).

    Parameters: ``timeseries`` (feature or group names, see
    :mod:`contactkit.features.timeseries`), ``window`` (fixed, planned, difference, change),
    ``window_s`` length [s], ``shift_s`` for fixed windows [s], ``signal`` and
    ``calibration`` of the detection methods, ``scalars`` (see
    :mod:`contactkit.features.scalars`), ``fft_k``, observer ``gain`` [1/s] and ``friction``,
    ``wrench_frame`` ("ee" or a link 1..7), ``robot`` the arm's model instead of each
    session's own (None: the session's, see :mod:`contactkit.robots`). Defaults are the
    thesis's best SVM input: the range of joint velocity, torque and residual in a 0.5 s
    window.

    ``dynamics`` (an attribute, not a parameter: no stored setting, a model file does not
    carry it) is the arm's identified dynamics the chain uses (``--dynamics``), None for
    the nominal model.
    """

    dynamics: ArmDynamics | None = None

    def __init__(self, timeseries: Sequence[str] = DEFAULT_TIMESERIES,
                 window: str = "difference", window_s: float = 0.5, shift_s: float = 0.0,
                 signal: str = "tau", calibration: str = "pre-contact",
                 scalars: Sequence[str] = DEFAULT_SCALARS, fft_k: int = 3,
                 gain: float = 50.0, friction: bool = True, wrench_frame: str | int = "ee",
                 robot: str | None = None) -> None:
        self.timeseries = timeseries
        self.window = window
        self.window_s = window_s
        self.shift_s = shift_s
        self.signal = signal
        self.calibration = calibration
        self.scalars = scalars
        self.fft_k = fft_k
        self.gain = gain
        self.friction = friction
        self.wrench_frame = wrench_frame
        self.robot = robot

    def _check(self) -> None:
        try:
            expand(list(self.timeseries))
        except KeyError as err:
            raise InputError(f"unknown timeseries feature {err.args[0]!r}") from err
        unknown = [s for s in self.scalars if s not in SCALARS]
        if unknown:
            raise InputError(f"unknown scalar feature {unknown[0]!r} (expected some of "
                             f"{', '.join(SCALARS)})")

    @property
    def window_spec(self) -> WindowSpec:
        """The window settings as a :class:`WindowSpec`."""
        return WindowSpec(self.window, self.window_s, self.shift_s, signal=self.signal,
                          calibration=self.calibration)

    def chain_config(self) -> ChainConfig:
        """The feature-chain settings."""
        return ChainConfig(ObserverConfig(gain=self.gain, friction=self.friction),
                           self.wrench_frame, self.robot, self.dynamics)

    def config(self) -> dict:
        """Return the parameters as JSON-ready values (stored with tables and models)."""
        params = {name: getattr(self, name) for name in PARAMETERS}
        return {k: list(v) if isinstance(v, tuple) else v for k, v in params.items()}

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        """Return the feature names, for example ``range(tau_3)``."""
        self._check()
        channels = self.channels()
        _, names = scalar_features(np.zeros((4, len(channels))), list(self.scalars), channels,
                                   self.fft_k)
        return np.array(names, dtype=object)

    def channels(self) -> list[str]:
        """Return the per-sample columns the features are computed from, e.g. ``tau_3``."""
        return [c for name in expand(list(self.timeseries)) for c in columns_of(name)]

    def online_rows(self, t: np.ndarray, values: np.ndarray, ends: np.ndarray | list[int]
                    ) -> np.ndarray:
        """Return the scalar features (len(ends), features) of the ``window_s`` seconds
        ending at each sample of ``ends``, from per-sample ``values`` (N, channels, in
        :meth:`channels` order) at times ``t`` [s]; a window uses samples up to its end
        only. A window that holds fewer than 2 samples (a session sampled slower than
        the window) is widened to the last 2.

        The windows overlap (a replay's hops are 20 ms apart, its windows 0.5 s), so
        the scalars of :data:`contactkit.features.sliding.SLIDING_SCALARS` reduce each
        piece of the series once (:func:`contactkit.features.sliding.window_moments`).
        Other scalars compute windows of equal length together, side by side as the
        columns of one array (at most :data:`ONLINE_BLOCK_VALUES` values at a time).
        Either way the values equal each window's own to about 1e-13 relative."""
        ends = np.asarray(ends, dtype=np.intp)
        firsts = np.searchsorted(t, t[ends] - self.window_s, side="right")
        firsts = np.maximum(0, np.minimum(firsts, ends - 1))
        scalars, width = list(self.scalars), values.shape[1]
        if SLIDING_SCALARS.issuperset(scalars):
            return np.concatenate(window_scalar_blocks(values, firsts, ends, scalars), axis=1)
        lengths = ends + 1 - firsts
        n_blocks = sum(self.fft_k if name == "fft" else 1 for name in scalars)
        rows = np.empty((len(ends), n_blocks * width))
        by_channel = np.ascontiguousarray(values.T)
        for length in np.unique(lengths):
            same = np.flatnonzero(lengths == length)
            per = max(1, ONLINE_BLOCK_VALUES // int(length * width))
            for part in np.array_split(same, -(-len(same) // per)):
                # (channels, windows, length): each window's channels as columns
                x = sliding_window_view(by_channel, int(length), axis=1)[:, firsts[part]]
                blocks = np.stack(scalar_blocks(x.reshape(-1, length).T, scalars, self.fft_k))
                rows[part] = (blocks.reshape(n_blocks, width, len(part))
                              .transpose(2, 0, 1).reshape(len(part), -1))
        return rows

    def window_row(self, t: np.ndarray, values: np.ndarray, window: Window,
                   path: str | Path | None = None) -> np.ndarray:
        """Return the scalar features of ``window`` from per-sample ``values`` (N,
        channels, in :meth:`channels` order) at times ``t`` [s] around it. Raises
        InputError naming ``path`` when the window holds fewer than 2 samples."""
        return self._scalar_row(values[window.mask(t)], expand(list(self.timeseries)), window,
                                path)[0]

    def session_row(self, session: Session | str | Path) -> tuple[np.ndarray, list[str], Window]:
        """Return (values, names, window) for one session. A session file longer than
        :data:`STREAMED_ABOVE_ROWS` samples is read batch by batch, keeping only what
        its window needs (:mod:`contactkit.features.window_stream`)."""
        names = expand(list(self.timeseries))
        spec = self.window_spec
        if not isinstance(session, Session):
            _, footer = read_session_meta(session)
            if footer.num_rows > STREAMED_ABOVE_ROWS:
                values, window = streamed_window_values(session, spec, self.chain_config(),
                                                        names)
                return self._scalar_row(values, names, window, Path(session))
            session = read_session(session)
        session = session.complete()
        needed = list(dict.fromkeys(names + ([spec.signal] if spec.method in
                                             ("difference", "change") else [])))
        series = chain_series(session, self.chain_config(), needed)
        window = session_window(session, spec, series.get(spec.signal))
        values = np.column_stack([series[n] for n in names])[window.mask(session.t)]
        return self._scalar_row(values, names, window, session.path)

    def _scalar_row(self, values: np.ndarray, names: list[str], window: Window,
                    path: str | Path | None) -> tuple[np.ndarray, list[str], Window]:
        """Return (scalar features, their names, window) of a window's samples."""
        if len(values) < 2:
            raise InputError(f"window {window.start_s:.3f}-{window.end_s:.3f} s holds fewer "
                             "than 2 samples (session too short?)", path)
        channels = [c for n in names for c in columns_of(n)]
        row, labels = scalar_features(values, list(self.scalars), channels, self.fft_k)
        return row, labels, window


def session_window(session: Session, spec: WindowSpec,
                   signal_values: np.ndarray | None) -> Window:
    """Return the interaction window of a session (needs its planned time)."""
    planned = session.meta.planned_at_s
    if planned is None:
        raise InputError("session has no planned interaction time (planned_at_s)", session.path)
    return find_window(session.t, planned, spec, signal_values)


PARAMETERS = tuple(inspect.signature(WindowFeatures).parameters)
"""The parameters of :class:`WindowFeatures` (those of its ``__init__``), by name."""


_DEFAULTS = {name: p.default for name, p in
             inspect.signature(WindowFeatures).parameters.items()}


def _setting(name: str, kind: type, *constraints: Interval | Choice, unit: str | None = None
             ) -> Param:
    return Param(name, kind, _DEFAULTS[name], unit=unit, constraints=constraints,
                 optional=_DEFAULTS[name] is None)


MAX_WINDOW_S = 86400.0
"""The longest window [s] (and the largest shift) a feature setting may give: a day, the
longest session. A model file is untrusted input: a window of 1e300 s overflowed the
replay's time arithmetic."""

SETTINGS = (
    _setting("window", str, Choice(METHODS)),
    _setting("window_s", float, Interval(0, MAX_WINDOW_S, "right"), unit="s"),
    _setting("shift_s", float, Interval(-MAX_WINDOW_S, MAX_WINDOW_S), unit="s"),
    _setting("signal", str, Choice(tuple(ALL_TIMESERIES))),
    _setting("calibration", str, Choice(CALIBRATIONS)),
    _setting("fft_k", int, Interval(1, None)),
    _setting("gain", float, Interval(0, None, "neither"), unit="1/s"),
    _setting("friction", bool),
    _setting("timeseries", list),
    _setting("scalars", list),
    _setting("wrench_frame", object),
    _setting("robot", str),
)
"""The stored settings of :class:`WindowFeatures` (:data:`PARAMETERS`) as declarations,
for :func:`check_config`; the defaults are ``__init__``'s."""


def check_config(config: object, owner: str = "features settings") -> dict:
    """Return a stored window-feature configuration (a model file's ``features``) as
    keywords of :class:`WindowFeatures`, checked as the features' own checks would
    (feature names, window method and length, robot); raise a one-line InputError
    naming ``owner`` for a document that is not an object, a setting that is unknown, of
    the wrong type, not finite or out of range, and an unknown feature or robot."""
    config = check_settings(SETTINGS, config, owner)
    for name in ("timeseries", "scalars"):
        if config.get(name) is not None:
            check_names(config[name], name, owner)
    frame = config.get("wrench_frame", "ee")
    if not ((isinstance(frame, str) and frame)
            or (isinstance(frame, int) and not isinstance(frame, bool) and 1 <= frame <= 7)):
        raise InputError(f"{owner}: wrench_frame must be 'ee', a frame name or a link 1..7, "
                         f"got {frame!r:.80}")
    features = WindowFeatures(**config)
    try:
        features._check()
        features.window_spec  # noqa: B018 (checks the window's method and length)
        if features.robot is not None:
            from contactkit.robots.registry import canonical_robot_name

            canonical_robot_name(features.robot)
    except InputError as err:
        raise InputError(f"{owner}: {err.problem}") from err
    return config


def window_features_from_config(config: dict) -> WindowFeatures:
    """Return the window features a model file's configuration describes; InputError
    (naming no file) if it is malformed (:func:`check_config`)."""
    return WindowFeatures(**check_config(config))
