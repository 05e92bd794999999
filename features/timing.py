"""Measured sampling of a session's time stamps (real logs are irregular)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass

import numpy as np

from contactkit.util.exact_median import exact_medians
from contactkit.util.moments import RunningMoments

GAP_FACTOR = 3.0
RESTART_STEP_S = 0.1
"""A step between two samples longer than this [s] is a gap after which the feature
chain's observer and the contact detector restart, as at the start of a session
(:func:`restarts`). A fixed bound, so that a live stream decides it at the sample after
the gap, without the session's median step. Real recordings never step this long:
host-stamped FR3 logs step 0.35-5 ms, the Gaz log 0.7-8.8 ms, MindLab logs every 5 ms
(up to 12 ms) a state that changes at about 100 Hz, up to 35 ms apart once repeated
rows are dropped, and a 30 Hz ROS topic steps 33 ms. Over 0.1 s, five time constants
of the default observer, its one implicit step would integrate the momentum balance
across a stretch it never saw, and the detector's filters have forgotten the arm's
state."""


@dataclass(frozen=True)
class SamplingStats:
    """Sampling of a time column: steps in s, rate in Hz, gaps are steps longer than
    3x the median step, ``dropped_estimate`` the samples those gaps stand for, and
    ``restarts`` the steps longer than :data:`RESTART_STEP_S`, after which the feature
    chain and the detector restart."""

    samples: int
    duration_s: float
    median_step_s: float
    min_step_s: float
    max_step_s: float
    jitter_s: float
    rate_hz: float
    gaps: int
    dropped_estimate: int
    restarts: int = 0

    def as_dict(self) -> dict:
        """Return the statistics as a plain dict."""
        return asdict(self)


def restarts(t: np.ndarray, t_before: float | None = None) -> np.ndarray:
    """Return the indices of the samples of ``t`` [s] that follow a gap, a step longer
    than :data:`RESTART_STEP_S` (from ``t_before``, the stamp before ``t[0]``, for the
    first; None: ``t[0]`` starts the stream and is no restart), in increasing order."""
    t = np.asarray(t, dtype=float)
    first = t_before is not None and len(t) > 0 and t[0] - t_before > RESTART_STEP_S
    if len(t) == 1:  # a live stream's sample: no array work
        return np.zeros(int(first), dtype=np.intp)
    found = np.flatnonzero(t[1:] - t[:-1] > RESTART_STEP_S) + 1
    return np.concatenate(([0], found)) if first else found


def sampling_stats(t: np.ndarray) -> SamplingStats:
    """Return the :class:`SamplingStats` of time stamps ``t`` [s] (strictly increasing).

    Jitter is the standard deviation of the steps that are not gaps.
    """
    steps = np.diff(np.asarray(t, dtype=float))
    if steps.size == 0:
        return SamplingStats(len(t), 0.0, float("nan"), float("nan"), float("nan"),
                             float("nan"), float("nan"), 0, 0)
    median = float(np.median(steps))
    is_gap = steps > GAP_FACTOR * median
    regular = steps[~is_gap]
    return SamplingStats(
        samples=len(t),
        duration_s=float(t[-1] - t[0]),
        median_step_s=median,
        min_step_s=float(steps.min()),
        max_step_s=float(steps.max()),
        jitter_s=float(regular.std()) if regular.size else 0.0,
        rate_hz=1.0 / median,
        gaps=int(is_gap.sum()),
        dropped_estimate=int(np.round(steps[is_gap] / median - 1).sum()),
        restarts=int((steps > RESTART_STEP_S).sum()),
    )


def streamed_sampling_stats(read_t: Callable[[], Iterable[np.ndarray]]) -> SamplingStats:
    """Return :func:`sampling_stats` of time stamps [s] read in chunks, in bounded memory.

    ``read_t()`` returns a fresh iterable of consecutive chunks of ``t`` each time; it
    is read a few times (the exact median step takes up to 5 passes, see
    :func:`contactkit.util.exact_median.exact_medians`, then one more). Equal to
    :func:`sampling_stats` except the jitter, which is merged chunk by chunk (to about
    1e-15 relative).
    """
    def read_steps() -> Iterator[np.ndarray]:
        return (steps[:, None] for steps in chunked_steps(read_t()))

    samples, first, last = 0, math.nan, math.nan
    for chunk in read_t():
        if len(chunk):
            first = chunk[0] if samples == 0 else first
            samples, last = samples + len(chunk), chunk[-1]
    if samples < 2:
        return sampling_stats(np.asarray([first] if samples else [], dtype=float))
    median = float(exact_medians(read_steps)[0])
    regular = RunningMoments()
    gaps, dropped, low, high, restart = 0, 0.0, math.inf, -math.inf, 0
    for steps in chunked_steps(read_t()):
        is_gap = steps > GAP_FACTOR * median
        regular.add(steps[~is_gap])
        gaps += int(is_gap.sum())
        dropped += float(np.round(steps[is_gap] / median - 1).sum())
        restart += int((steps > RESTART_STEP_S).sum())
        low, high = min(low, float(steps.min())), max(high, float(steps.max()))
    return SamplingStats(
        samples=samples, duration_s=float(last - first), median_step_s=median,
        min_step_s=low, max_step_s=high,
        jitter_s=float(regular.std()) if regular.count else 0.0,
        rate_hz=1.0 / median, gaps=gaps, dropped_estimate=int(dropped), restarts=restart)


def chunked_steps(chunks: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
    """Yield the steps of consecutive chunks of time stamps (``np.diff`` of the whole,
    chunk by chunk, in the stamps' unit), the step across each chunk boundary included
    (empty chunks skipped)."""
    last = None
    for chunk in chunks:
        t = np.asarray(chunk, dtype=float)
        if len(t) == 0:
            continue
        steps = np.diff(t) if last is None else np.diff(t, prepend=last)
        last = t[-1]
        if len(steps):
            yield steps


MIN_FEATURE_RATE_HZ = 200.0
"""Below this sample rate [Hz] the feature chain's features mean little: the observer
(gain 50 1/s) and the backward-difference accelerations need steps well under its time
constant, and a 0.5 s interaction window needs enough samples. The thesis recorded at
about 600 Hz; the real contact recordings beside the project are at 200 Hz; franka_ros
publishes at 30 Hz by default."""


def rate_warning(rate_hz: float) -> str | None:
    """Return a one-line warning when a measured sample rate [Hz] is too slow for the
    feature chain (below :data:`MIN_FEATURE_RATE_HZ`), else None."""
    if math.isnan(rate_hz) or rate_hz >= MIN_FEATURE_RATE_HZ:
        return None
    return (f"sampled at {rate_hz:.1f} Hz, too slow for the feature chain (needs "
            f"{MIN_FEATURE_RATE_HZ:.0f} Hz or more; the thesis used about 600 Hz)")
