"""Scalar features of many overlapping windows of one series, from shared pieces.

A replay classifies a 0.5 s window every 20 ms, so each sample lies in some 25
windows; reducing every window on its own repeats that work 25 times. Here the
windows' start and end samples cut the series into elementary segments, each
reduced once (count, mean, sum of squared deviations, max, min); runs of 2, 4, 8, ...
consecutive segments are combined once for all windows, and each window combines the
runs its segment count's binary digits call for. Moments combine with Chan's pairwise
update of mean and variance, which is as stable as numpy's two-pass variance (they
agree to about 1e-13 relative). Max and min combine exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactkit.features.scalars import safe_ratio

SLIDING_SCALARS = frozenset(("mean", "variance", "range", "delta", "energy", "hjorth_mob",
                             "hjorth_comp"))
"""The scalar features :func:`window_scalar_blocks` computes from segments (skew and
the FFT are not: their windows are reduced one by one)."""


@dataclass
class WindowMoments:
    """Per window and channel (windows, channels): sample count, mean, population
    variance, max and min, in the series' unit (variance: its square)."""

    count: np.ndarray
    mean: np.ndarray
    var: np.ndarray
    max: np.ndarray
    min: np.ndarray


def window_moments(y: np.ndarray, starts: np.ndarray, stops: np.ndarray,
                   extremes: bool = True) -> WindowMoments:
    """Return the moments of the windows ``y[starts[i]:stops[i]]`` of the series ``y``
    (N, channels); empty windows (start == stop) have count, mean, variance, max and
    min 0. Without ``extremes`` max and min are not computed (left 0).

    Each window joins its elementary segments in runs of 1, 2, 4, ... segments (the
    binary digits of its segment count), each run's moments combined once for every
    window (:func:`_doubled_runs`): a replay's window of some 50 segments takes 6
    combinations instead of 50."""
    starts, stops = np.asarray(starts, dtype=np.intp), np.asarray(stops, dtype=np.intp)
    shape = (len(starts), y.shape[1])
    cuts = np.unique(np.concatenate([starts, stops]))
    if len(cuts) < 2:
        zeros = np.zeros(shape)
        return WindowMoments(np.zeros((len(starts), 1)), zeros, zeros.copy(), zeros.copy(),
                             zeros.copy())
    first = np.searchsorted(cuts, starts)
    n_segments = np.searchsorted(cuts, stops) - first
    runs = _doubled_runs(_segments(y, cuts, extremes), int(n_segments.max()).bit_length())
    total = _Moments(np.zeros((len(starts), 1)), np.zeros(shape), np.zeros(shape),
                     np.full(shape, -np.inf) if extremes else None,
                     np.full(shape, np.inf) if extremes else None)
    position = first.copy()
    for level in reversed(range(len(runs))):
        # every window with this binary digit in its segment count takes the run of
        # 2**level segments that starts where it has got to
        has = (n_segments >> level) & 1 == 1
        rows = slice(None) if has.all() else np.flatnonzero(has)
        _merge_into(total, rows, runs[level], position[rows])
        position[rows] += 1 << level
    if total.max is not None and total.min is not None:  # with extremes
        high, low = total.max, total.min
        empty = n_segments == 0
        high[empty] = low[empty] = 0.0
    else:
        high, low = np.zeros(shape), np.zeros(shape)
    var = total.m2 / np.maximum(total.count, 1.0)
    return WindowMoments(total.count, total.mean, var, high, low)


@dataclass
class _Moments:
    """Moments of pieces of a series (pieces, channels): count (pieces, 1), mean, sum
    of squared deviations ``m2``, max and min (None when not computed)."""

    count: np.ndarray
    mean: np.ndarray
    m2: np.ndarray
    max: np.ndarray | None
    min: np.ndarray | None


