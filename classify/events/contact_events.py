"""Contact events: detect, decide once, hold until release. Batch and streaming.

Per sample, the residual r and joint velocity dq go through the contact detector
(:mod:`contactkit.features.detector`). When it reports an onset, the pipeline waits
``decide_after_s`` (or until the release, if that comes first) and classifies the
intent *once*, from the samples between onset - ``PRE_S`` and the decision, with
r taken relative to the detector's baseline frozen at onset. A weak contact waits
longer (:class:`WeakDecision`): one whose detector score has not reached
``weak.score`` by then is decided ``weak.decide_after_s`` after its onset (or at its
release, if that comes first). That label is held
until the detector reports the release; then the event is complete. Without a
detected contact the output is ``none``; between onset and decision it is
``undecided``; without an intent classifier a decided event is ``contact``. Event
features far outside the classifier's training range (by more than
:data:`RANGE_SLACK` of it) give the label ``unknown`` and set ``out_of_range``,
instead of a confident class, unless one class explains them (the range rule,
:meth:`EventModel.range_check`): every feature beyond the range measures strength
(a torque or its rate: a harder push, not another shape), lies on the side where
the decided class reaches furthest among the training examples (a shove stronger
than any training shove), and the event's overall strength stays within
:data:`BEYOND_FACTOR` of that class's extreme (not another arm's scale). Such an
event keeps its class, and says so in ``beyond_range`` (``above`` or ``below``) and
``beyond_features``; a refused one names its features there too. A gap in the stream
(a step over :data:`contactkit.features.timing.RESTART_STEP_S`) restarts the detector;
an event still open then is released (and, if undecided, decided) at the last sample
before the gap, and no sample before a gap enters an event after it.

Nothing looks ahead: every output at sample k uses samples up to k only, and the
batch entry points (:func:`stream_events`) feed the same streaming object sample by
sample, so batch and streaming agree exactly. :meth:`EventPipeline.update_block`
(replay) runs the detector vectorised over a chunk and steps only the samples of an
event: the same labels and events (tests/features/test_block_paths.py).

Event features (all from e = r - baseline, Nm, and seconds; none from dq, tau or
q, which grow with motion and do not transfer from the simulator to a real robot):
per joint the peak |e| and |e| at the decision; over the joints the norm |e|: its
peak, mean, value at the decision, value at the decision over the peak, time from
onset to the peak, mean absolute rate of change, and the window length; and the
shape of its rise: the norm every 25 ms from 50 ms before (the window's first
sample) to 150 ms after the onset (the window's last value beyond its end), as it
is and divided by the largest of the nine, so that a quick shove and a slowly
building adjust differ whatever the operator's strength (leave-one-pose-out on the
default model's simulated sessions, decided at 150 ms: balanced accuracy 86.8 ->
90.8 %). The first sample tells how far the contact had built up before the
detector saw it, which a slow adjust has and a sudden shove has not: sampling the
rise from 50 ms before the onset instead of 25 ms took the intent of the detected
contacts, balanced, on 12 thesis datasets of seeds the model never saw (11 of them
on robot instances it never saw either) from 96.4 % on average, 92.2 % at the
lowest, to 98.1 % and 95.5 %.

Contact isolation (the touched link, point and force) works on the detector's own
deviation e = rf - b, the residual low-passed by the detector (``smooth_s``, 30 ms)
less the baseline frozen at onset, not on the raw residual: the estimate at the
peak of |e| is made where |e| is largest, and on the raw residual that sample is
the one where the observer's sample-to-sample noise (from the velocity noise in
the momentum) happens to add most to the touch, so its error pattern drowns a weak
touch's. Simulated robot instance 22, 64 sessions each of ``thesis-static`` /
``thesis-dynamic``, link right at the peak of the detected contacts: raw residual
23/31, 22/31, 23/31 (nominal, identified, true parameters) at rest and 19/26,
21/29, 21/29 in motion; the detector's deviation 27/31, 28/31, 28/31 at rest and
20/26, 28/29, 28/29 in motion.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from contactkit.classify.kinds.fast import fast_predictor
from contactkit.errors import InputError
from contactkit.features.detector import (
    DYNAMIC_FEATURE,
    N_JOINTS,
    Detection,
    Detector,
    DetectorConfig,
    DetectorState,
    detect,
)
from contactkit.features.isolation import (
    ContactEstimate,
    ContactIsolator,
    EventTrack,
    robot_isolator,
)
from contactkit.features.timeseries import ChainConfig, TimeseriesChain
from contactkit.robots.dynamics import RobotChoice
from contactkit.schemas import Session

PRE_S = 0.05  # s of samples before the onset in the decision window
DEFAULT_DECIDE_AFTER_S = 0.15
RANGE_SLACK = 0.5  # a feature beyond its training range by this share of the range is out
BEYOND_FACTOR = 2.5
"""A strength feature beyond the training range keeps the class that reaches furthest on
its side while the overall strength features (:data:`SCALE`) stay within this multiple
of that class's extreme (its largest value above, its smallest divided by this below):
a person pushes harder than any simulated shove (at most about 170 N), not 2.5 times
harder; a 10 times larger event is another arm's scale or a unit error."""
NONE, UNDECIDED, UNKNOWN = "none", "undecided", "unknown"
RISE_S = np.arange(-2, 7) * 0.025  # s after onset at which the rise is sampled
EVENT_FEATURES = ([f"peak_abs_e_{j}" for j in range(1, N_JOINTS + 1)]
                  + [f"final_abs_e_{j}" for j in range(1, N_JOINTS + 1)]
                  + ["peak_norm", "mean_norm", "final_norm", "final_over_peak",
                     "time_to_peak", "mean_abs_rate", "window_s"]
                  + [f"norm_at_{1000 * s:+.0f}ms" for s in RISE_S]
                  + [f"relative_norm_at_{1000 * s:+.0f}ms" for s in RISE_S])
