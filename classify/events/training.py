"""Training and evaluating the event classifier on simulated sessions.

Each session goes through the observer, the detector and the event pipeline
without a classifier (:func:`contactkit.classify.events.contact_events.batch_events`, which gives
the streaming pipeline's events), so the classifier learns from exactly what it sees online: windows
aligned to the detector's onset. An event that overlaps the session's ground-truth
contact is labelled with the session's action; every other event (in a ``none``
session, or an after-effect outside the contact) is labelled ``none``. With
``threshold_scales``, each contact is also found with the detector's thresholds scaled
(:meth:`contactkit.features.detector.DetectorConfig.scaled`), and its matched event
there is one more training row: lower thresholds decide the onset earlier in the rise,
as an arm identified from its own motion does (its thresholds are lower), and the
classifier reads the rise from the onset on.

Event-level scoring of a session (:func:`session_outcome`): a contact session is
right when its first event overlapping the contact carries the session's action
(no such event: a *missed* contact, predicted ``none``); a ``none`` session is
right when every event in it says ``none``. Events outside the contact are
counted as *false events*.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from contactkit.classify.events.contact_events import (
    NONE,
    UNKNOWN,
    ContactEvent,
    EventModel,
    WeakDecision,
    batch_events,
)
from contactkit.classify.kinds.kind import ModelOptions
from contactkit.classify.kinds.svm import SVM
from contactkit.classify.schemes import check_two_classes
from contactkit.features.detector import DYNAMIC_FEATURE, DetectorConfig, detect
from contactkit.features.timeseries import TimeseriesChain
from contactkit.schemas import read_session
from contactkit.util.parallel import map_ordered
from contactkit.util.progress import ProgressCallback

MATCH_SLACK_S = 0.1
"""How far [s] an event may lie outside the ground-truth contact and still match it: its
release this long before the start, its onset this long after the end (the detector
decides an onset after the low-pass and ``min_on_s``, some 40 ms into a rise, so a bump
shorter than that is decided after it ended; a 47 ms bump on a moving arm was, 2 ms
after its end, and counted as missed and as a false event)."""


def first_overlapping(events: Sequence[ContactEvent], contact: tuple[float, float]
                      ) -> ContactEvent | None:
    """Return the first of ``events`` that overlaps the ground-truth ``contact`` (start,
    end) [s] widened by :data:`MATCH_SLACK_S` on both sides: its onset no later than
    that after the end, its release (None: still on) no earlier than that before the
    start; None when none does."""
    start, end = contact
    for event in events:
        release = np.inf if event.release_s is None else event.release_s
        if event.onset_s <= end + MATCH_SLACK_S and release >= start - MATCH_SLACK_S:
            return event
    return None


@dataclass
class SessionEvents:
    """One session's events (with feature vectors) and what is known about it: the
    action, the pose group (target pose of a move, else the held pose), the
    ground-truth contact interval [s] (None without contact) and the contact's events
    found with scaled thresholds (``rescaled``)."""

    path: str
    action: str
    group: str
    contact: tuple[float, float] | None
    events: list[ContactEvent]
    rescaled: list[ContactEvent] = field(default_factory=list)
    """The contact's matched event found with the detector's thresholds scaled, once
    per scale that found one (training rows only; not scored)."""

    def matched(self) -> ContactEvent | None:
        """Return the first event overlapping the ground-truth contact, if any."""
        return None if self.contact is None else first_overlapping(self.events, self.contact)

    def rows(self) -> tuple[list[np.ndarray], list[str]]:
        """Return the training rows (feature vectors) and labels of the decided events,
        those of ``rescaled`` labelled with the session's action."""
        match = self.matched()
        xs, ys = [], []
        for event in self.events:
            if event.features is not None:
                xs.append(event.features)
                ys.append(self.action if event is match else NONE)
        for event in self.rescaled:
            if event.features is not None:
                xs.append(event.features)
                ys.append(self.action)
        return xs, ys


