"""The detect -> decide -> hold pipeline: streaming = batch, no look-ahead, held labels."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contactkit.classify.events.contact_events import (
    EVENT_FEATURES,
    NONE,
    UNDECIDED,
    UNKNOWN,
    ContactEvent,
    EventModel,
    EventPipeline,
    WeakDecision,
    batch_events,
    stream_events,
)
from contactkit.classify.events.training import (
    MATCH_SLACK_S,
    SessionEvents,
    first_overlapping,
    session_events,
)
from contactkit.classify.kinds.svm_estimators import svm_pipeline
from contactkit.features.detector import BEYOND_RANGE, DetectorConfig, detect
from contactkit.features.timeseries import TimeseriesChain
from contactkit.schemas import InputError, read_session
from tests.conftest import make_session

DETECTOR = DetectorConfig(noise=(0.5,) * 7, speed=(0.5,) * 7, accel=(0.02,) * 7)


@pytest.fixture(scope="module")
def model() -> EventModel:
    rng = np.random.default_rng(0)
    X = np.abs(rng.normal(2.0, 1.0, (60, len(EVENT_FEATURES))))
    y = np.array(["bump", "adjust", "shove"] * 20)
    X[y == "shove"] *= 3.0
    estimator = svm_pipeline(1.0).fit(X, y)
    return EventModel(estimator, [str(c) for c in estimator.classes_], 0.15,
                      X.min(axis=0), X.max(axis=0))


@pytest.fixture(scope="module")
def shove(tmp_path_factory) -> dict[str, np.ndarray]:
    path = make_session(tmp_path_factory.mktemp("events"), action="shove", link=4,
                        duration_s=4.0, planned_at_s=1.5)
    session = read_session(path)
    t, q, dq, tau = session.t, session.q, session.dq, session.tau
    r = TimeseriesChain().compute(t, q, dq, tau, ["r"])["r"]
    return {"t": t, "q": q, "dq": dq, "tau": tau, "r": r, "contact": session.column("contact")}


def _streamed(data, model, decide_after_s=None, stop=None, weak=None):
    chain = TimeseriesChain(names=["r"])
    pipeline = EventPipeline(DETECTOR, model, decide_after_s, weak=weak)
    labels = []
    for k in range(len(data["t"]) if stop is None else stop):
        out = chain.update(data["t"][k], data["q"][k], data["dq"][k], data["tau"][k])
        labels.append(pipeline.update(data["t"][k], out["r"], data["dq"][k]).label)
    return pipeline.finish(), labels


def _same(a, b) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert (x.onset_s, x.decision_s, x.release_s, x.label) == \
               (y.onset_s, y.decision_s, y.release_s, y.label)
        for c in x.probabilities:
            assert abs(x.probabilities[c] - y.probabilities[c]) < 1e-6


def test_streaming_and_batch_give_the_same_events(shove, model) -> None:
    streamed, labels = _streamed(shove, model)
    assert len(streamed) >= 1
    detection = detect(shove["t"], shove["r"], shove["dq"], DETECTOR)
    _same(batch_events(shove["t"], shove["r"], detection, model, 0.15), streamed)
    arrays, array_labels = stream_events(shove["t"], shove["r"], shove["dq"], DETECTOR, model)
    _same(arrays, streamed)
    assert array_labels == labels


def test_one_decision_held_until_release(shove, model) -> None:
    events, labels = _streamed(shove, model)
    event = events[0]
    t = shove["t"]
    touched = t[shove["contact"]]
    assert touched[0] - 0.05 <= event.onset_s <= touched[0] + 0.1
    assert event.decision_s == pytest.approx(event.onset_s + 0.15, abs=0.003)
    assert event.label in [*model.classes, UNKNOWN]
    held = [lab for s, lab in zip(t, labels, strict=True)
            if event.decision_s <= s < event.release_s]
    assert set(held) == {event.label}
    pending = [lab for s, lab in zip(t, labels, strict=True)
               if event.onset_s <= s < event.decision_s]
    assert set(pending) == {UNDECIDED}
    assert labels[0] == NONE and labels[-1] == NONE


def test_no_look_ahead(shove, model) -> None:
    full, labels = _streamed(shove, model)
    cut = int(np.searchsorted(shove["t"], full[0].decision_s)) + 1
    part, part_labels = _streamed(shove, model, stop=cut)
    assert part[0].label == full[0].label and part[0].release_s is None
    assert part_labels == labels[:cut]


def test_out_of_range_is_flagged_not_a_confident_class(shove, model) -> None:
    narrow = EventModel(model.estimator, model.classes, 0.15, model.low * 0, model.low * 0)
    events, _ = _streamed(shove, narrow)
    assert events[0].out_of_range and events[0].label == UNKNOWN


def test_without_classifier_events_say_contact(shove) -> None:
    events, _ = _streamed(shove, None)
    assert events[0].label == "contact" and events[0].features is not None


def test_bad_decision_delay(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="decision delay"):
        EventPipeline(DETECTOR, None, -1.0)


def test_with_the_dynamic_term_streaming_chunked_and_batch_agree(shove, model) -> None:
    detector = DetectorConfig(noise=(0.5,) * 7, speed=(0.2,) * 7, accel=(0.01,) * 7,
                              dynamic=(0.05,) * 7)
    assert detector.chain_features == ["r", "tau_dyn"]
    t, q, dq, tau = shove["t"], shove["q"], shove["dq"], shove["tau"]
    chain = TimeseriesChain(names=detector.chain_features)
    pipeline = EventPipeline(detector, model)
    labels = []
    for k in range(len(t)):
        out = chain.update(t[k], q[k], dq[k], tau[k])
        labels.append(pipeline.update(t[k], out["r"], dq[k], None, out["tau_dyn"]).label)
    streamed = pipeline.finish()
    assert len(streamed) >= 1
    whole = TimeseriesChain(names=detector.chain_features).compute(t, q, dq, tau)
    r, dyn = whole["r"], whole["tau_dyn"]
    _same(batch_events(t, r, detect(t, r, dq, detector, dyn), model, 0.15), streamed)
    arrays, array_labels = stream_events(t, r, dq, detector, model, dyn=dyn)
    _same(arrays, streamed)
    assert array_labels == labels
    chunked = EventPipeline(detector, model)
    block_labels = [label for i in range(0, len(t), 250)
                    for label in chunked.update_block(t[i:i + 250], r[i:i + 250],
                                                      dq[i:i + 250], None,
                                                      dyn[i:i + 250]).labels]
    _same(chunked.finish(), streamed)
    assert block_labels == labels


def test_a_weak_contact_waits_for_its_later_decision(shove, model) -> None:
    t, r, dq = shove["t"], shove["r"], shove["dq"]
    detection = detect(t, r, dq, DETECTOR)
    onset, release = detection.intervals[0]
    due = int(np.searchsorted(t, t[onset] + 0.15 - 1e-12))
    by_then = float(detection.score[onset:due + 1].max())
    assert t[release] - t[onset] > 0.22  # the shove outlasts both delays
    for weak, waits in ((WeakDecision(by_then * 1.01, 0.2), True),
                        (WeakDecision(by_then * 0.99, 0.2), False),
                        (WeakDecision(by_then * 1.01, 0.1), False)):  # not later: no rule
        streamed, labels = _streamed(shove, model, weak=weak)
        event = streamed[0]
        assert event.decision_s == pytest.approx(
            event.onset_s + (0.2 if waits else 0.15), abs=0.003)
        assert labels[int(np.searchsorted(t, event.decision_s)) - 1] == UNDECIDED
        # batch, per-sample arrays and chunks agree; so does the model's own rule
        _same(batch_events(t, r, detection, model, weak=weak), streamed)
        ruled = EventModel(model.estimator, model.classes, 0.15, model.low, model.high,
                           weak=weak)
        _same(batch_events(t, r, detection, ruled), streamed)
        arrays, array_labels = stream_events(t, r, dq, DETECTOR, ruled)
        _same(arrays, streamed)
        assert array_labels == labels
        chunked = EventPipeline(DETECTOR, ruled)
        block_labels = [label for i in range(0, len(t), 97)
                        for label in chunked.update_block(t[i:i + 97], r[i:i + 97],
                                                          dq[i:i + 97]).labels]
        _same(chunked.finish(), streamed)
        assert block_labels == labels
    # a release before the later delay decides it there
    streamed, _ = _streamed(shove, model, weak=WeakDecision(by_then * 1.01, 5.0))
    assert streamed[0].decision_s == streamed[0].release_s
    _same(batch_events(t, r, detection, model, weak=WeakDecision(by_then * 1.01, 5.0)),
          streamed)
    # the rule travels with the model's settings
    ruled = EventModel(model.estimator, model.classes, 0.15, model.low, model.high,
                       weak=WeakDecision(2.0, 0.3))
    assert EventModel.from_meta(model.estimator, ruled.meta()).weak == WeakDecision(2.0, 0.3)
    assert EventModel.from_meta(model.estimator, model.meta()).weak is None


@pytest.mark.parametrize("score, delay", [(-1.0, 0.35), (float("nan"), 0.35), (3.0, -0.1),
                                          (3.0, 5.5)])
def test_bad_weak_rule(score: float, delay: float) -> None:
    with pytest.raises(InputError, match="weak contact"):
        WeakDecision(score, delay)


def test_an_event_matches_a_contact_it_overlaps_with_slack_on_both_sides() -> None:
    contact = (2.0, 2.5)
    early = ContactEvent(onset_s=1.0, release_s=2.0 - 2 * MATCH_SLACK_S)  # ended before
    slack = ContactEvent(onset_s=1.5, release_s=2.0 - MATCH_SLACK_S / 2)  # within the slack
    inside = ContactEvent(onset_s=2.1, release_s=2.4)
    open_ended = ContactEvent(onset_s=2.5)  # still on, decided at the contact's last sample
    lagging = ContactEvent(onset_s=2.5 + MATCH_SLACK_S / 2, release_s=3.0)  # decided after
    late = ContactEvent(onset_s=2.5 + 2 * MATCH_SLACK_S, release_s=3.0)  # another event
    assert first_overlapping([early, inside, slack], contact) is inside
    assert first_overlapping([early, slack, inside], contact) is slack
    assert first_overlapping([open_ended], contact) is open_ended
    assert first_overlapping([early, lagging], contact) is lagging
    assert first_overlapping([early, late], contact) is None
    assert SessionEvents("s", "bump", "A", contact, [late, inside]).matched() is inside
    assert SessionEvents("s", "none", "A", None, [inside]).matched() is None


def test_training_finds_each_contact_again_with_scaled_thresholds(tmp_path: Path) -> None:
    shoved = make_session(tmp_path, action="shove", link=4, duration_s=4.0, planned_at_s=1.5)
    (plain,) = session_events(shoved, DETECTOR, [0.15])
    (events,) = session_events(shoved, DETECTOR, [0.15], threshold_scales=(0.6, 0.8))
    assert plain.rescaled == []
    assert [e.onset_s for e in events.events] == [e.onset_s for e in plain.events]
    assert len(events.rescaled) == 2
    # lower thresholds decide the same contact no later, and each is a training row
    assert all(e.onset_s <= plain.matched().onset_s for e in events.rescaled)
    xs, ys = events.rows()
    assert len(xs) == len(plain.rows()[0]) + 2 and ys[-2:] == ["shove", "shove"]
    quiet = make_session(tmp_path, action="none", link=None, duration_s=4.0, planned_at_s=1.5)
    (none,) = session_events(quiet, DETECTOR, [0.15], threshold_scales=(0.6,))
    assert none.rescaled == []  # nothing to find again without a contact


@pytest.mark.parametrize("factor", [0.0, -1.0, float("nan"), float("inf")])
def test_a_threshold_scale_must_be_positive(factor: float) -> None:
    with pytest.raises(ValueError, match="threshold scale"):
        DETECTOR.scaled(factor)


def test_scaled_thresholds_are_that_many_times_as_high() -> None:
    t = np.linspace(0.0, 1.0, 11)
    dq = np.full((11, 7), 0.3)
    dyn = np.full((11, 7), 2.0)
    config = DetectorConfig(dynamic=(0.1,) * 7, dynamic_range=(1.0,) * 7)
    base = detect(t, np.zeros((11, 7)), dq, config, dyn).threshold
    scaled = detect(t, np.zeros((11, 7)), dq, config.scaled(0.5), dyn).threshold
    beyond = BEYOND_RANGE * (2.0 - 1.0)  # the growth beyond the calibrated range stays
    np.testing.assert_allclose(scaled - beyond, 0.5 * (base - beyond), atol=1e-12)
