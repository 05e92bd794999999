"""The samples around a session's interaction window, found and gathered batch by batch.

:class:`WindowCollector` takes a session's feature values batch by batch, as the chain
(:class:`contactkit.features.timeseries.TimeseriesChain`) computes them, finds the
window as it goes (:class:`contactkit.features.windows.WindowSearch`) and keeps only the
samples that are or may still become the window's: the planned window (the fallback),
the samples from the earliest time that may still be the onset, and the window once
found, each with ``margin_s`` seconds either side. Memory holds one batch and a few
window lengths, however long the session. :func:`streamed_window_values` runs it over a
session file (training on long sessions); the replay runs it on the features it streams
(its offline answer). The values equal those of the whole session held at once to about
1e-12 (the chunked chain; the window to the rounding of its calibration's mean and
standard deviation).
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
    """Samples kept for later: session sample indices, times [s] and values (n,
    channels), in order."""

    def __init__(self, channels: int) -> None:
        self.sample = np.zeros(0, dtype=np.int64)
        self.t = np.zeros(0)
        self.values = np.zeros((0, channels))

    def add(self, sample: np.ndarray, t: np.ndarray, values: np.ndarray) -> None:
        self.sample = np.concatenate([self.sample, sample])
        self.t = np.concatenate([self.t, t])
        self.values = np.concatenate([self.values, values])

    def since(self, start_s: float) -> None:
        """Forget the samples before ``start_s`` [s]."""
        keep = self.t >= start_s
        self.sample, self.t, self.values = self.sample[keep], self.t[keep], self.values[keep]


class WindowCollector:
    """The samples within ``margin_s`` [s] of a session's interaction window (planned
    at ``planned_at_s`` [s], found by ``spec``), gathered from consecutive batches of
    the session's feature values. Feed each batch to :meth:`add` until :attr:`done`;
    :meth:`result` then gives the window and its samples."""

    def __init__(self, planned_at_s: float, spec: WindowSpec, margin_s: float = 0.0) -> None:
        self.spec, self.margin_s = spec, margin_s
        self.search = WindowSearch(planned_at_s, spec)
        self._planned = Window(planned_at_s, planned_at_s + spec.length_s, spec.method,
                               False, None)
        self._rows: _Rows | None = None
        self._fallback: _Rows | None = None
        self.done = False
        """Whether the window and its margin after it have been seen (later batches
        change nothing)."""

    def _near(self, window: Window, t: np.ndarray) -> np.ndarray:
        return (t >= window.start_s - self.margin_s) & (t <= window.end_s + self.margin_s)

    def add(self, sample: np.ndarray, t: np.ndarray, values: np.ndarray,
            signal_values: np.ndarray) -> None:
        """Take the next batch: session sample indices ``sample`` (n,), times ``t`` (n,)
        [s] after the previous batch's, the feature ``values`` (n, channels) and the
        values of the window's signal (n, 7)."""
        if self.done or len(t) == 0:
            return
        if self._rows is None:
            self._rows, self._fallback = _Rows(values.shape[1]), _Rows(values.shape[1])
        search = self.search
        if search.window is None:
            assert self._fallback is not None  # made with _rows
            search.feed(t, signal_values)
            near = self._near(self._planned, t)
            self._fallback.add(sample[near], t[near], values[near])
        self._rows.add(sample, t, values)
        if search.window is None:
            self._rows.since(search.undecided_from_s - self.margin_s)
            return
        self._rows.since(search.window.start_s - self.margin_s)
        self.done = bool(t[-1] >= search.window.end_s + self.margin_s)

    def result(self) -> tuple[Window, np.ndarray, np.ndarray, np.ndarray] | None:
        """Return the window of the samples fed so far, and the session sample indices
        (m,), times (m,) [s] and feature values (m, channels) of the samples within
        ``margin_s`` of it; None before any sample."""
        if self._rows is None:
            return None
        assert self._fallback is not None  # made with _rows
        decided = self.search.window is not None  # the rows were kept from its start
        window = self.search.finish()
        rows = self._rows if decided or window.found else self._fallback
        near = self._near(window, rows.t)
        return window, rows.sample[near], rows.t[near], rows.values[near]


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
    needed = list(dict.fromkeys([*names, spec.signal]))
    collector = WindowCollector(meta.planned_at_s, spec)
    batches = iter_sample_batches(path, chain_cache.BATCH_ROWS)
    config = config or ChainConfig()
    start = 0
    for batch, series in iter_chain_batches(batches, config.robot_setup(meta, path), config,
                                            needed):
        collector.add(np.arange(start, start + len(batch)), batch.t,
                      np.column_stack([series[n] for n in names]), series[spec.signal])
        start += len(batch)
        if collector.done:
            _validate_rest(batches)
            break
    found = collector.result()
    if found is None:
        raise InputError("no sample has every joint value", path)
    window, _, t, values = found
    return values[window.mask(t)], window


def _validate_rest(batches: Iterator[SampleBatch]) -> None:
    """Read the rest of the file: each batch is validated as it is read."""
    for _ in batches:
        pass