def session_events(path: str | Path, detector: DetectorConfig,
                   decide_after_s: Sequence[float],
                   weak: WeakDecision | None = None,
                   threshold_scales: Sequence[float] = ()) -> list[SessionEvents]:
    """Run one session through the observer and the pipeline once per decision delay
    (and ``weak``, when a weak contact is decided: None, at the delay); return one
    :class:`SessionEvents` per delay, with the contact's matched event found with the
    detector's thresholds times each of ``threshold_scales`` in its ``rescaled``."""
    session = read_session(path).complete()
    meta = session.meta
    chain = TimeseriesChain.for_session(meta, path=path)
    t, dq = session.t, session.dq
    detector = detector.for_robot(chain.model.spec)
    features = chain.compute(t, session.q, dq, session.tau, detector.chain_features)
    r = features["r"]
    contact = None
    if session.has("contact") and session.column("contact").any():
        touched = np.flatnonzero(session.column("contact"))
        contact = (float(t[touched[0]]), float(t[touched[-1]]))
    dyn = features.get(DYNAMIC_FEATURE)
    detection = detect(t, r, dq, detector, dyn)
    rescaled = [] if contact is None else [
        detect(t, r, dq, detector.scaled(scale), dyn) for scale in threshold_scales]
    group = meta.target_pose or meta.pose or ""
    out = []
    for delay in decide_after_s:
        matches = [] if contact is None else [
            match for found in rescaled
            if (match := first_overlapping(batch_events(t, r, found, None, delay, weak=weak),
                                           contact)) is not None]
        out.append(SessionEvents(str(path), meta.action, group, contact,
                                 batch_events(t, r, detection, None, delay, weak=weak),
                                 matches))
    return out


def _job(item: tuple[str, DetectorConfig, tuple[float, ...], WeakDecision | None,
                      tuple[float, ...]]) -> list[SessionEvents]:
    return session_events(*item)


def load_session_events(paths: Sequence[str | Path], detector: DetectorConfig,
                        decide_after_s: Sequence[float], workers: int = 1,
                        progress: ProgressCallback | None = None, *,
                        scheduler: str | None = None,
                        weak: WeakDecision | None = None,
                        threshold_scales: Sequence[float] = ()
                        ) -> dict[float, list[SessionEvents]]:
    """Return, per decision delay, every session's events (in the order of ``paths``),
    found in ``workers`` processes or on the Dask ``scheduler``, a weak contact decided
    as ``weak`` says (None: at the delay), each contact also found with the detector's
    thresholds times each of ``threshold_scales`` (see :func:`session_events`)."""
    delays = tuple(float(d) for d in decide_after_s)
    scales = tuple(float(x) for x in threshold_scales)
    per_session = list(map_ordered(_job, [(str(p), detector, delays, weak, scales)
                                          for p in paths],
                                   workers=workers, progress=progress,
                                   scheduler=scheduler))
    return {d: [s[i] for s in per_session] for i, d in enumerate(delays)}


def fit_event_model(sessions: Sequence[SessionEvents], decide_after_s: float,
                    c: float = 10.0, seed: int = 0,
                    weak: WeakDecision | None = None) -> EventModel:
    """Fit the intent classifier (scaled RBF SVM, Platt probabilities) on the
    sessions' event rows (a class with a single row is left out); return the
    :class:`EventModel` with its training range, overall and per class, and ``weak``,
    the rule the sessions' events were decided by (None: all at the delay)."""
    xs, ys = [], []
    for session in sessions:
        rows, labels = session.rows()
        xs += rows
        ys += labels
    X, y = np.asarray(xs), np.asarray(ys)
    names, counts = np.unique(y, return_counts=True)
    keep = np.isin(y, names[counts >= 2])  # a class seen once cannot be calibrated
    X, y = X[keep], y[keep]
    check_two_classes(y, "the event model's training (a class needs at least two events)")
    options = ModelOptions(kind=SVM.name, seed=seed, params={"c": c})
    estimator = SVM.estimator(options, []).fit(X, y)
    classes = [str(name) for name in estimator.classes_]
    return EventModel(estimator, classes, decide_after_s, X.min(axis=0), X.max(axis=0),
                      {name: X[y == name].min(axis=0) for name in classes},
                      {name: X[y == name].max(axis=0) for name in classes}, weak)


def session_outcome(session: SessionEvents, model: EventModel) -> tuple[str, int]:
    """Return the event-level prediction for a session (see the module docstring) and
    its number of false events, classifying each event's features with ``model``."""

    def label(event: ContactEvent) -> str:
        if event.features is None:
            return NONE
        proba = model.estimator.predict_proba(event.features[None, :])[0]
        label = model.classes[int(np.argmax(proba))]
        return UNKNOWN if model.range_check(event.features, label).refused else label

    match = session.matched()
    false_events = sum(1 for e in session.events if e is not match)
    if session.contact is None:
        labels = [label(e) for e in session.events]
        predicted = next((lab for lab in labels if lab != NONE), NONE)
        return predicted, false_events
    return (NONE if match is None else label(match)), false_events
