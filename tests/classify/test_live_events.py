"""recorder capture --events: the event pipeline on every sample as it is recorded, the
same events as replay on the written file, nothing seen from the future."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from contactkit.classify.events.listener import LiveEvents
from contactkit.classify.modelfile.model_file import load_model
from contactkit.cli.default_model import build_default_model
from contactkit.features.isolation import robot_isolator
from contactkit.recorder.capture.record import record_session
from contactkit.recorder.sources import ProtocolChoices, open_source
from contactkit.replay.engine import ReplayStream
from contactkit.robots import RobotSetup
from contactkit.schemas import joint_columns, read_session
from tests.conftest import run_cli, run_command

CAPTURE = ("--pose", "B", "--action", "adjust", "--link", "4", "--seed", "2", "--rate", "500",
           "--duration", "4", "--planned-at", "1.5")


@pytest.fixture(scope="module")
def model_path() -> Path:
    return build_default_model()


@pytest.fixture(scope="module")
def captured(tmp_path_factory, model_path) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("live")
    result = run_cli("recorder", "capture", *CAPTURE, "--events", "--model", str(model_path),
                     "--out", str(out))
    assert result.returncode == 0, result.stderr
    return Path(result.stdout.strip()), result.stderr


def _listener(model_path: Path, with_hand: bool = True, report=None) -> LiveEvents:
    model = load_model(model_path)
    return LiveEvents(model.transformer().chain_config(), RobotSetup(with_hand=with_hand),
                      model.detector_config(),
                      model.event_model(), report=report)


def test_capture_reports_one_event_as_replay_does(captured, model_path) -> None:
    path, stderr = captured
    assert [kind in stderr for kind in ("onset", "decided", "released")] == [True] * 3
    stored = read_session(path).meta.events
    assert len(stored) == 1
    replayed = ReplayStream(read_session(path), load_model(model_path)).run().events
    # the live chain runs sample by sample, replay batch by batch: equal to 1e-9
    assert len(replayed) == len(stored)
    for live, batch in zip(stored, (e.to_dict() for e in replayed), strict=True):
        _same_values(batch, live)
    # the contact estimates (link, point, force) travel with the stored event
    for key in ("contact_at_decision", "contact_at_peak"):
        assert stored[0][key]["link"] in range(1, 8)
        assert len(stored[0][key]["point_base_m"]) == len(stored[0][key]["force_n"]) == 3
    # which contact class is the model's quality (docs/results.md), not this test's
    assert stored[0]["label"] in {"bump", "adjust", "shove"}
    # decided at the model's delay, or a weak contact at its rule's later one
    events = load_model(model_path).event_model()
    delays = [events.decide_after_s] + ([] if events.weak is None
                                        else [events.weak.decide_after_s])
    waited = stored[0]["decision_s"] - stored[0]["onset_s"]
    assert any(waited == pytest.approx(d, abs=0.003) for d in delays)


def _same_values(batch: dict, live: dict) -> None:
    """Assert two event dicts agree: strings, flags and None exactly, numbers to 1e-9
    relative, nested dicts (contact estimates) and lists value by value."""
    assert batch.keys() == live.keys()
    for key, value in live.items():
        if isinstance(value, dict) and not all(isinstance(v, float) for v in value.values()):
            _same_values(batch[key], value)
        elif value is None or isinstance(value, str | bool):
            assert batch[key] == value, key
        else:
            assert batch[key] == pytest.approx(value, rel=1e-9), key


def test_info_shows_the_stored_events(captured) -> None:
    path, _ = captured
    result = run_command("recorder", "info", str(path), "--json")
    assert result.returncode == 0, result.stderr
    events = json.loads(result.stdout)["metadata"]["events"]
    assert events == read_session(path).meta.events
    table = run_command("recorder", "info", str(path)).stdout
    flat = " ".join(re.sub("[\u2500-\u257f]", " ", table).split())  # a cell's text, unwrapped
    assert "event 1" in flat and f"{events[0]['label']} (p = " in flat
    assert f"at the peak link {events[0]['contact_at_peak']['link']} at (" in flat


def _chunks(path: Path, size: int) -> list[dict[str, np.ndarray]]:
    session = read_session(path)
    names = ["t", *joint_columns("q"), *joint_columns("dq"), *joint_columns("tau")]
    columns = {name: session.column(name) for name in names}
    return [{k: v[i:i + size] for k, v in columns.items()}
            for i in range(0, session.n_samples, size)]


def test_live_pipeline_sees_no_future_samples(captured, model_path) -> None:
    path, _ = captured
    chunks = _chunks(path, 7)
    seen: list[tuple[float, float]] = []  # (time the report speaks of, last sample fed)
    fed = {"t": -np.inf}

    def report(kind, event) -> None:
        stamp = {"onset": event.onset_s, "decision": event.decision_s,
                 "release": event.release_s}[kind]
        seen.append((stamp, fed["t"]))

    full = _listener(model_path, report=report)
    for chunk in chunks:
        fed["t"] = float(chunk["t"][-1])
        full.on_chunk(chunk)
    assert len(seen) == 3 and all(stamp <= last for stamp, last in seen)
    decision = full.events[0].decision_s
    # Cut the stream just after the decision: the same decision, from the past alone.
    cut = _listener(model_path)
    for chunk in chunks:
        keep = chunk["t"] <= decision
        cut.on_chunk({k: v[keep] for k, v in chunk.items()})
    [early] = cut.events
    assert early.release_s is None
    assert (early.onset_s, early.decision_s, early.label, early.probabilities) == (
        full.events[0].onset_s, decision, full.events[0].label, full.events[0].probabilities)


def test_listener_through_the_library_and_in_the_metadata(tmp_path, model_path) -> None:
    source = open_source("sim", {"seed": 2, "rate": 500.0},
                         ProtocolChoices(action="adjust", pose="B", link=4, duration_s=4.0,
                                         planned_at_s=1.5))
    listener = _listener(model_path)
    result = record_session(source, tmp_path, listeners=[listener])
    assert read_session(result.path).meta.events == listener.session_fields()["events"]
    assert listener.samples == result.samples


def test_event_options_need_events(tmp_path, model_path) -> None:
    result = run_cli("recorder", "capture", *CAPTURE, "--model", str(model_path),
                     "--out", str(tmp_path))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "--events" in lines[0], result.stderr


def test_a_capture_keeps_no_contact_track_unless_asked(captured, model_path) -> None:
    """The events of a capture with isolation keep their estimates at the decision and
    the peak, and the same metadata, with or without their 50 Hz tracks; only with
    ``keep_track`` do they hold the tracks (which the metadata leaves out)."""
    path, _ = captured
    model = load_model(model_path)
    chain = model.online_transformer().chain_config()
    robot = chain.robot_setup(read_session(path).meta)
    listeners = [LiveEvents(chain, robot, model.detector_config(), model.event_model(),
                            isolator=robot_isolator(robot), keep_track=keep)
                 for keep in (False, True)]
    for chunk in _chunks(path, 50):
        for listener in listeners:
            listener.on_chunk(chunk)
    light, full = (listener.events for listener in listeners)
    assert [e.to_dict() for e in light] == [e.to_dict() for e in full] != []
    assert light[0].contact_at_peak is not None and light[0].contact_at_decision is not None
    assert all(not e.contact_track for e in light) and full[0].contact_track