SCALE = np.array([name.startswith("norm_at_")
                  or name in ("peak_norm", "mean_norm", "final_norm", "mean_abs_rate")
                  for name in EVENT_FEATURES])
"""Which event features measure the event's overall strength (the norm |e| in Nm, its
rate in Nm/s)."""
STRENGTH = SCALE | np.array([name.startswith(("peak_abs_e_", "final_abs_e_"))
                             for name in EVENT_FEATURES])
"""Which event features measure strength: the overall ones (:data:`SCALE`) and each
joint's |e| [Nm]. They grow with how hard a person pushes, while the others (ratios,
times, the rise's shape) do not."""


@dataclass(frozen=True)
class WeakDecision:
    """When a weak contact is decided: an event whose detector score (|e| over the
    threshold, the largest since its onset) is still below ``score`` when the decision
    delay is up waits until ``decide_after_s`` [s] after its onset (or its release, if
    that comes first); a clear one is decided at the delay.

    Why: at a score of a few thresholds the 150 ms after the onset hold little more than
    the noise can hide, and a sudden push on the base (a shove through joint 1's axis,
    a few Nm at most) looks like the start of a slow adjust; the next 200 ms show
    whether it holds (an adjust) or falls (a shove's short hold), while a clear contact
    is told at once. On 14 simulated thesis datasets of seeds the default model never
    saw (12 on robot instances it never saw), 16 % of the detected contacts waited
    (score 3, 0.35 s); errors on the detected contacts, without the rule -> with it:
    shoves 10 -> 4 of 306, adjusts 4 -> 4 of 277, bumps 5 -> 7 of 285.
    """

    score: float = 3.0
    decide_after_s: float = 0.35

    def __post_init__(self) -> None:
        if not (np.isfinite(self.score) and self.score >= 0):
            raise InputError(f"a weak contact's score must be >= 0, got {self.score}")
        if not 0 <= self.decide_after_s <= 5:
            raise InputError("a weak contact's decision delay must lie in 0..5 s, got "
                             f"{self.decide_after_s}")

    def to_dict(self) -> dict[str, float]:
        """Return the JSON-ready settings."""
        return {"score": self.score, "decide_after_s": self.decide_after_s}

    @classmethod
    def from_dict(cls, doc: dict) -> WeakDecision:
        """Rebuild from :meth:`to_dict`'s document."""
        return cls(float(doc["score"]), float(doc["decide_after_s"]))


