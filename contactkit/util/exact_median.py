"""Exact column medians of a stream too long to hold, in a few passes and bounded memory.

:func:`exact_medians` reads the stream several times (a callable returns a fresh
iterator of (n, k) chunks each time) and selects the middle order statistics by radix
selection on the bits of the float64 values, mapped to unsigned keys that sort as the
floats do: each pass counts 16 more bits of the candidates in a 65,536-bin histogram,
and once at most :data:`COLLECT_AT` candidates are left they are gathered and
partitioned. The result equals ``np.median(values, axis=0)`` bit for bit (for finite
values); memory is one chunk, the histograms and at most :data:`COLLECT_AT` values per
column, whatever the stream's length: at most 5 passes over the stream (one to count
the rows).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

DIGIT_BITS = 16
COLLECT_AT = 1 << 16
"""Candidates gathered and partitioned in memory instead of counted bit by bit."""
_SIGN = np.uint64(1 << 63)
_DIGIT_MASK = np.uint64((1 << DIGIT_BITS) - 1)


def sortable_keys(values: np.ndarray) -> np.ndarray:
    """Return uint64 keys of float64 ``values`` that sort as the values do (NaN aside)."""
    bits = np.ascontiguousarray(values, dtype=np.float64).view(np.uint64)
    return np.where(bits & _SIGN, ~bits, bits | _SIGN)


def key_values(keys: np.ndarray) -> np.ndarray:
    """Return the float64 values of keys made by :func:`sortable_keys`."""
    keys = np.asarray(keys, dtype=np.uint64)
    return np.where(keys & _SIGN, keys & ~_SIGN, ~keys).view(np.float64)


@dataclass
class _Target:
    """One order statistic of one column: its rank among the keys that begin with the
    ``known`` leading bits ``prefix``, of which there are ``count``."""

    column: int
    rank: int
    count: int
    prefix: int = 0
    known: int = 0
    key: int | None = None

    def selector(self) -> tuple[int, int, int]:
        return self.column, self.known, self.prefix

    def candidates(self, keys: np.ndarray) -> np.ndarray:
        column = keys[:, self.column]
        if self.known == 0:
            return column
        selected: np.ndarray = column[(column >> np.uint64(64 - self.known))
                                      == np.uint64(self.prefix)]
        return selected

    def narrow(self, histogram: np.ndarray) -> None:
        """Keep the bin of the histogram of the next 16 bits that holds the rank."""
        below = np.cumsum(histogram)
        digit = int(np.searchsorted(below, self.rank, side="right"))
        self.rank -= int(below[digit - 1]) if digit else 0
        self.count = int(histogram[digit])
        self.prefix = (self.prefix << DIGIT_BITS) | digit
        self.known += DIGIT_BITS
        if self.known == 64:
            self.key = self.prefix


def exact_medians(read: Callable[[], Iterable[np.ndarray]]) -> np.ndarray:
    """Return the median of each column of a stream, as ``np.median(axis=0)`` does.

    ``read()`` returns a fresh iterable of float64 chunks of shape (n_i, k), the same
    rows each time (finite values). Returns a (k,) float64 array, NaN where the stream
    has no rows; the unit is the values'.
    """
    rows, width = 0, None
    for chunk in read():
        rows += len(chunk)
        width = chunk.shape[1]
    if width is None:
        return np.zeros(0)
    if rows == 0:
        return np.full(width, np.nan)
    ranks = sorted({(rows - 1) // 2, rows // 2})
    targets = [_Target(column, rank, rows) for column in range(width) for rank in ranks]
    while any(target.key is None for target in targets):
        _one_pass(read, [target for target in targets if target.key is None])
    keys = np.array([target.key for target in targets], dtype=np.uint64)
    middle = key_values(keys).reshape(width, len(ranks))
    medians: np.ndarray = np.mean(middle, axis=1)
    return medians


def _one_pass(read: Callable[[], Iterable[np.ndarray]], targets: list[_Target]) -> None:
    """Read the stream once: gather the candidates of targets with few enough left,
    count the next 16 bits of the others; targets sharing candidates share the work."""
    collect: dict[tuple[int, int, int], list[np.ndarray]] = {
        t.selector(): [] for t in targets if t.count <= COLLECT_AT}
    count = {t.selector(): np.zeros(1 << DIGIT_BITS, dtype=np.int64) for t in targets
             if t.count > COLLECT_AT}
    first = {t.selector(): t for t in targets}
    for chunk in read():
        keys = sortable_keys(chunk)
        for selector, gathered in collect.items():
            gathered.append(first[selector].candidates(keys))
        for selector, histogram in count.items():
            target = first[selector]
            digits = target.candidates(keys) >> np.uint64(64 - target.known - DIGIT_BITS)
            histogram += np.bincount((digits & _DIGIT_MASK).astype(np.intp),
                                     minlength=1 << DIGIT_BITS)
    for target in targets:
        selector = target.selector()
        if selector in collect:
            candidates = np.concatenate(collect[selector])
            target.key = int(np.partition(candidates, target.rank)[target.rank])
        else:
            target.narrow(count[selector])
