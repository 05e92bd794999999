"""The out-of-range rule judges direction as well as distance (issue 38): an event
stronger than any training example of its class keeps that class's answer and says
why; inputs no class explains (another arm's scale, a flat-lined sensor, a reversed
rise) stay ``unknown``. Hand-made residual profiles, a classifier fitted on them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contactkit.classify.events.contact_events import (
    UNKNOWN,
    ContactEvent,
    EventModel,
    EventPipeline,
    event_features,
)
from contactkit.classify.events.training import SessionEvents, fit_event_model, session_outcome
from contactkit.classify.modelfile.model_file import _check_event_meta
from contactkit.schemas import InputError

T = np.arange(-0.05, 0.1501, 0.002)  # s from the onset: the decision window at 500 Hz
SPREAD = np.ones(7) / np.sqrt(7)  # how the residual's norm falls on the joints


def _profile(action: str, peak_nm: float, rise_s: float) -> np.ndarray:
    """The deviation e (n, 7) [Nm] of a hand-made contact: a ramp to ``peak_nm`` over
    ``rise_s`` (shove, adjust) or a triangle of that half-width (bump)."""
    s = T + 0.01
    norm = peak_nm * (np.clip(1 - np.abs(s - rise_s) / rise_s, 0, 1) if action == "bump"
                      else np.clip(s / rise_s, 0, 1))
    return norm[:, None] * SPREAD


def _features(e: np.ndarray) -> np.ndarray:
    return event_features(T, e, 0.0)


@pytest.fixture(scope="module")
def model() -> EventModel:
    """An intent classifier fitted on 240 hand-made events: shoves of 3-10 Nm rising in
    40-100 ms, bumps and adjusts of 0.5-3 Nm (bumps as 25-75 ms triangles, adjusts
    rising in 0.3-0.6 s), each spread over the joints at random."""
    rng = np.random.default_rng(0)
    ranges = {"shove": ((3, 10), (0.04, 0.1)), "bump": ((0.5, 3), (0.025, 0.075)),
              "adjust": ((0.5, 3), (0.3, 0.6))}
    sessions = []
    for k in range(240):
        action = ("bump", "adjust", "shove")[k % 3]
        (low, high), rise = ranges[action]
        weights = np.abs(rng.normal(size=7))
        e = _profile(action, rng.uniform(low, high), rng.uniform(*rise)) / SPREAD \
            * weights / np.linalg.norm(weights) + rng.normal(0, 0.02, (len(T), 7))
        event = ContactEvent(0.0, 0.15, 0.5, features=_features(e))
        sessions.append(SessionEvents(f"s{k}", action, "A", (0.0, 0.4), [event]))
    return fit_event_model(sessions, 0.15)


def test_a_shove_stronger_than_any_training_shove_keeps_its_class(model) -> None:
    strong = _features(_profile("shove", 18.0, 0.06))  # 1.8 times the strongest
    kept = model.range_check(strong, "shove")
    assert not kept.refused and kept.side == "above" and "peak_norm" in kept.features
    # The side is the shoves': the same features said to be a bump are not explained.
    assert model.range_check(strong, "bump").refused
    typical = model.range_check(_features(_profile("shove", 6.0, 0.06)), "shove")
    assert typical == type(typical)()


@pytest.mark.parametrize("hostile", ["10x scale", "flat-line sensor", "reversed rise"])
def test_inputs_no_class_explains_stay_unknown(model, hostile: str) -> None:
    typical = _profile("shove", 6.0, 0.06)
    if hostile == "10x scale":  # another arm's scale, or a unit error
        e = 10.0 * typical
    elif hostile == "flat-line sensor":  # joint 2's sensor drops to 0 at the onset
        e = np.zeros_like(typical)
        e[T >= 0.0, 1] = 6.0
    else:  # the norm falls from the onset on: not a push building up
        e = typical[::-1]
    for label in model.classes:
        check = model.range_check(_features(e), label)
        assert check.refused and check.features, (hostile, label)


def test_the_pipeline_and_the_scoring_keep_or_refuse_alike(model) -> None:
    class Says:
        """A classifier that always answers shove."""

        classes_ = np.array(model.classes)

        def predict_proba(self, x: np.ndarray) -> np.ndarray:
            return np.tile([0.05, 0.05, 0.9], (len(x), 1))

    shove_model = EventModel(Says(), model.classes, 0.15, model.low, model.high,
                             model.class_low, model.class_high)
    for peak, refused in ((18.0, False), (60.0, True)):
        e = _profile("shove", peak, 0.06)
        pipeline = EventPipeline(None, shove_model)
        pipeline.current = ContactEvent(onset_s=0.0)
        pipeline._window = list(zip(T, e, strict=True))
        event = pipeline._decide(0.15)
        assert event.out_of_range is refused and event.beyond_range == "above"
        assert event.label == (UNKNOWN if refused else "shove")
        assert event.to_dict()["beyond_features"] == event.beyond_features
        outcome, _ = session_outcome(SessionEvents("s", "shove", "A", (0.0, 0.4), [event]),
                                     shove_model)
        assert outcome == event.label


def test_class_ranges_travel_in_the_model_file_and_old_files_refuse_as_before(
        model, tmp_path: Path) -> None:
    doc = model.meta()
    _check_event_meta(doc, tmp_path)
    again = EventModel.from_meta(model.estimator, doc)
    strong = _features(_profile("shove", 18.0, 0.06))
    assert again.range_check(strong, "shove") == model.range_check(strong, "shove")
    old = {k: v for k, v in doc.items() if not k.startswith("class_")}
    _check_event_meta(old, tmp_path)
    assert EventModel.from_meta(model.estimator, old).range_check(strong, "shove").refused
    with pytest.raises(InputError, match="class_high"):
        _check_event_meta({**doc, "class_high": {"shove": [1.0]}}, tmp_path)
    with pytest.raises(InputError, match="come together"):
        _check_event_meta({**old, "class_low": doc["class_low"]}, tmp_path)


@pytest.fixture(scope="module")
def default_events() -> tuple:
    """The default model's detector and event classifier (built on first use)."""
    from contactkit.classify.modelfile.model_file import load_model
    from contactkit.cli.default_model import build_default_model

    model = load_model(build_default_model(), lazy=True)
    return model.detector_config(), model.event_model()