@dataclass(frozen=True)
class RangeCheck:
    """The range rule's verdict on one event (:meth:`EventModel.range_check`):
    ``refused`` (label ``unknown``), ``side`` the features lie beyond the training range
    on (``above``, ``below`` or ``both``; None within it) and their names."""

    refused: bool = False
    side: str | None = None
    features: tuple[str, ...] = ()


def event_features(t: np.ndarray, e: np.ndarray, onset_s: float) -> np.ndarray:
    """Return the event feature vector (see the module docstring) of a decision window:
    times ``t`` (n,) [s] from ``PRE_S`` before the onset, deviations ``e`` (n, 7) [Nm],
    onset time ``onset_s`` [s]."""
    norm = np.linalg.norm(e, axis=1)
    peak_at = int(np.argmax(norm))
    peak = float(norm[peak_at])
    span = float(t[-1] - t[0])
    rate = float(np.abs(np.diff(norm)).sum() / span) if span > 0 else 0.0
    rise = np.interp(np.clip(onset_s + RISE_S, t[0], t[-1]), t, norm)
    top = float(rise.max())
    return np.concatenate([np.abs(e).max(axis=0), np.abs(e[-1]),
                           [peak, float(norm.mean()), float(norm[-1]),
                            float(norm[-1] / peak) if peak > 0 else 0.0,
                            float(t[peak_at] - t[0]), rate, span],
                           rise, rise / top if top > 0 else np.zeros_like(rise)])


@dataclass
class EventModel:
    """What the pipeline needs besides the detector: the intent classifier (anything
    with ``predict_proba``), its classes, the decision delay [s], the per-feature
    training range (``low``, ``high``) that flags out-of-range events, each class's
    own (``class_low``, ``class_high``: class name to its per-feature extremes; None in
    model files written before them, whose events beyond the range are all
    ``unknown``) and when a weak contact is decided (``weak``; None in model files
    written before it, which decide every event at the delay)."""

    estimator: Any  # a fitted scikit-learn classifier
    classes: list[str]
    decide_after_s: float = DEFAULT_DECIDE_AFTER_S
    low: np.ndarray = field(default_factory=lambda: np.full(len(EVENT_FEATURES), -np.inf))
    high: np.ndarray = field(default_factory=lambda: np.full(len(EVENT_FEATURES), np.inf))
    class_low: dict[str, np.ndarray] | None = None
    class_high: dict[str, np.ndarray] | None = None
    weak: WeakDecision | None = None

    def meta(self) -> dict:
        """Return the JSON-ready settings (everything but the estimator)."""
        doc = {"classes": list(self.classes), "decide_after_s": self.decide_after_s,
               "features": EVENT_FEATURES, "low": self.low.tolist(),
               "high": self.high.tolist()}
        if self.class_low is not None and self.class_high is not None:
            doc["class_low"] = {c: v.tolist() for c, v in self.class_low.items()}
            doc["class_high"] = {c: v.tolist() for c, v in self.class_high.items()}
        if self.weak is not None:
            doc["weak"] = self.weak.to_dict()
        return doc

    @classmethod
    def from_meta(cls, estimator: object, doc: dict) -> EventModel:
        """Rebuild from :meth:`meta`'s document and the estimator."""
        if list(doc.get("features", [])) != EVENT_FEATURES:
            raise InputError("the event classifier was trained on other event features")
        per_class = {key: {c: np.asarray(v, float) for c, v in doc[key].items()}
                     for key in ("class_low", "class_high") if key in doc}
        return cls(estimator, list(doc["classes"]), float(doc["decide_after_s"]),
                   np.asarray(doc["low"], float), np.asarray(doc["high"], float),
                   per_class.get("class_low"), per_class.get("class_high"),
                   WeakDecision.from_dict(doc["weak"]) if "weak" in doc else None)

    def out_of_range(self, x: np.ndarray) -> bool:
        """Return whether a feature vector lies far outside the training range (by more
        than :data:`RANGE_SLACK` of it), whatever the range rule then decides."""
        slack = RANGE_SLACK * (self.high - self.low)
        return bool(((x < self.low - slack) | (x > self.high + slack)).any())

    def range_check(self, x: np.ndarray, label: str) -> RangeCheck:
        """Return the range rule's verdict (see the module docstring) on feature vector
        ``x`` that the classifier gives class ``label``."""
        slack = RANGE_SLACK * (self.high - self.low)
        above, below = x > self.high + slack, x < self.low - slack
        beyond = np.flatnonzero(above | below)
        if not beyond.size:
            return RangeCheck()
        # a vector with features past the event features (an experiment's extra inputs)
        # names those by position; they are not strength features
        names = tuple(EVENT_FEATURES[i] if i < len(EVENT_FEATURES) else f"feature {i}"
                      for i in beyond)
        if above.any() and below.any():
            return RangeCheck(True, "both", names)
        side = "above" if above.any() else "below"
        strength = np.zeros(len(x), bool)
        strength[:min(len(x), len(STRENGTH))] = STRENGTH[:len(x)]
        if (self.class_low is None or self.class_high is None or label not in self.classes
                or not strength[beyond].all()):
            return RangeCheck(True, side, names)
        extremes = np.array([(self.class_high if side == "above" else self.class_low)[c]
                             for c in self.classes])[:, beyond]
        furthest = extremes.argmax(axis=0) if side == "above" else extremes.argmin(axis=0)
        # How far is judged on the overall strength: how a push shares out over the
        # joints depends on where it lands, and a push on the hand a little stronger than
        # any training shove loads one wrist joint several times more than any did.
        own = extremes[self.classes.index(label)]
        within = x[beyond] <= BEYOND_FACTOR * own if side == "above" else \
            x[beyond] >= own / BEYOND_FACTOR
        explained = bool((furthest == self.classes.index(label)).all()
                         and within[SCALE[beyond]].all())
        return RangeCheck(not explained, side, names)


