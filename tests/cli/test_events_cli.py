"""classify calibrate, predict --events and replay with contact events, end to end."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import rerun.chunk as rc

from contactkit.classify.events.contact_events import EVENT_FEATURES, EventModel
from contactkit.classify.kinds.kind import ModelOptions
from contactkit.classify.kinds.svm_estimators import svm_pipeline
from contactkit.classify.modelfile.model_file import load_model
from contactkit.classify.training import train
from contactkit.features.detector import DetectorConfig, load_calibration
from contactkit.schemas import read_session, write_session
from contactkit.viewer import layout
from tests.conftest import make_dataset, make_session, run_command
from tests.rrd_frames import assert_frames_ok

DETECTOR = DetectorConfig(noise=(1.0,) * 7, speed=(0.5,) * 7, accel=(0.02,) * 7)


@pytest.fixture(scope="module")
def model_path(tmp_path_factory) -> Path:
    directory = make_dataset(tmp_path_factory.mktemp("train"), poses=("A", "B"), repeats=1)
    rng = np.random.default_rng(0)
    X = np.abs(rng.normal(2.0, 1.0, (60, len(EVENT_FEATURES))))
    y = np.array(["bump", "adjust", "shove"] * 20)
    events = EventModel(svm_pipeline(1.0).fit(X, y), ["adjust", "bump", "shove"], 0.15,
                        X.min(axis=0) * 0 - 1e9, X.max(axis=0) + 1e9)
    return train([directory], tmp_path_factory.mktemp("model") / "m.skops",
                 ModelOptions(kind="svm", window="planned", params={"c": 10.0}),
                 detector=DETECTOR.to_dict(), events=(events.estimator, events.meta())).path


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> dict[str, Path]:
    directory = tmp_path_factory.mktemp("sessions")
    shove = make_session(directory, seed=5, action="shove", link=4, duration_s=4.0,
                         planned_at_s=1.5)
    still = make_session(directory, seed=6, action="none", duration_s=4.0, planned_at_s=1.5)
    session = read_session(shove)
    unplanned = directory / "unplanned.parquet"
    columns = {name: session.column(name) for name in session.table.column_names}
    write_session(unplanned, columns, dataclasses.replace(session.meta, planned_at_s=None))
    return {"shove": shove, "none": still, "unplanned": unplanned}


def test_model_file_carries_detector_and_event_classifier(model_path) -> None:
    model = load_model(model_path)
    assert model.detector_config() == DETECTOR
    assert model.event_model().classes == ["adjust", "bump", "shove"]


def test_calibrate_round_trip_through_the_cli(tmp_path, sessions) -> None:
    out = tmp_path / "robot.json"
    result = run_command("classify", "calibrate", str(sessions["none"]), str(sessions["shove"]),
                         "--out", str(out))
    assert result.returncode == 0, result.stderr
    config = load_calibration(out)
    assert config.source["sessions"] == 2
    assert len(config.noise) == 7
    assert config.dynamic == (0.0,) * 7  # fitted only when asked
    assert config.dynamic_range is None and "beyond a dynamic torque" not in result.stdout
    result = run_command("classify", "calibrate", str(sessions["none"]), "--dynamic",
                         "--out", str(out), "--overwrite")
    assert result.returncode == 0, result.stderr
    assert "per Nm of dynamic torque" in result.stdout
    assert "beyond a dynamic torque of" in result.stdout
    config = load_calibration(out)
    assert len(config.dynamic) == 7 and config.dynamic_range is not None


def test_predict_events_with_the_models_detector(model_path, sessions) -> None:
    result = run_command("classify", "predict", str(model_path), str(sessions["shove"]),
                         "--events", "--json")
    assert result.returncode == 0, result.stderr
    events = [json.loads(line)["event"] for line in result.stdout.splitlines()]
    assert len(events) == 1
    assert events[0]["label"] in ("adjust", "bump", "shove")
    assert events[0]["decision_s"] == pytest.approx(events[0]["onset_s"] + 0.15, abs=0.003)
    peak = events[0]["contact_at_peak"]
    assert peak["status"] == "ok" and peak["link"] in range(1, 8)
    assert len(peak["point_link_m"]) == len(peak["point_base_m"]) == len(peak["force_n"]) == 3
    assert 0.0 <= peak["confidence"] <= 1.0
    text = run_command("classify", "predict", str(model_path), str(sessions["shove"]), "--events")
    assert "at the peak link " in text.stdout


def test_decide_after_moves_the_decision(model_path, sessions) -> None:
    result = run_command("classify", "predict", str(model_path), str(sessions["shove"]),
                         "--events", "--json", "--decide-after", "0.1")
    event = json.loads(result.stdout.splitlines()[0])["event"]
    assert event["decision_s"] == pytest.approx(event["onset_s"] + 0.1, abs=0.003)


@pytest.mark.parametrize("content", ["{", '{"format": "contactkit-detector/1", "noise": 3}'])
@pytest.mark.parametrize("tool", ["classify", "replay"])
def test_bad_calibration_file_exits_2(tmp_path, model_path, sessions, content, tool) -> None:
    bad = tmp_path / "robot.json"
    bad.write_text(content)
    if tool == "classify":
        args = ["classify", "predict", str(model_path), str(sessions["shove"])]
    else:
        args = ["replay", str(sessions["shove"]), "--model", str(model_path), "--viewer",
                "none", "--save", str(tmp_path / "x.rrd")]
    result = run_command(*args, "--calibration", str(bad))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "robot.json" in lines[0], result.stderr


def test_replay_runs_without_planned_time_and_reports_events(tmp_path, model_path,
                                                             sessions) -> None:
    result = run_command("replay", str(sessions["unplanned"]), "--model", str(model_path),
                         "--viewer", "none", "--save", str(tmp_path / "u.rrd"))
    assert result.returncode == 0, result.stderr
    summary = result.stdout + result.stderr
    assert "no planned time" in summary
    assert "1 contact event: " in summary


def test_replay_draws_the_isolated_and_the_true_contact(tmp_path, model_path, sessions) -> None:
    out = tmp_path / "s.rrd"
    result = run_command("replay", str(sessions["shove"]), "--model", str(model_path),
                         "--viewer", "none", "--save", str(out))
    assert result.returncode == 0, result.stderr
    assert_frames_ok(out)
    rows: dict[str, int] = {}
    for chunk in rc.RrdReader(out).stream():
        if not chunk.is_static:
            path = chunk.entity_path.lstrip("/")
            rows[path] = rows.get(path, 0) + chunk.to_record_batch().num_rows
    for entity in (layout.CONTACT_POINT, layout.CONTACT_FORCE, layout.TRUE_POINT,
                   layout.TRUE_ARROW):
        assert rows.get(entity, 0) > 0, entity
    assert any(path.startswith(layout.CONTACT_LINK) for path in rows)
