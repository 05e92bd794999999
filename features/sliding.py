"""Scalar features of many overlapping windows of one series, from shared pieces.

A replay classifies a 0.5 s window every 20 ms, so each sample lies in some 25
windows; reducing every window on its own repeats that work 25 times. Here the
windows' start and end samples cut the series into elementary segments, each
reduced once (count, mean, sum of squared deviations, max, min), and each window
combines its segments with Chan's pairwise update of mean and variance, which is as
stable as numpy's two-pass variance (they agree to about 1e-13 relative). Max and
min combine exactly.
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
    min 0. Without ``extremes`` max and min are not computed (left 0)."""
    starts, stops = np.asarray(starts, dtype=np.intp), np.asarray(stops, dtype=np.intp)
    shape = (len(starts), y.shape[1])
    count, mean, var = np.zeros((len(starts), 1)), np.zeros(shape), np.zeros(shape)
    high, low = np.zeros(shape), np.zeros(shape)
    cuts = np.unique(np.concatenate([starts, stops]))
    if len(cuts) < 2:
        return WindowMoments(count, mean, var, high, low)
    # the elementary segments [cuts[j], cuts[j + 1]), each reduced once
    span = y[cuts[0]:cuts[-1]]
    heads, lengths = cuts[:-1] - cuts[0], np.diff(cuts)
    seg_count = lengths[:, None].astype(float)
    seg_mean = np.add.reduceat(span, heads, axis=0) / seg_count
    centred = span - np.repeat(seg_mean, lengths, axis=0)
    seg_m2 = np.add.reduceat(centred * centred, heads, axis=0)
    if extremes:
        seg_max = np.maximum.reduceat(span, heads, axis=0)
        seg_min = np.minimum.reduceat(span, heads, axis=0)
    first = np.searchsorted(cuts, starts)
    n_segments = np.searchsorted(cuts, stops) - first
    every = int(n_segments.min())
    m2 = np.zeros(shape)
    if extremes:
        high, low = np.full(shape, -np.inf), np.full(shape, np.inf)
    for step in range(int(n_segments.max(initial=0))):
        # each window's step-th segment joins it (Chan's update of n, mean and M2); all
        # windows have the first `every` segments, so those steps select no rows
        rows = slice(None) if step < every else np.flatnonzero(n_segments > step)
        j = first[rows] + step
        n_a, n_b = count[rows], seg_count[j]
        n = n_a + n_b
        delta = seg_mean[j] - mean[rows]
        mean[rows] += delta * (n_b / n)
        m2[rows] += seg_m2[j] + delta * delta * (n_a * n_b / n)
        count[rows] = n
        if extremes:
            high[rows] = np.maximum(high[rows], seg_max[j])
            low[rows] = np.minimum(low[rows], seg_min[j])
    if extremes:
        empty = n_segments == 0
        high[empty] = low[empty] = 0.0
    var = m2 / np.maximum(count, 1.0)
    return WindowMoments(count, mean, var, high, low)


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
    hjorth = None
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