@dataclass
class ContactEvent:
    """One detected contact: onset, decision and release times [s] (release None while
    it lasts), the held label, the class probabilities at the decision, whether its
    features were out of the training range so that its label is ``unknown``
    (``out_of_range``), the side they lie beyond it on and their names, refused or
    kept (``beyond_range``: ``above``, ``below`` or ``both``, None within it;
    ``beyond_features``; :meth:`EventModel.range_check`), and its peak detector score. With contact
    isolation (:mod:`contactkit.features.isolation`): the touched link, point and force
    at the decision (``contact_at_decision``) and at the peak of the residual
    (``contact_at_peak``, so far while the event lasts), and the estimates during the
    event (``contact_track``, at 50 Hz, about 1.7 kB each; empty from a pipeline made
    with ``keep_track=False``, which hands each estimate over in its
    :class:`EventOutput` instead)."""

    onset_s: float
    decision_s: float | None = None
    release_s: float | None = None
    label: str = UNDECIDED
    probabilities: dict[str, float] = field(default_factory=dict)
    out_of_range: bool = False
    peak_score: float = 0.0
    contact_at_decision: ContactEstimate | None = None
    contact_at_peak: ContactEstimate | None = None
    features: np.ndarray | None = field(default=None, repr=False)
    contact_track: list[ContactEstimate] = field(default_factory=list, repr=False)
    beyond_range: str | None = None
    beyond_features: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        """Return the event as a JSON-ready dict (without its feature vector and its
        track of estimates)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)
               if f.name not in ("features", "contact_track")}
        out["probabilities"] = dict(self.probabilities)
        out["beyond_features"] = list(self.beyond_features)
        for name in ("contact_at_decision", "contact_at_peak"):
            out[name] = None if out[name] is None else out[name].to_dict()
        return out


@dataclass
class EventOutput:
    """The pipeline's answer at one sample: the current ``label`` (none, undecided, a
    class or unknown), the detector ``score``, ``contact``, the event that was
    just started, decided or released at this sample (else None), and the ``estimate``
    of the event's contact track made at this sample (else None; with contact
    isolation, one every 1 / :data:`~contactkit.features.isolation.DEFAULT_TRACK_HZ` s
    of an event)."""

    label: str
    score: float
    contact: bool
    started: ContactEvent | None = None
    decided: ContactEvent | None = None
    released: ContactEvent | None = None
    estimate: ContactEstimate | None = None


@dataclass
class BlockEvents:
    """The pipeline's answer for a chunk of samples (:meth:`EventPipeline.update_block`):
    per sample the ``labels`` (n,), the detector ``score`` (n,) and ``contact`` (n,)
    bool, and the :class:`EventOutput` of each sample of an event as (row, output) in
    order (rows outside events are ``none`` with nothing started, decided or
    released)."""

    labels: np.ndarray
    score: np.ndarray
    contact: np.ndarray
    steps: list[tuple[int, EventOutput]] = field(default_factory=list)


class EventPipeline:
    """Streaming detect -> decide -> hold (see the module docstring).

    ``detector`` and ``model`` are the contact detector's settings and the intent
    classifier, ``decide_after_s`` [s] the decision delay (None: the model's, or
    ``DEFAULT_DECIDE_AFTER_S`` without a model), ``weak`` when a weak contact is
    decided (None: the model's rule; without a model or a rule every event is decided
    at the delay), and
    ``isolator`` estimates the touched link, point and force. With ``keep_track``
    (the default) each event keeps its estimates in ``contact_track``; without it the
    events' tracks stay empty and each estimate is only handed over in the
    :class:`EventOutput` of its sample, so that memory does not grow with the time
    spent in contact (a replay logs them as they come).
    """

    def __init__(self, detector: DetectorConfig | None = None, model: EventModel | None = None,
                 decide_after_s: float | None = None,
                 isolator: ContactIsolator | None = None, keep_track: bool = True,
                 weak: WeakDecision | None = None) -> None:
        if not isinstance(keep_track, bool):
            raise InputError(f"keep_track must be True or False, got {keep_track!r}")
        self.keep_track = keep_track
        self.detector = Detector(detector)
        self.isolator = isolator
        self._track: EventTrack | None = None
        self.model = model
        self.decide_after_s = (decide_after_s if decide_after_s is not None else
                               model.decide_after_s if model is not None else
                               DEFAULT_DECIDE_AFTER_S)
        if not 0 <= self.decide_after_s <= 5:
            raise InputError(f"decision delay must lie in 0..5 s, got {self.decide_after_s}")
        self.weak = weak if weak is not None else None if model is None else model.weak
        self._delay = self.decide_after_s
        """The current event's decision delay [s]: ``decide_after_s``, or the weak
        rule's once the event is found weak at it."""
        self._predict = None if model is None else fast_predictor(model.estimator)
        self.events: list[ContactEvent] = []
        self._recent: deque[tuple[float, np.ndarray]] = deque()
        self._window: list[tuple[float, np.ndarray]] = []
        self._baseline = np.zeros(N_JOINTS)
        self._last_q: np.ndarray | None = None
        self._last_e: tuple[np.ndarray, np.ndarray | None] | None = None
        """The current event's last isolated sample: the detector's e and threshold [Nm]."""
        self.current: ContactEvent | None = None

    def _weak_delay(self, peak_score: float) -> float | None:
        """Return the later decision delay [s] of an event due at the decision delay with
        this peak detector score so far, if it is weak; None if it is decided now."""
        weak = self.weak
        if (weak is None or self._delay != self.decide_after_s
                or weak.decide_after_s <= self.decide_after_s or peak_score >= weak.score):
            return None
        return weak.decide_after_s

    def _decide(self, t: float) -> ContactEvent:
        event = self.current
        assert event is not None  # decided during an event
        times = np.array([s for s, _ in self._window])
        e = np.array([r for _, r in self._window]) - self._baseline
        event.decision_s = t
        event.features = x = event_features(times, e, event.onset_s)
        if self.model is None:
            event.label = "contact"
            return event
        assert self._predict is not None  # made with the model
        proba = self._predict(x[None, :])[0]
        event.probabilities = {c: float(p) for c, p in zip(self.model.classes, proba,
                                                           strict=True)}
        label = self.model.classes[int(np.argmax(proba))]
        check = self.model.range_check(x, label)
        event.out_of_range = check.refused
        event.beyond_range, event.beyond_features = check.side, list(check.features)
        event.label = UNKNOWN if check.refused else label
        return event

    def _isolate(self, t: float, q: np.ndarray | None, e: np.ndarray, decided: bool,
                 released: bool, threshold: np.ndarray | None = None
                 ) -> ContactEstimate | None:
        """Feed one sample of the current event to its isolation track: the detector's
        deviation ``e`` [Nm] (7,) from its baseline frozen at onset (the low-passed
        residual's, see the module docstring) and its threshold [Nm] at that sample
        (which weighs the joints); store the estimate at the decision and at the
        peak. Return the track's estimate made at this sample (None: none is due, or
        no isolation)."""
        if self._track is None or q is None:
            return None
        self._last_e = e, threshold
        made = self._track.update(t, q, e, threshold)
        event = self.current
        assert event is not None  # a track is an event's
        if decided:
            event.contact_at_decision = self._track.at(t, q, e, threshold)
        event.contact_track = self._track.track
        event.contact_at_peak = self._track.finish() if released else self._track.peak
        return made

    def update(self, t: float, r: np.ndarray, dq: np.ndarray,
               q: np.ndarray | None = None, dyn: np.ndarray | None = None) -> EventOutput:
        """Feed one sample: time [s], residual r [Nm] (7,), joint velocity [rad/s] (7,),
        for contact isolation joint position q [rad] (7,), and the chain's dynamic
        torque scale ``tau_dyn`` [Nm] (7,) when the detector reads it (None: 0)."""
        t = float(t)  # a NumPy scalar's arithmetic costs several times a float's
        state = self.detector.update(t, r, dq, dyn)
        return self._step(t, np.array(r, dtype=float), q, state,
                          self.detector.baseline if state.onset else None)

    def update_block(self, t: np.ndarray, r: np.ndarray, dq: np.ndarray,
                     q: np.ndarray | None = None, dyn: np.ndarray | None = None
                     ) -> BlockEvents:
        """Feed a chunk of samples at once: times ``t`` (n,) [s], residual ``r`` [Nm],
        joint velocity ``dq`` [rad/s], for contact isolation joint position ``q``
        [rad], and the dynamic torque scale ``dyn`` [Nm] (None: 0) (n, 7). The same as
        :meth:`update` sample by sample, with the detector run vectorised over the chunk
        (:meth:`Detector.run`) and per-sample work only on the samples of an event."""
        n = len(t)
        found = self.detector.run(t, r, dq, dyn)
        assert found.onset is not None and found.release is not None  # run gives them
        out = BlockEvents(np.full(n, NONE, dtype=object), found.score, found.contact)
        onsets = np.flatnonzero(found.onset)
        restarted, cuts = set(found.restarts), set(found.cuts)
        k, stepped, carried = 0, -1, list(self._recent)
        while k < n:
            if self.current is None:
                later = onsets[onsets >= k]
                if not later.size:
                    break
                k = int(later[0])
            if stepped != k - 1:
                self._recent = _recent_before(carried, t, r, k, found.restarts)
            state = DetectorState(bool(found.contact[k]), float(found.score[k]),
                                  bool(found.onset[k]), bool(found.release[k]), found.e[k],
                                  found.threshold[k], k in restarted, k in cuts)
            step = self._step(float(t[k]), np.array(r[k], dtype=float),
                              None if q is None else q[k], state, found.baseline[k])
            out.labels[k] = step.label
            out.steps.append((k, step))
            stepped, k = k, k + 1
        if n and stepped != n - 1:
            self._recent = _recent_before(carried, t, r, n, found.restarts)
            self._last_q = None if q is None else q[-1]
        return out

    def _step(self, t: float, r: np.ndarray, q: np.ndarray | None, state: DetectorState,
              baseline: np.ndarray | None) -> EventOutput:
        """Advance the pipeline by one sample (time [s], residual [Nm], q [rad] or None)
        given the detector's ``state`` there and its ``baseline`` [Nm] after it (read at
        an onset only: None will do elsewhere). Returns the pipeline's output there."""
        sample = (t, r)
        out = EventOutput(NONE, state.score, state.contact)
        if state.cut:
            self._cut(out)
        if state.restarted:
            self._recent.clear()
        self._last_q = q
        if state.onset:
            self.current = out.started = ContactEvent(onset_s=t)
            assert baseline is not None  # given at an onset
            self._baseline = baseline.copy()
            self._delay = self.decide_after_s
            self._window = [s for s in self._recent if s[0] >= t - PRE_S]
            self._track = None if self.isolator is None else EventTrack(
                self.isolator, t, keep=self.keep_track)
        self._recent.append(sample)
        while self._recent and self._recent[0][0] < t - PRE_S:
            self._recent.popleft()
        event = self.current
        if event is None:
            return out
        event.peak_score = max(event.peak_score, state.score)
        if event.decision_s is None:
            self._window.append(sample)
            due = t - event.onset_s >= self._delay - 1e-12
            later = self._weak_delay(event.peak_score) if due and not state.release else None
            if later is not None:
                self._delay = later
                due = t - event.onset_s >= later - 1e-12
            if due or state.release:
                out.decided = self._decide(t)
        if self._track is not None:  # reading e or the threshold of a live sample computes it
            out.estimate = self._isolate(t, q, np.array(state.e, dtype=float),
                                         out.decided is not None, state.release,
                                         state.threshold)
        out.label = event.label
        if state.release:
            event.release_s = t
            self.events.append(event)
            out.released, self.current = event, None
        return out

    def _cut(self, out: EventOutput) -> None:
        """Release the current event at the last sample before a gap (deciding it there
        if it is undecided), as the detector's release at that sample would have."""
        event = self.current
        assert event is not None  # a cut ends the current event
        t, _ = self._recent[-1]
        decide_now = event.decision_s is None
        if decide_now:
            out.decided = self._decide(t)
        last = self._last_e
        if self._track is not None and self._last_q is not None and last is not None:
            if decide_now:  # as the detector's release at that sample would have
                event.contact_at_decision = self._track.at(t, self._last_q, *last)
            event.contact_at_peak = self._track.finish()
        event.release_s = t
        self.events.append(event)
        out.released, self.current = event, None

    def finish(self) -> list[ContactEvent]:
        """Return every event, including one still open at the end of the stream (its
        estimate at the peak so far)."""
        if self.current is not None and self._track is not None:
            self.current.contact_at_peak = self._track.finish()
        return self.events + ([self.current] if self.current is not None else [])