def test_the_default_model_keeps_a_shove_harder_than_any_it_saw_and_refuses_hostile_ones(
        default_events, tmp_path: Path) -> None:
    """A 200 N shove on the hand at pose B (its strongest training shove: 167 N), which
    also drives joint 6 past its speed limit: the arm's reflex stops it. Its event
    stays a shove; the same event ten times larger, reversed, or as a sensor stepping to
    a constant is unknown."""
    from dataclasses import replace

    from contactkit.classify.events.contact_events import PRE_S, session_events
    from contactkit.features.detector import DYNAMIC_FEATURE, detect
    from contactkit.features.timeseries import TimeseriesChain
    from contactkit.recorder.sim.dataset import simulate_specs
    from contactkit.recorder.sim.simulator import SimConfig, plan_session
    from contactkit.schemas import read_session

    detector, events_model = default_events
    spec = plan_session(seed=2, condition="static", action="shove", pose="B", link=7,
                        duration_s=2.5, planned_at_s=1.0)
    spec = replace(spec, contact=replace(spec.contact, onset_s=1.0, peak_n=200.0,
                                         rise_s=0.06, hold_s=0.1, fall_s=0.15))
    (path,) = simulate_specs([spec], SimConfig(rate_hz=500.0), tmp_path)
    session = read_session(path)
    assert "reflex" in session.meta.simulator
    (event,) = session_events(session, detector, events_model, isolate=False)
    assert event.label == "shove" and not event.out_of_range
    assert event.beyond_range == "above" and event.beyond_features
    # The event's own decision window, made hostile.
    session = session.complete()
    chain = TimeseriesChain.for_session(session.meta)
    t = session.t
    features = chain.compute(t, session.q, session.dq, session.tau, detector.chain_features)
    r = features["r"]
    found = detect(t, r, session.dq, detector.for_robot(chain.model.spec),
                   features.get(DYNAMIC_FEATURE))
    onset = found.intervals[0][0]
    keep = (t >= t[onset] - PRE_S) & (t <= event.decision_s)
    e = r[keep] - found.baseline[onset]
    flat = np.zeros_like(e)
    flat[t[keep] >= t[onset], 1] = np.abs(e[:, 1]).max()
    for hostile in (10.0 * e, e[::-1], flat):
        x = event_features(t[keep], hostile, t[onset])
        label = events_model.classes[int(np.argmax(
            events_model.estimator.predict_proba(x[None, :])[0]))]
        assert events_model.range_check(x, label).refused


def test_features_past_the_event_features_are_named_by_position(model) -> None:
    """An experiment that appends inputs to the event features (docs/isolation.py's
    isolated link and force direction) gets a verdict, with those named by position and
    never counted as strength: a value far past the range there is not explained."""
    from dataclasses import replace

    extra = 3
    wider = replace(model, low=np.r_[model.low, np.zeros(extra)],
                    high=np.r_[model.high, np.ones(extra)],
                    class_low={c: np.r_[v, np.zeros(extra)] for c, v in model.class_low.items()},
                    class_high={c: np.r_[v, np.ones(extra)] for c, v in model.class_high.items()})
    typical = np.r_[_features(_profile("shove", 6.0, 0.06)), np.full(extra, 0.5)]
    assert not wider.range_check(typical, "shove").refused
    odd = typical.copy()
    odd[-1] = 10.0
    check = wider.range_check(odd, "shove")
    assert check.refused and check.features == (f"feature {len(odd) - 1}",)
