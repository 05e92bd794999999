"""Interaction windows (thesis Appendix A): where in a session the contact is.

* ``fixed``: T seconds centred on the planned interaction time T_e, optionally
  shifted (A.1.1).
* ``planned``: T seconds starting at T_e (the fallback of Algorithm 4).
* ``difference`` and ``change``: Algorithm 4 (A.1.2). A signal s(t) is the sum
  over joints of a timeseries squared (the thesis uses tau_i^2); its standard
  deviation sigma is measured in a calibration window [T_e - 2, T_e - 2 + T]. From
  the end of the calibration window, step forward one sample at a time until
  |s(t_a) - s(t_b)| > c * sigma (c = 5.5):

  - difference: t_a = T_e - T fixed, t_b = t_ce + delta;
  - change: t_a = t_ce + delta, t_b = t_a + 0.15 s.

  The window is [t_b, t_b + T]. If nothing is found, it falls back to the planned
  window [T_e, T_e + T].

Calibration. The thesis's 0.5 s calibration window is short: on the real Panda
recording in free, fast motion (``shared/reference``) it raises a false detection
at almost every planned time we tried, because the motion alone changes s by more
than 5.5 sigma of half a second. The default calibration, ``"pre-contact"``, uses
everything the robot has seen before the interaction could start: sigma and the
reference level (the mean of s) come from [t_0 + 0.5 s, T_e - T], and the search
starts at T_e - T. On that recording it detects nothing for planned times from 6 s
on, while contacts in held poses stand out as clearly as before.
``calibration="thesis"`` reproduces Algorithm 4 exactly (reference s(t_a)).

The signal is the measured torque by default, as in the thesis; ``signal="r"``
uses the observer residual. Every method returns the window and how it was found.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from contactkit.errors import check_choice
from contactkit.schemas import InputError
from contactkit.util.moments import RunningMoments

METHODS = ("fixed", "planned", "difference", "change")
THRESHOLD_C = 5.5
CHANGE_LAG_S = 0.15
CALIBRATION_LEAD_S = 2.0
SETTLE_S = 0.5
CALIBRATIONS = ("pre-contact", "thesis")


@dataclass(frozen=True)
class Window:
    """A window [start_s, end_s) in session time, the method asked for, whether the
    contact onset was detected (``found``) or the planned time was used, and the
    detected onset [s] (None when not found)."""

    start_s: float
    end_s: float
    method: str
    found: bool
    onset_s: float | None

    def mask(self, t: np.ndarray) -> np.ndarray:
        """Return a boolean mask of the samples of ``t`` inside the window."""
        return (t >= self.start_s) & (t < self.end_s)

    def as_dict(self) -> dict:
        """Return the window as plain values."""
        return asdict(self)


@dataclass(frozen=True)
class WindowSpec:
    """How to find windows: ``method`` (one of METHODS), length T [s], ``shift`` [s]
    for fixed windows, threshold ``c``, and the ``signal`` timeseries summed
    squared by the detection methods ("tau", thesis; or "r", observer residual), and
    the ``calibration`` of sigma ("pre-contact" or "thesis", see the module doc)."""

    method: str = "difference"
    length_s: float = 0.5
    shift_s: float = 0.0
    c: float = THRESHOLD_C
    signal: str = "tau"
    calibration: str = "pre-contact"

    def __post_init__(self) -> None:
        check_choice("calibration", self.calibration, CALIBRATIONS)
        check_choice("window method", self.method, METHODS)
        if self.length_s <= 0:
            raise InputError(f"window length must be positive, got {self.length_s} s")


def detection_signal(values: np.ndarray) -> np.ndarray:
    """Return s(t) = sum_i x_i(t)^2 for an (N, 7) timeseries."""
    return np.einsum("ki,ki->k", values, values)


def find_window(t: np.ndarray, planned_at_s: float, spec: WindowSpec,
                signal_values: np.ndarray | None = None) -> Window:
    """Return the window of one session.

    ``t`` (N,) [s]; ``signal_values`` (N, 7) is the timeseries named by
    ``spec.signal`` (needed by the difference and change methods).
    """
    length = spec.length_s
    if spec.method == "fixed":
        start = planned_at_s - length / 2 + spec.shift_s
        return Window(start, start + length, "fixed", False, None)
    planned = Window(planned_at_s, planned_at_s + length, spec.method, False, None)
    if spec.method == "planned":
        return planned
    if signal_values is None:
        raise ValueError("the difference and change methods need the signal values")
    search = WindowSearch(planned_at_s, spec)
    search.feed(t, signal_values)
    return search.finish()


class WindowSearch:
    """The difference and change methods' search over a session streamed in
    consecutive chunks (:func:`find_window` feeds it the whole session as one), in
    memory bounded by the method's look-ahead (0.15 s for ``change``; for the thesis
    calibration of ``difference``, the samples between the calibration's end and the
    reference time), not by the session's length.

    Feed each chunk's ``t`` [s] and signal values (n, 7) to :meth:`feed`, then call
    :meth:`finish` for the window. :attr:`window` is known as soon as the onset is
    found (or the planned fallback is certain); :attr:`undecided_from_s` is the earliest
    time that may still become the onset. Fed in several chunks, the calibration's mean
    and standard deviation are merged chunk by chunk (equal to the one-chunk values to
    about 1e-15 relative; a sample within that of the threshold could fall the other
    way).
    """

    def __init__(self, planned_at_s: float, spec: WindowSpec) -> None:
        self.planned_at_s = planned_at_s
        self.spec = spec
        self.window: Window | None = None
        if spec.method in ("fixed", "planned"):
            self.window = find_window(np.zeros(0), planned_at_s, spec)
        self._calibration = RunningMoments()
        self._span: tuple[float, float] | None = None
        self._threshold: float | None = None
        self._reference: float | None = None
        self._last_s = self._last_t = math.nan
        self._pending_t = np.zeros(0)
        self._pending_s = np.zeros(0)

    @property
    def undecided_from_s(self) -> float:
        """The earliest time [s] that may still become the onset (inf once decided)."""
        if self.window is not None:
            return math.inf
        if len(self._pending_t):
            return float(self._pending_t[0])
        if self._threshold is not None:  # every candidate fed so far is decided
            return math.nextafter(self._last_t, math.inf)
        return -math.inf if self._span is None else self._span[1]

    def _planned(self) -> Window:
        return Window(self.planned_at_s, self.planned_at_s + self.spec.length_s,
                      self.spec.method, False, None)

    def feed(self, t: np.ndarray, signal_values: np.ndarray) -> None:
        """Take the next chunk: ``t`` (n,) [s] after the previous chunk's, the signal's
        values (n, 7)."""
        if self.window is not None or len(t) == 0:
            return
        s = detection_signal(signal_values)
        spec, length = self.spec, self.spec.length_s
        if self._span is None:
            if spec.calibration == "thesis":
                start = self.planned_at_s - CALIBRATION_LEAD_S
                self._span = (start, start + length)
            else:
                self._span = (float(t[0]) + SETTLE_S, self.planned_at_s - length)
        t_cs, t_ce = self._span
        self._calibration.add(s[(t >= t_cs) & (t <= t_ce)])
        if spec.calibration == "thesis" and self._reference is None:
            at = np.flatnonzero(t >= self.planned_at_s - length)
            self._reference = float(s[at[0]]) if at.size else None
        self._last_s, self._last_t = float(s[-1]), float(t[-1])
        candidates = t > t_ce
        if not candidates.any():
            return
        if self._threshold is None:
            if self._calibration.count < 2:
                self.window = self._planned()
                return
            self._threshold = spec.c * float(self._calibration.std())
        self._pending_t = np.concatenate([self._pending_t, t[candidates]])
        self._pending_s = np.concatenate([self._pending_s, s[candidates]])
        self._search(final=False)

    def _search(self, final: bool) -> None:
        """Look for the first hit among the pending candidates; drop those decided."""
        pending_t, pending_s, threshold = self._pending_t, self._pending_s, self._threshold
        if self.spec.method == "difference":
            if self.spec.calibration == "thesis":
                reference = self._last_s if final and self._reference is None \
                    else self._reference
                if reference is None:  # the reference sample is still to come
                    return
            else:
                reference = float(self._calibration.mean)
            hits = np.flatnonzero(np.abs(reference - pending_s) > threshold)
            onset_index, decided = (hits[0] if hits.size else None), len(pending_t)
        else:
            b_index = np.searchsorted(pending_t, pending_t + CHANGE_LAG_S)
            decided = int(np.searchsorted(b_index, len(pending_t)))
            a_index = np.arange(decided)
            hits = b_index[:decided][np.abs(pending_s[a_index] - pending_s[b_index[:decided]])
                                     > threshold]
            onset_index = hits[0] if hits.size else None
        if onset_index is not None:
            onset = float(pending_t[onset_index])
            self.window = Window(onset, onset + self.spec.length_s, self.spec.method, True,
                                 onset)
        self._pending_t, self._pending_s = pending_t[decided:], pending_s[decided:]

    def finish(self) -> Window:
        """Return the window of the whole session fed so far (the planned window when
        no onset was found)."""
        if self.window is None and self._threshold is not None:
            self._search(final=True)
        return self.window or self._planned()
