"""Per-session measurements for ``recorder stats --deep``.

Each worker reads one session and returns a small summary (a few hundred numbers):
sampling, the thesis's torque-noise statistic, peak residual norm and estimated
force, the estimated force profile around the interaction, how the Difference window
was found, the delay between planned and detected onset, joint-limit proximity and
the file's SHA-256.

The session is read batch by batch, several times (a session of at most one row
group, 65,536 samples, is read once and its batches kept), so memory stays bounded
however long the session is: one pass validates it and takes the extremes, moments and the
Difference window (:class:`contactkit.features.windows.WindowSearch`); the medians
(median step, the robust noise sigmas, the residual's median) are exact, found by
radix selection in a few more passes (:func:`contactkit.util.exact_median.exact_medians`);
one pass runs the feature chain batch by batch
(:class:`contactkit.features.timeseries.TimeseriesChain`) and spills the residual after
the first second to a temporary file (:class:`contactkit.recorder.importers.spill.RowSpill`)
for its median. The numbers equal
those of the whole session held at once up to rounding (1e-12 relative for the
chunked chain, 1e-15 for the merged moments).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np

from contactkit.errors import DATA_ERRORS, problem_text
from contactkit.features import chain_cache
from contactkit.features.agreement import session_residual_agreement
from contactkit.features.limits import ROBOT_MODE_REFLEX, robot_limits
from contactkit.features.timeseries import ChainConfig, TimeseriesChain
from contactkit.features.timing import streamed_sampling_stats
from contactkit.features.windows import WindowSearch, WindowSpec
from contactkit.recorder.importers.spill import RowSpill
from contactkit.robots.dynamics import ArmDynamics
from contactkit.schemas import InputError, SessionMeta
from contactkit.schemas.columns import REQUIRED_COLUMNS
from contactkit.schemas.session import (
    ROW_GROUP_ROWS,
    SampleBatch,
    iter_sample_batches,
    read_session_meta,
)
from contactkit.util.exact_median import exact_medians
from contactkit.util.moments import RunningMoments

PROFILE_BEFORE_S = 0.25
PROFILE_AFTER_S = 2.0
PROFILE_HZ = 100.0
PROFILE_T = np.arange(-PROFILE_BEFORE_S, PROFILE_AFTER_S, 1.0 / PROFILE_HZ)
RESIDUAL_SETTLE_S = 1.0
"""The residual's median leaves out the observer's first second [s]."""


def file_sha256(path: Path) -> str:
    """Return the SHA-256 of a file's bytes (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


class _Chunks:
    """One session's complete samples (every joint value present), batch by batch on
    each call, as :class:`contactkit.schemas.session.SampleBatch`. A file of at most
    ``ROW_GROUP_ROWS`` samples is read once, by the first, validating call, and its
    chunks are kept for the later passes; a longer one is read again on each call."""

    def __init__(self, path: Path, rows: int) -> None:
        self.path = path
        self._keep = rows <= ROW_GROUP_ROWS
        self._kept: list[SampleBatch] | None = None

    def __call__(self, validate_all: bool = False) -> Iterator[SampleBatch]:
        if self._kept is not None:
            return iter(self._kept)
        chunks = self._read(validate_all)
        if self._keep and validate_all:
            self._kept = list(chunks)
            return iter(self._kept)
        return chunks

    def _read(self, validate_all: bool) -> Iterator[SampleBatch]:
        columns = None if validate_all else REQUIRED_COLUMNS
        return iter_sample_batches(self.path, chain_cache.BATCH_ROWS, columns)


