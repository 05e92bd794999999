"""Event-level scoring of detected contacts against per-sample contact labels.

A labelled *touch* is a run of samples with the label set. A detected event
(onset, release) *covers* a touch when the two intervals overlap; a touch is
*detected* when some event covers it, and its *onset delay* is the first covering
event's onset minus the touch's start (negative when the detector fired first,
e.g. because the label comes from a glove that closes late); a touch covered only
by an event that began before it (two touches in one event) has no delay. An event is *false*
when it overlaps no touch widened by ``tail_s`` on both sides (the observer needs
a few tens of ms to fall after a release, and labels are not exact).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

TAIL_S = 0.3


def touches(t: np.ndarray, label: np.ndarray) -> list[tuple[float, float]]:
    """Return the labelled touches as (start, end) times [s]: runs of ``label`` True."""
    edges = np.diff(np.concatenate([[0], label.astype(int), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [(float(t[a]), float(t[min(b, len(t) - 1)])) for a, b in zip(starts, ends, strict=True)]


@dataclass
class EventScore:
    """Counts and delays of one or more recordings: ``touches`` (longer than the
    minimum duration), ``detected``, ``events``, ``false_events``, ``no_contact_s``
    [s] of unlabelled time, and per detected touch ``delays_s`` [s]."""

    touches: int = 0
    detected: int = 0
    events: int = 0
    false_events: int = 0
    no_contact_s: float = 0.0
    delays_s: list[float] = field(default_factory=list)

    def __add__(self, other: EventScore) -> EventScore:
        return EventScore(self.touches + other.touches, self.detected + other.detected,
                          self.events + other.events, self.false_events + other.false_events,
                          self.no_contact_s + other.no_contact_s,
                          self.delays_s + other.delays_s)

    @property
    def false_per_min(self) -> float:
        """False events per minute of no-contact time."""
        return self.false_events / (self.no_contact_s / 60.0) if self.no_contact_s else 0.0

    def delay_ms(self, percentile: float) -> float:
        """Return a percentile of the onset delay [ms] (NaN without detected touches)."""
        if not self.delays_s:
            return float("nan")
        return 1000.0 * float(np.percentile(self.delays_s, percentile))


def score_events(t: np.ndarray, label: np.ndarray, events: list[tuple[float, float]],
                 min_touch_s: float = 0.2, tail_s: float = TAIL_S) -> EventScore:
    """Score detected ``events`` ((onset, release) times [s]) against the per-sample
    ``label`` of one recording; only touches longer than ``min_touch_s`` count."""
    labelled = touches(t, label)
    long = [(a, b) for a, b in labelled if b - a > min_touch_s]
    score = EventScore(touches=len(long), events=len(events))
    for start, end in long:
        covering = [on for on, off in events if on <= end and off >= start]
        if covering:
            score.detected += 1
            own = [on for on in covering if on >= start - tail_s]
            if own:
                score.delays_s.append(own[0] - start)
    for on, off in events:
        if not any(on <= b + tail_s and off >= a - tail_s for a, b in labelled):
            score.false_events += 1
    steps = np.diff(t)
    score.no_contact_s = float(steps[~label[1:]].sum())
    return score
