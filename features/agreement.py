"""How well the observer residual agrees with the robot's own external-torque estimate.

A Franka arm reports ``tau_ext_hat_filtered`` (the session's ``tau_ext_hat``
columns), its own estimate of the external joint torque, with the opposite sign of
the momentum-observer residual r. Where a session has it, the agreement of r with
``-tau_ext_hat`` tells whether the session's robot model is right: with the wrong
model (an FR3 replayed with the Panda's inertias) joint 2 disagrees by about 1 Nm RMS.

r is compared after a first-order low-pass of ``smooth_s`` (default 16 ms, a 10 Hz
corner), since libfranka's estimate is itself filtered, while r carries the velocity
noise of the observer's 8 Hz bandwidth and, on host-stamped logs, the jitter of the
time steps. Measured on the two shared real FR3 recordings
(FR3 model, joints 1-7): correlation 0.98-1.00 and RMS difference 0.02-0.14 Nm with
the low-pass, 0.56-0.99 and up to 0.81 Nm without it. The detector low-passes r
with 30 ms anyway, so the observer's own output stays unfiltered.

The first ``warmup_s`` of a session are left out: the observer starts at r = 0.
:class:`ResidualAgreement` accumulates chunk by chunk, so a long session is measured
in bounded memory and batch and streaming give the same figures.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.features.chain_cache import BATCH_ROWS
from contactkit.features.observer import solve_recurrence
from contactkit.features.timeseries import ChainConfig, TimeseriesChain
from contactkit.robots import RobotSetup
from contactkit.schemas.columns import joint_columns
from contactkit.schemas.metadata import SessionMeta
from contactkit.schemas.session import SampleBatch, iter_session_batches

DEFAULT_SMOOTH_S = 1.0 / (2.0 * math.pi * 10.0)
DEFAULT_WARMUP_S = 0.5


class ResidualAgreement:
    """Accumulates the agreement of the residual r [Nm] with ``-tau_ext_hat`` [Nm], per
    joint, over consecutive chunks of one session."""

    def __init__(self, smooth_s: float = DEFAULT_SMOOTH_S,
                 warmup_s: float = DEFAULT_WARMUP_S) -> None:
        if not smooth_s > 0 or not warmup_s >= 0:
            raise ValueError("smooth_s must be positive and warmup_s non-negative")
        self.smooth_s = smooth_s
        self.warmup_s = warmup_s
        self._t_last: float | None = None
        self._t_first: float | None = None
        self._filtered = np.zeros(7)
        self._sums = np.zeros((6, 7))  # x, y, xx, yy, xy, (x - y)^2
        self._n = 0

    def update(self, t: np.ndarray, r: np.ndarray, tau_ext_hat: np.ndarray) -> None:
        """Add the samples of one chunk: ``t`` (n,) [s], ``r`` and ``tau_ext_hat`` (n, 7) [Nm]."""
        if len(t) == 0:
            return
        steps = np.diff(t, prepend=t[0] if self._t_last is None else self._t_last)
        a = np.exp(-steps / self.smooth_s)[:, None] * np.ones((1, 7))
        before = self._filtered
        if self._t_last is None:  # the filter starts at the first sample's value
            self._t_first, before = float(t[0]), r[0]
        filtered = solve_recurrence(a, (1.0 - a) * r, before)
        self._filtered = filtered[-1]
        self._t_last = float(t[-1])
        assert self._t_first is not None  # set at the stream's first sample
        keep = t >= self._t_first + self.warmup_s
        x, y = filtered[keep], -tau_ext_hat[keep]
        self._sums += np.stack([x.sum(0), y.sum(0), (x * x).sum(0), (y * y).sum(0),
                                (x * y).sum(0), ((x - y) ** 2).sum(0)])
        self._n += int(keep.sum())

    def result(self) -> dict | None:
        """Return the agreement per joint, or None before any sample past the warm-up:
        ``correlation`` (Pearson), ``rms_difference_nm``, ``rms_residual_nm`` and
        ``rms_robot_nm`` (7 values each, joint 1 first), ``samples``, ``smooth_s``."""
        if self._n < 2:
            return None
        n = self._n
        sx, sy, sxx, syy, sxy, sdd = self._sums
        cov = sxy / n - (sx / n) * (sy / n)
        var_x = np.maximum(sxx / n - (sx / n) ** 2, 0.0)
        var_y = np.maximum(syy / n - (sy / n) ** 2, 0.0)
        denominator = np.sqrt(var_x * var_y)
        with np.errstate(invalid="ignore", divide="ignore"):
            correlation = np.where(denominator > 0, cov / denominator, np.nan)
        return {"correlation": _rounded(correlation, 4),
                "rms_difference_nm": _rounded(np.sqrt(sdd / n), 4),
                "rms_residual_nm": _rounded(np.sqrt(sxx / n), 4),
                "rms_robot_nm": _rounded(np.sqrt(syy / n), 4),
                "samples": n, "smooth_s": self.smooth_s}


def _rounded(values: np.ndarray, digits: int) -> list[float | None]:
    return [None if not math.isfinite(v) else round(float(v), digits) for v in values]


class StreamAgreement:
    """The residual's agreement with the robot's own estimate over a session streamed as
    consecutive blocks of session columns (``t`` [s], ``q_1``.., ``dq_1``.., ``tau_1``..,
    ``tau_ext_hat_1``..): the residual comes from the chain of ``robot``. Samples
    missing a joint value are left out of the chain, as the session reader leaves them
    out; samples missing an estimate value are left out of the agreement."""

    def __init__(self, robot: RobotSetup, config: ChainConfig | None = None) -> None:
        self.chain = TimeseriesChain(config, robot, ["r"])
        self.agreement = ResidualAgreement()

    def add(self, block: pa.RecordBatch | Mapping[str, np.ndarray]) -> None:
        """Take the next block of session columns (see
        :meth:`contactkit.schemas.session.SampleBatch.from_columns`; a block without the
        estimate is skipped)."""
        batch = SampleBatch.from_columns(block)
        if batch.tau_ext_hat is None:
            return
        batch = batch.complete()
        r = self.chain.feed(batch)["r"]
        assert batch.tau_ext_hat is not None  # complete() keeps the columns
        known = np.isfinite(batch.tau_ext_hat).all(axis=1)
        self.agreement.update(batch.t[known], r[known], batch.tau_ext_hat[known])

    def result(self) -> dict | None:
        """Return :meth:`ResidualAgreement.result` (None without any estimate)."""
        return self.agreement.result()


def stream_residual_agreement(blocks: Iterable[pa.RecordBatch | Mapping[str, np.ndarray]],
                              robot: RobotSetup,
                              config: ChainConfig | None = None) -> dict | None:
    """Return the agreement of a session streamed as ``blocks`` (see
    :class:`StreamAgreement`); None when no block carries the robot's estimate."""
    stream = StreamAgreement(robot, config)
    for block in blocks:
        stream.add(block)
    return stream.result()


def session_residual_agreement(path: str | Path, meta: SessionMeta,
                               config: ChainConfig | None = None) -> dict | None:
    """Return the agreement of a session file with ``tau_ext_hat`` columns, read batch by
    batch (:func:`stream_residual_agreement`, the session's robot or ``config.robot``);
    None for a session without the robot's estimate."""
    names = ["t", *(c for prefix in ("q", "dq", "tau", "tau_ext_hat")
                    for c in joint_columns(prefix))]
    if not set(names) <= set(pq.read_schema(path).names):
        return None
    config = config or ChainConfig()
    return stream_residual_agreement(iter_session_batches(path, BATCH_ROWS, names),
                                     config.robot_setup(meta, path), config)