def _second_differences(chunks: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
    """Yield ``np.diff(x, n=2, axis=0)`` of the rows of consecutive chunks, chunk by
    chunk (the differences across chunk boundaries included)."""
    tail = None
    for chunk in chunks:
        rows = chunk if tail is None else np.concatenate([tail, chunk])
        tail = rows[-2:]
        if len(rows) > 2:
            yield np.diff(rows, n=2, axis=0)


def _robust_noise_sigmas(read: Callable[[], Iterable[np.ndarray]]) -> np.ndarray:
    """Return :func:`contactkit.recorder.sim.noise.robust_noise_sigma` of each column of a
    re-readable stream, exactly: the MAD's two medians are found in passes."""
    def differences() -> Iterator[np.ndarray]:
        return _second_differences(read())

    center = exact_medians(differences)
    mad = exact_medians(lambda: (np.abs(d - center) for d in differences()))
    return 1.4826 * mad / np.sqrt(6.0)


class _Profile:
    """The samples of a force [N] needed to interpolate it at given times as
    ``np.interp(times, t, force, left=nan, right=nan)`` on the whole session does: those
    within the times' span and the one on either side."""

    def __init__(self, times: np.ndarray) -> None:
        self.times = times
        self.t: list[np.ndarray] = []
        self.force: list[np.ndarray] = []
        self._before: tuple[float, float] | None = None
        self._after_seen = False

    def add(self, t: np.ndarray, force: np.ndarray) -> None:
        """Take the next chunk's times [s] and forces [N]."""
        if self._after_seen:
            return
        low, high = self.times[0], self.times[-1]
        before = np.flatnonzero(t < low)
        if before.size:
            self._before = (float(t[before[-1]]), float(force[before[-1]]))
        inside = (t >= low) & (t <= high)
        after = np.flatnonzero(t > high)
        if after.size:
            inside[after[0]] = True
            self._after_seen = True
        self.t.append(t[inside])
        self.force.append(force[inside])

    def values(self) -> np.ndarray:
        """Return the force interpolated at the times [N], NaN outside the session."""
        t, force = np.concatenate(self.t), np.concatenate(self.force)
        if self._before is not None:
            t, force = np.insert(t, 0, self._before[0]), np.insert(force, 0, self._before[1])
        if t.size == 0:
            return np.full(self.times.shape, np.nan)
        return np.interp(self.times, t, force, left=np.nan, right=np.nan)


def session_summary(path: str, dynamics: ArmDynamics | None = None) -> dict:
    """Measure one session (its residual with the arm's identified ``dynamics`` when
    given); on a bad file, or dynamics of another arm, return ``{"file": name,
    "problem": text}``."""
    name = Path(path).name
    try:
        meta, footer = read_session_meta(path)
        return _summary(Path(path), meta, footer.num_rows, ChainConfig(dynamics=dynamics))
    except DATA_ERRORS as err:
        return {"file": name, "problem": problem_text(err)}


def _summary(path: Path, meta: SessionMeta, rows: int, config: ChainConfig) -> dict:
    chunks = _Chunks(path, rows)
    planned = meta.planned_at_s
    search = WindowSearch(planned, WindowSpec("difference")) if planned is not None else None
    tau_moments = RunningMoments()
    q_low, q_high = np.full(7, np.inf), np.full(7, -np.inf)
    dq_peak, tau_peak = np.zeros(7), np.zeros(7)
    first_t = last_t = math.nan
    for batch in chunks(validate_all=True):
        t, q, dq, tau = batch.t, batch.q, batch.dq, batch.tau
        if tau_moments.count == 0:
            first_t = float(t[0])
        q_low, q_high = np.minimum(q_low, q.min(axis=0)), np.maximum(q_high, q.max(axis=0))
        dq_peak = np.maximum(dq_peak, np.abs(dq).max(axis=0))
        # after a reflex stop the brakes, not the motors, hold the arm: not the motors'
        # torque (features.limits)
        motors = tau if batch.robot_mode is None else tau[batch.robot_mode != ROBOT_MODE_REFLEX]
        if len(motors):
            tau_peak = np.maximum(tau_peak, np.abs(motors).max(axis=0))
        tau_moments.add(tau)
        last_t = float(t[-1])
        if search is not None:
            search.feed(t, tau)
    if tau_moments.count == 0:
        raise InputError("no sample has every joint value", path)
    duration = last_t - first_t if tau_moments.count > 1 else 0.0
    sampling = streamed_sampling_stats(lambda: (b.t for b in chunks())).as_dict()
    sigmas = _robust_noise_sigmas(lambda: (np.hstack([b.tau, b.dq, b.q]) for b in chunks()))
    window = search.finish() if search is not None else None
    onset = None if window is None else (window.onset_s if window.found else planned)
    profile = _Profile(onset + PROFILE_T) if onset is not None else None
    chain = TimeseriesChain(config, config.robot_setup(meta, path), ["r", "fm_norm"])
    peak_residual = peak_force = -math.inf
    settled = RowSpill(7)
    try:
        for batch in chunks():
            t, series = batch.t, chain.feed(batch)
            residual, force = series["r"], series["fm_norm"][:, 0]
            peak_residual = max(peak_residual, float(np.linalg.norm(residual, axis=1).max()))
            peak_force = max(peak_force, float(force.max()))
            if profile is not None:
                profile.add(t, force)
            settled.append(residual[t > first_t + RESIDUAL_SETTLE_S])
        residual_median = (exact_medians(lambda: settled.chunks(chain_cache.BATCH_ROWS))
                           if settled.rows else np.zeros(7))
    finally:
        settled.close()
    out = {"file": path.name, "session_id": meta.session_id, "action": meta.action,
           "condition": meta.condition, "sha256": file_sha256(path),
           "duration_s": duration, "sampling": sampling,
           "tau_std_nm": np.asarray(tau_moments.std()).tolist(),
           "tau_sigma_nm": sigmas[:7].tolist(),
           "dq_sigma_rad_s": sigmas[7:14].tolist(),
           "q_sigma_rad": sigmas[14:].tolist(),
           "r_median_nm": residual_median.tolist(),
           "peak_residual_norm_nm": peak_residual,
           "peak_force_n": peak_force}
    if window is not None:
        assert planned is not None and profile is not None  # a window has its plan
        out.update({"window_found": window.found,
                    "onset_delay_s": None if not window.found or window.onset_s is None
                    else window.onset_s - planned,
                    "short_for_window": bool(last_t < planned + 0.5),
                    "force_profile_n": profile.values().tolist()})
    else:
        out.update({"window_found": None, "onset_delay_s": None,
                    "short_for_window": bool(duration < 0.5),
                    "force_profile_n": None})
    robot = meta.robot_setup(path).robot
    out["robot"] = robot
    out["residual_agreement"] = session_residual_agreement(path, meta, config)
    limits = robot_limits(meta)
    margins = np.minimum(q_low - limits.q_min, limits.q_max - q_high)
    # a continuous joint has no position limit: no margin (None, as JSON has no infinity)
    out["limit_margin_rad"] = [float(m) if np.isfinite(m) else None for m in margins]
    out["max_speed_fraction"] = (dq_peak / limits.dq_max).tolist()
    out["max_torque_fraction"] = (tau_peak / limits.tau_max).tolist()
    return out
