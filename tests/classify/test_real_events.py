"""The default model's contact events on the real Panda recordings (no calibration on
real data). Builds the default model on first use (minutes; cached afterwards)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contactkit.classify.events.contact_events import batch_events
from contactkit.classify.events.metrics import EventScore, score_events
from contactkit.classify.modelfile.model_file import load_model
from contactkit.cli.default_model import build_default_model
from contactkit.features.detector import DYNAMIC_FEATURE, detect
from contactkit.features.timeseries import TimeseriesChain
from contactkit.recorder.importers.arrays import load_joint_arrays
from contactkit.replay.engine import ReplayStream
from contactkit.robots import RobotSetup
from contactkit.schemas import SessionMeta, joint_columns, read_session, write_session
from tests.conftest import MINDLAB_FILES, load_mindlab

# The default model is built once (about 5 minutes on 2 cores) and cached: these are
# the checks of the model a new user gets, on real recordings it never saw.


@pytest.fixture(scope="module")
def default_model():
    return load_model(build_default_model())


def _events(model, t, q, dq, tau, with_hand: bool):
    detector = model.detector_config()
    features = TimeseriesChain(robot=RobotSetup(with_hand=with_hand)).compute(
        t, q, dq, tau, detector.chain_features)
    r = features["r"]
    detection = detect(t, r, dq, detector, features.get(DYNAMIC_FEATURE))
    return batch_events(t, r, detection, model.event_model())


def test_free_motion_log_has_no_contact_events(default_model, reference_dir: Path) -> None:
    gaz = load_joint_arrays(*(reference_dir / f for f in ("time.txt", "positions.txt",
                                                          "velocity.txt", "torques.txt")))
    events = _events(default_model, gaz["t"], gaz["q"], gaz["dq"], gaz["tau"], False)
    assert events == []


def test_every_real_touch_detected_quickly_and_few_false_events(default_model,
                                                                mindlab_dir: Path) -> None:
    total = EventScore()
    for name in MINDLAB_FILES:
        data = load_mindlab(mindlab_dir / f"{name}.csv")
        events = _events(default_model, data["t"], data["q"], data["dq"], data["tau"], True)
        spans = [(e.onset_s, data["t"][-1] if e.release_s is None else e.release_s)
                 for e in events]
        total = total + score_events(data["t"], data["contact"], spans)
    assert total.detected == total.touches
    assert total.false_per_min <= 1.0
    assert total.delay_ms(50) <= 60.0


def test_real_events_are_decided_once_and_never_confident_out_of_range(
        default_model, mindlab_dir: Path) -> None:
    data = load_mindlab(mindlab_dir / "a4.csv")
    events = _events(default_model, data["t"], data["q"], data["dq"], data["tau"], True)
    assert events
    for event in events:
        assert event.decision_s is not None
        if event.out_of_range:
            assert event.label == "unknown"
        assert np.isclose(sum(event.probabilities.values()), 1.0)


def test_per_hop_output_is_none_in_free_motion(default_model, reference_dir: Path,
                                               tmp_path: Path) -> None:
    gaz = load_joint_arrays(*(reference_dir / f for f in ("time.txt", "positions.txt",
                                                          "velocity.txt", "torques.txt")))
    columns = {"t": gaz["t"] - gaz["t"][0]}
    for prefix in ("q", "dq", "tau"):
        columns.update(zip(joint_columns(prefix), gaz[prefix].T, strict=True))
    path = write_session(tmp_path / "gaz.parquet", columns,
                         SessionMeta(session_id="gaz", source="real", action="none",
                                     with_hand=False))
    stream = ReplayStream(read_session(path), default_model).run()
    assert len(stream.pred_label) > 1000 and set(stream.pred_label) == {"none"}
    none = default_model.classes.index("none")
    assert all(p[none] == 1.0 for p in stream.pred_proba)
