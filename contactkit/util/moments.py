"""Mean and standard deviation of a stream, merged chunk by chunk in bounded memory."""

from __future__ import annotations

import numpy as np


class RunningMoments:
    """Count, mean and sum of squared deviations of a stream's values (or of each
    column of (n, k) chunks), each chunk's own two-pass moments merged into the total
    by Chan, Golub and LeVeque's formula: the result equals ``np.mean`` and ``np.std``
    of the whole stream up to rounding (about 1e-15 relative)."""

    def __init__(self) -> None:
        self.count = 0
        self.mean: np.ndarray | float = 0.0
        self._m2: np.ndarray | float = 0.0

    def add(self, values: np.ndarray) -> None:
        """Merge the next chunk (n,) or (n, k); an empty chunk changes nothing."""
        n = len(values)
        if n == 0:
            return
        mean = values.mean(axis=0)
        m2 = np.square(values - mean).sum(axis=0)
        total = self.count + n
        delta = mean - self.mean
        self.mean = self.mean + delta * (n / total)
        self._m2 = self._m2 + m2 + np.square(delta) * (self.count * n / total)
        self.count = total

    def std(self) -> np.ndarray | float:
        """Return the population standard deviation (``np.std``'s ddof=0) of what was
        added, in the values' unit; NaN when nothing was."""
        if self.count == 0:
            return np.nan
        return np.sqrt(self._m2 / self.count)
