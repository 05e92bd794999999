"""The FR3 end to end: real FR3 recordings imported with their robot named, the default
pipeline on them without calibration, and touches on an FR3 (simulated, and synthetic
ones added to the real recordings) found. Builds the default model on first use."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contactkit.classify.events.contact_events import session_events
from contactkit.classify.modelfile.model_file import load_model
from contactkit.cli.default_model import build_default_model
from contactkit.recorder.importers.csv_import import CsvImporter
from contactkit.recorder.importers.csv_map import load_csv_map
from contactkit.recorder.metadata import session_meta, set_session_robot
from contactkit.recorder.sim.forces import add_synthetic_touches
from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.schemas import read_session
from tests.conftest import make_session, run_command, write_imported

FR3_MAP = Path(__file__).resolve().parents[2] / "recorder" / "data" / "fr3_teleop_csv_map.toml"
TOUCH_TIMES_S = (1.5, 4.0, 6.5, 9.0)
SYNTHETIC_VARIANTS = 4


@pytest.fixture(scope="module")
def default_model_path() -> Path:
    return build_default_model()


@pytest.fixture(scope="module")
def default_model(default_model_path):
    return load_model(default_model_path)


@pytest.fixture(scope="module")
def fr3_sessions(fr3_dir: Path, tmp_path_factory) -> list[Path]:
    out = tmp_path_factory.mktemp("fr3")
    cmap = load_csv_map(FR3_MAP)
    return [write_imported(CsvImporter.read(path, cmap),
                           session_meta(source="csv", action="none", robot=cmap.robot), out)
            for path in sorted(fr3_dir.glob("*.csv"))]


def test_imported_fr3_sessions_name_their_robot_and_agree_with_its_estimate(
        fr3_sessions) -> None:
    for path in fr3_sessions:
        meta = read_session(path).meta
        assert meta.robot == "fr3" and meta.with_hand
        agreement = meta.residual_agreement
        assert min(agreement["correlation"][:4]) >= 0.95, agreement
        assert max(agreement["rms_difference_nm"]) <= 0.2, agreement


def test_the_panda_model_does_not_fit_an_fr3(fr3_sessions, default_model_path,
                                             tmp_path: Path) -> None:
    result = run_command("replay", str(fr3_sessions[0]), "--viewer", "none", "--robot", "panda",
                         "--model", str(default_model_path), "--save", str(tmp_path / "panda.rrd"))
    assert result.returncode == 0, result.stderr
    # joint 2's correlation drops well below the FR3 model's 0.98
    line = result.stdout + result.stderr
    correlation = [float(v) for v in line.split("correlation ")[1].split(",")[0].split()]
    assert correlation[1] < 0.9 and correlation[3] < 0.5, line


def test_fr3_free_motion_has_no_contact_events(default_model, fr3_sessions) -> None:
    detector, events_model = default_model.detector_config(), default_model.event_model()
    for path in fr3_sessions:
        assert session_events(read_session(path), detector, events_model) == []


def test_synthetic_touches_on_the_real_fr3_recordings_are_found(default_model,
                                                                fr3_sessions) -> None:
    detector, events_model = default_model.detector_config(), default_model.event_model()
    found = total = false = 0
    for seed in range(SYNTHETIC_VARIANTS):
        for path in fr3_sessions:
            touched, touches = add_synthetic_touches(read_session(path),
                                                     np.random.default_rng(seed), TOUCH_TIMES_S)
            events = session_events(touched, detector, events_model)
            spans = [(c.onset_s, c.onset_s + c.duration_s) for c in touches]
            hits = [any(e.onset_s <= end + 0.2 and (e.release_s or np.inf) >= onset
                        for e in events) for onset, end in spans]
            found, total = found + sum(hits), total + len(spans)
            false += sum(not any(e.onset_s <= end + 0.2 and (e.release_s or np.inf) >= onset
                                 for onset, end in spans) for e in events)
    # the same touches on the real Panda's free-motion log: 80 % found (docs/results.md,
    # "On a real FR3"); the misses are on links 1-2, whose torque reaches few joints
    assert found >= 0.7 * total, (found, total)
    assert false == 0


def test_simulated_fr3_touches_are_found(default_model, tmp_path: Path) -> None:
    detector, events_model = default_model.detector_config(), default_model.event_model()
    found = 0
    links = (3, 4, 5, 6, 7, 2)
    for seed, link in enumerate(links):
        path = make_session(tmp_path, seed=seed, action="adjust", link=link, duration_s=5.0,
                            planned_at_s=2.0, rate_hz=1000.0, robot="fr3")
        session = read_session(path)
        assert session.meta.robot == "fr3"
        found += bool(session_events(session, detector, events_model))
    assert found >= len(links) - 1


def test_set_robot_corrects_a_session_and_robot_overrides_it(tmp_path: Path) -> None:
    path = make_session(tmp_path, seed=1, action="none", duration_s=1.0, planned_at_s=0.5)
    before = read_session(path)
    assert before.meta.robot == "panda"
    meta = set_session_robot(path, "fr3")
    after = read_session(path)
    assert meta.robot == after.meta.robot == "fr3"
    assert after.meta.urdf_sha256 == RobotModel(RobotSetup("fr3")).urdf_sha256
    assert after.table.equals(before.table.replace_schema_metadata(
        after.table.schema.metadata))
    result = run_command("recorder", "set-robot", str(path), "--robot", "kuka")
    assert result.returncode == 2 and "unknown robot 'kuka'" in result.stderr
    assert result.stderr.count("\n") == 1