def _recent_before(carried: list[tuple[float, np.ndarray]], t: np.ndarray, r: np.ndarray,
                   k: int, restarts: list[int]) -> deque[tuple[float, np.ndarray]]:
    """Return the samples a stream holds in the pipeline's ``_recent`` before row ``k``
    of a chunk (times ``t`` [s], residuals ``r`` [Nm]): those within ``PRE_S`` of row
    k - 1 since the last restart, ``carried`` (what it held before the chunk) where they
    reach into the chunk before."""
    since = max([g for g in restarts if g < k], default=None)
    last = float(t[k - 1]) if k else None
    lo = 0 if last is None else int(np.searchsorted(t, last - PRE_S))
    kept = deque() if since is not None else deque(
        s for s in carried if last is None or s[0] >= last - PRE_S)
    lo = lo if since is None else max(lo, since)
    kept.extend((float(t[j]), np.array(r[j], dtype=float)) for j in range(lo, k))
    return kept


def batch_events(t: np.ndarray, r: np.ndarray, detection: Detection,
                 model: EventModel | None = None, decide_after_s: float | None = None,
                 q: np.ndarray | None = None, isolator: ContactIsolator | None = None,
                 weak: WeakDecision | None = None) -> list[ContactEvent]:
    """Return the events of a whole stream from its detector output (one detector run
    serves any decision delay), the same events :class:`EventPipeline` gives (``model``,
    ``decide_after_s`` and ``weak`` as there); with joint positions ``q`` [rad] (N, 7)
    and an ``isolator``, with their contact estimates."""
    pipeline = EventPipeline(None, model, decide_after_s, isolator, weak=weak)
    events = []
    restarts = np.asarray(detection.restarts, dtype=np.int64)
    for onset, release in detection.intervals:
        last = len(t) - 1 if release is None else release
        pipeline._delay = pipeline.decide_after_s
        stop = int(np.searchsorted(t, t[onset] + pipeline._delay - 1e-12))
        # as the stream at sample ``stop``: a weak event not released there waits
        later = (pipeline._weak_delay(float(detection.score[onset:stop + 1].max()))
                 if stop < last or (stop == last and release is None) else None)
        if later is not None:
            stop = int(np.searchsorted(t, t[onset] + later - 1e-12))
        decision = min(stop, last)
        since = restarts[restarts <= onset]  # no sample before a gap enters the window
        start = max(int(np.searchsorted(t, t[onset] - PRE_S)),
                    int(since[-1]) if since.size else 0)
        pipeline.current = ContactEvent(onset_s=float(t[onset]))
        pipeline._baseline = detection.baseline[onset]
        pipeline._window = list(zip(t[start:decision + 1], r[start:decision + 1], strict=True))
        decided = release is not None or stop <= last
        if decided:
            pipeline._decide(float(t[decision]))
        pipeline._track = None
        if isolator is not None and q is not None:
            pipeline._track = EventTrack(isolator, float(t[onset]))
            for k in range(onset, last + 1):
                pipeline._isolate(float(t[k]), q[k], np.asarray(detection.e[k], dtype=float),
                                  decided and k == decision, k == release,
                                  detection.threshold[k])
        event = pipeline.finish()[-1]
        event.release_s = None if release is None else float(t[release])
        event.peak_score = float(detection.score[onset:last + 1].max())
        events.append(event)
    return events


