"""Low- and high-pass filters (thesis Appendix B.4).

Butterworth filters in second-order sections (scipy.signal). The batch path is
zero-phase (``sosfiltfilt``: forward and backward, no delay, twice the order's
attenuation) for offline analysis; the streaming path is causal (``sosfilt`` with
kept state, as a live robot must), so the two differ by the causal filter's phase
lag and are not meant to agree sample by sample. Both assume a uniform rate: pass
the session's median rate (``contactkit.schemas.timing.sampling_stats``). Cut-offs in Hz.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfilt, sosfilt_zi, sosfiltfilt


def design(kind: str, cutoff_hz: float, rate_hz: float, order: int = 2) -> np.ndarray:
    """Return Butterworth second-order sections; ``kind`` is "low" or "high"."""
    if kind not in ("low", "high"):
        raise ValueError(f"filter kind must be low or high, got {kind!r}")
    if not 0 < cutoff_hz < rate_hz / 2:
        raise ValueError(f"cut-off {cutoff_hz} Hz must lie below Nyquist ({rate_hz / 2} Hz)")
    return butter(order, cutoff_hz, btype=kind, fs=rate_hz, output="sos")


def filter_batch(x: np.ndarray, kind: str, cutoff_hz: float, rate_hz: float,
                 order: int = 2) -> np.ndarray:
    """Zero-phase filter of an (N, k) array along time; returns an array of the same shape."""
    return sosfiltfilt(design(kind, cutoff_hz, rate_hz, order), x, axis=0)


class StreamingFilter:
    """Causal filter fed one sample (a (k,) vector) at a time."""

    def __init__(self, kind: str, cutoff_hz: float, rate_hz: float, channels: int,
                 order: int = 2) -> None:
        self.sos = design(kind, cutoff_hz, rate_hz, order)
        self._zi_unit = sosfilt_zi(self.sos)
        self._state: np.ndarray | None = None
        self.channels = channels
        self.kind = kind

    def update(self, x: np.ndarray) -> np.ndarray:
        """Filter one sample; the first sample initialises the state at steady state
        (a low-pass starts at x, a high-pass at 0)."""
        if self._state is None:
            level = x if self.kind == "low" else np.zeros_like(x)
            self._state = self._zi_unit[:, :, None] * level[None, None, :]
        y, self._state = sosfilt(self.sos, x[None, :], axis=0, zi=self._state)
        return y[0]