def _segments(y: np.ndarray, cuts: np.ndarray, extremes: bool) -> _Moments:
    """Return the moments of the elementary segments ``y[cuts[j]:cuts[j + 1]]``, each
    reduced once (its mean, then the squared deviations from it: two passes)."""
    span = y[cuts[0]:cuts[-1]]
    heads, lengths = cuts[:-1] - cuts[0], np.diff(cuts)
    count = lengths[:, None].astype(float)
    mean = np.add.reduceat(span, heads, axis=0) / count
    centred = span - np.repeat(mean, lengths, axis=0)
    m2 = np.add.reduceat(centred * centred, heads, axis=0)
    if not extremes:
        return _Moments(count, mean, m2, None, None)
    return _Moments(count, mean, m2, np.maximum.reduceat(span, heads, axis=0),
                    np.minimum.reduceat(span, heads, axis=0))


def _doubled_runs(segments: _Moments, levels: int) -> list[_Moments]:
    """Return, for each level l < ``levels``, the moments of every run of 2**l
    consecutive segments (run j: segments j to j + 2**l - 1), each the combination of
    two runs of the level below."""
    runs = [segments]
    for level in range(1, levels):
        half, below = 1 << (level - 1), runs[-1]
        if len(below.count) <= half:
            break
        run = _Moments(below.count[:-half].copy(), below.mean[:-half].copy(),
                       below.m2[:-half].copy(),
                       None if below.max is None else below.max[:-half].copy(),
                       None if below.min is None else below.min[:-half].copy())
        _merge_into(run, slice(None), below, np.arange(half, len(below.count)))
        runs.append(run)
    return runs


def _merge_into(total: _Moments, rows: slice | np.ndarray, part: _Moments,
                pieces: np.ndarray) -> None:
    """Combine the moments ``part[pieces]`` into ``total[rows]`` (the part follows the
    total's samples) with Chan's update of count, mean and m2; max and min exactly."""
    n_a, n_b = total.count[rows], part.count[pieces]
    n = n_a + n_b
    delta = part.mean[pieces] - total.mean[rows]
    total.mean[rows] += delta * (n_b / n)
    total.m2[rows] += part.m2[pieces] + delta * delta * (n_a * n_b / n)
    total.count[rows] = n
    if total.max is not None:
        assert total.min is not None and part.max is not None and part.min is not None
        total.max[rows] = np.maximum(total.max[rows], part.max[pieces])
        total.min[rows] = np.minimum(total.min[rows], part.min[pieces])


def window_scalar_blocks(values: np.ndarray, firsts: np.ndarray, lasts: np.ndarray,
                         names: tuple[str, ...] | list[str]) -> list[np.ndarray]:
    """Return the scalar features ``names`` (all in :data:`SLIDING_SCALARS`) of the
    windows ``values[firsts[i]:lasts[i] + 1]`` (each of at least 2 samples) as blocks
    (windows, channels), one per name, as
    :func:`contactkit.features.scalars.scalar_blocks` gives them window by window."""
    unknown = set(names) - SLIDING_SCALARS
    if unknown:
        raise ValueError(f"not computed from segments: {sorted(unknown)}")
    stops = np.asarray(lasts) + 1
    moments = window_moments(values, firsts, stops, extremes="range" in names)
    hjorth: dict[str, np.ndarray] = {}
    if not {"hjorth_mob", "hjorth_comp"}.isdisjoint(names):
        first_diff = np.diff(values, axis=0)  # a window's differences are the series'
        var_first = window_moments(first_diff, firsts, stops - 1, extremes=False).var
        var_second = window_moments(np.diff(first_diff, axis=0), firsts,
                                    np.maximum(firsts, stops - 2), extremes=False).var
        mobility = np.sqrt(safe_ratio(var_first, moments.var))
        hjorth = {"hjorth_mob": mobility,
                  "hjorth_comp": safe_ratio(np.sqrt(safe_ratio(var_second, var_first)), mobility)}
    blocks = []
    for name in names:
        if name == "mean":
            blocks.append(moments.mean)
        elif name == "variance":
            blocks.append(moments.var)
        elif name == "range":
            blocks.append(moments.max - moments.min)
        elif name == "delta":
            blocks.append(values[lasts] - values[firsts])
        elif name == "energy":
            blocks.append(moments.count * (moments.var + moments.mean * moments.mean))
        else:
            blocks.append(hjorth[name])
    return blocks