def stream_events(t: np.ndarray, r: np.ndarray, dq: np.ndarray,
                  detector: DetectorConfig | None = None, model: EventModel | None = None,
                  decide_after_s: float | None = None, q: np.ndarray | None = None,
                  isolator: ContactIsolator | None = None, dyn: np.ndarray | None = None
                  ) -> tuple[list[ContactEvent], list[str]]:
    """Run the pipeline over whole arrays (t (N,) [s], r and dq (N, 7), for contact
    isolation q (N, 7) [rad] and an isolator, and the dynamic torque scale dyn (N, 7)
    [Nm]); return the events and the per-sample label, exactly as the streaming path
    gives them."""
    pipeline = EventPipeline(detector, model, decide_after_s, isolator)
    labels = [pipeline.update(float(t[k]), r[k], dq[k], None if q is None else q[k],
                              None if dyn is None else dyn[k]).label
              for k in range(len(t))]
    return pipeline.finish(), labels


def session_events(session: Session, detector: DetectorConfig, model: EventModel | None = None,
                   decide_after_s: float | None = None, robot: RobotChoice = None,
                   isolate: bool = True) -> list[ContactEvent]:
    """Return the contact events of a whole session (observer, detector, pipeline, and
    with ``isolate`` contact isolation on the session's arm); ``robot`` names the arm's
    model instead of the session's own (or carries its identified dynamics, an
    :class:`~contactkit.robots.dynamics.ArmOverride`). The detector is adapted to the arm
    (:meth:`DetectorConfig.for_robot`)."""
    session = session.complete()
    t, dq, q = session.t, session.dq, session.q
    chain = TimeseriesChain.for_session(session.meta, ChainConfig(robot=robot), session.path)
    detector = detector.for_robot(chain.model.spec)
    features = chain.compute(t, q, dq, session.tau, detector.chain_features)
    r = features["r"]
    isolator = robot_isolator(chain.model.setup) if isolate else None
    return batch_events(t, r, detect(t, r, dq, detector, features.get(DYNAMIC_FEATURE)),
                        model, decide_after_s, q, isolator)
