"""The samples of a long session's interaction window, found and gathered batch by batch.

:func:`streamed_window_values` reads a session file a batch at a time, runs the feature
chain on it (:class:`contactkit.features.timeseries.TimeseriesChain`), finds the window as
it goes (:class:`contactkit.features.windows.WindowSearch`) and keeps only the samples
that are or may still become the window's: the planned window (the fallback), the
samples from the earliest time that may still be the onset, and the window once found.
Memory holds one batch and a few window lengths, however long the session; after the
window the rest of the file is only validated. The values equal those of the whole
session held at once to about 1e-12 (the chunked chain; the window to the rounding of
its calibration's mean and standard deviation).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from contactkit.features import chain_cache
from contactkit.features.chain_cache import iter_chain_batches
from contactkit.features.timeseries import ChainConfig
from contactkit.features.windows import Window, WindowSearch, WindowSpec
from contactkit.schemas import InputError
from contactkit.schemas.session import SampleBatch, iter_sample_batches, read_session_meta


class _Rows:
    """Samples kept for later: times [s] and values (n, channels), in order."""

    def __init__(self, channels: int) -> None:
        self.t = np.zeros(0)
        self.values = np.zeros((0, channels))

    def add(self, t: np.ndarray, values: np.ndarray) -> None:
        self.t = np.concatenate([self.t, t])
        self.values = np.concatenate([self.values, values])

    def since(self, start_s: float) -> None:
        """Forget the samples before ``start_s`` [s]."""
        keep = self.t >= start_s
        self.t, self.values = self.t[keep], self.values[keep]

    def inside(self, window: Window) -> np.ndarray:
        return self.values[window.mask(self.t)]


def streamed_window_values(path: str | Path, spec: WindowSpec, config: ChainConfig,
                           names: list[str]) -> tuple[np.ndarray, Window]:
    """Return the values of the timeseries features ``names`` (expanded names, see
    :mod:`contactkit.features.timeseries`; their columns side by side, units theirs) at
    the samples inside a session file's interaction window, and the window.

    Raises :class:`InputError` naming the file for a bad file or a session without a
    planned interaction time.
    """
    path = Path(path)
    meta, _ = read_session_meta(path)
    if meta.planned_at_s is None:
        raise InputError("session has no planned interaction time (planned_at_s)", path)
    searching = spec.method in ("difference", "change")
    needed = list(dict.fromkeys(names + ([spec.signal] if searching else [])))
    search = WindowSearch(meta.planned_at_s, spec)
    planned = Window(meta.planned_at_s, meta.planned_at_s + spec.length_s, spec.method,
                     False, None)
    rows = fallback = None
    batches = iter_sample_batches(path, chain_cache.BATCH_ROWS)
    config = config or ChainConfig()
    robot = config.robot_setup(meta, path)
    for batch, series in iter_chain_batches(batches, robot, config, needed):
        t = batch.t
        values = np.column_stack([series[n] for n in names])
        if rows is None:
            rows, fallback = _Rows(values.shape[1]), _Rows(values.shape[1])
        if search.window is None:
            search.feed(t, series[spec.signal])
            in_planned = planned.mask(t)
            fallback.add(t[in_planned], values[in_planned])
        rows.add(t, values)
        if search.window is None:
            rows.since(search.undecided_from_s)
            continue
        rows.since(search.window.start_s)
        if t[-1] >= search.window.end_s:
            _validate_rest(batches)
            return rows.inside(search.window), search.window
    if rows is None:
        raise InputError("no sample has every joint value", path)
    window = search.finish()
    return (rows if window.found or not searching else fallback).inside(window), window


def _validate_rest(batches: Iterator[SampleBatch]) -> None:
    """Read the rest of the file: each batch is validated as it is read."""
    for _ in batches:
        pass
