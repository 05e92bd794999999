"""Identified dynamics stored with a session (issue 41): `recorder set-robot --dynamics`
writes them into the metadata as values, every command that builds the session's arm
uses them unless `--dynamics` overrides them, `recorder info` shows them, and dynamics in
the metadata that fail the dynamics file's checks are one line, exit code 2."""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from contactkit.errors import InputError
from contactkit.features.detector import DetectorConfig
from contactkit.features.timeseries import ChainConfig
from contactkit.recorder.sim.simulator import ArmSimulator, SimConfig
from contactkit.robots.dynamics import ArmDynamics, ArmOverride, dynamics_checksum, save_dynamics
from contactkit.schemas import read_session
from contactkit.schemas.session import METADATA_KEY, read_session_meta
from tests.conftest import make_session, run_command, save_quick_model

NOISE = (0.61, 0.62, 0.63, 0.64, 0.35, 0.36, 0.37)
"""The detector's at-rest thresholds [Nm] the stored dynamics carry (not the model's)."""


@pytest.fixture(scope="module")
def truth() -> ArmDynamics:
    """A simulated Panda instance's true parameters (masses +-15 % off the nominal
    model), with detector thresholds of their own."""
    dynamics = ArmSimulator(SimConfig(robot_seed=7)).true_dynamics()
    return replace(dynamics, detector=json.dumps(DetectorConfig(noise=NOISE).to_dict(),
                                                 sort_keys=True))


@pytest.fixture(scope="module")
def other() -> ArmDynamics:
    """Another instance's parameters, for --dynamics over the stored ones."""
    return ArmSimulator(SimConfig(robot_seed=11)).true_dynamics()


@pytest.fixture(scope="module")
def files(tmp_path_factory, truth, other) -> dict[str, Path]:
    """A 1.5 s simulated bump at 200 Hz (nominal), the same carrying ``truth``, the two
    dynamics files and a quick model with a detector."""
    out = tmp_path_factory.mktemp("stored")
    plain = make_session(out, seed=4, action="bump", link=5, duration_s=1.5,
                         planned_at_s=0.7, rate_hz=200.0)
    stored = out / "stored.parquet"
    stored.write_bytes(plain.read_bytes())
    paths = {"plain": plain, "stored": stored,
             "truth": save_dynamics(out / "truth.json", truth),
             "other": save_dynamics(out / "other.json", other),
             "model": save_quick_model(out / "m.skops", events=True)}
    result = run_command("recorder", "set-robot", str(stored), "--dynamics",
                         str(paths["truth"]))
    assert result.returncode == 0, result.stderr
    return paths


def _copy(source: Path, target: Path, edit=None) -> Path:
    table = pq.read_table(source)
    doc = json.loads(table.schema.metadata[METADATA_KEY])
    if edit is not None:
        edit(doc)
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: json.dumps(doc).encode()}),
                   target)
    return target


def _residual(path: Path, model, robot=None) -> np.ndarray:
    from contactkit.replay.engine import ReplayStream

    stream = ReplayStream(path, model, robot=robot)
    return np.vstack([block.r for block in stream.blocks()]), stream.detector


def test_the_metadata_holds_the_values_not_a_path(files, truth) -> None:
    meta, _ = read_session_meta(files["stored"])
    assert meta.dynamics == truth.to_dict()
    raw = pq.read_schema(files["stored"]).metadata[METADATA_KEY].decode()
    assert str(files["truth"]) not in raw and "truth.json" not in raw
    assert meta.robot_setup().dynamics == truth
    assert read_session(files["stored"]).t.size == read_session(files["plain"]).t.size


def test_a_session_carrying_dynamics_replays_with_them(files, truth, other) -> None:
    from contactkit.classify.modelfile import load_model

    model = load_model(files["model"])
    nominal, nominal_detector = _residual(files["plain"], model)
    stored, stored_detector = _residual(files["stored"], model)
    given, _ = _residual(files["plain"], model, ArmOverride(None, truth))
    assert np.abs(stored - nominal).max() > 0.05
    np.testing.assert_array_equal(stored, given)
    assert stored_detector.noise == NOISE != nominal_detector.noise
    # --dynamics overrides the stored ones (and their detector thresholds)
    overridden, detector = _residual(files["stored"], model, ArmOverride(None, other))
    np.testing.assert_array_equal(overridden,
                                  _residual(files["plain"], model, ArmOverride(None, other))[0])
    assert np.abs(overridden - stored).max() > 0.05
    assert detector.noise == nominal_detector.noise
    # the feature chain of every command: the session's own, or --dynamics'
    meta = read_session(files["stored"]).meta
    assert ChainConfig().robot_setup(meta).dynamics == truth
    assert ChainConfig(dynamics=other).robot_setup(meta).dynamics == other
    assert ChainConfig(robot="fr3").robot_setup(meta).dynamics is None  # another arm


def test_features_and_predict_use_the_stored_dynamics(files, tmp_path) -> None:
    out = {}
    for name, extra in (("plain", []), ("stored", []),
                        ("given", ["--dynamics", str(files["truth"])])):
        source = files["stored" if name == "stored" else "plain"]
        target = tmp_path / f"{name}.parquet"
        result = run_command("classify", "features", str(source), "--out", str(target),
                             "--window", "planned", *extra)
        assert result.returncode == 0, result.stderr
        table = pq.read_table(target)
        out[name] = np.array([table.column(c)[0].as_py() for c in table.column_names
                              if c.startswith("range(r_")])
    np.testing.assert_allclose(out["stored"], out["given"], rtol=0, atol=1e-12)
    assert np.abs(out["stored"] - out["plain"]).max() > 0.01
    result = run_command("classify", "predict", str(files["model"]), str(files["stored"]),
                         "--events", "--json")
    assert result.returncode == 0, result.stderr


def test_set_robot_follows_a_link_keeps_the_mode_and_clears(files, tmp_path, truth) -> None:
    target = tmp_path / "real.parquet"
    target.write_bytes(files["plain"].read_bytes())
    target.chmod(0o640)
    link = tmp_path / "link.parquet"
    link.symlink_to(target)
    result = run_command("recorder", "set-robot", str(link), "--dynamics", str(files["truth"]))
    assert result.returncode == 0, result.stderr
    assert "identified dynamics" in result.stderr
    assert link.is_symlink() and link.resolve() == target
    assert read_session_meta(target)[0].dynamics == truth.to_dict()
    assert target.stat().st_mode & 0o777 == 0o640
    # naming another arm drops them; --clear-dynamics removes them
    result = run_command("recorder", "set-robot", str(link), "--clear-dynamics")
    assert result.returncode == 0 and "nominal model" in result.stderr
    assert read_session_meta(target)[0].dynamics is None
    assert target.stat().st_mode & 0o777 == 0o640 and link.is_symlink()
    run_command("recorder", "set-robot", str(link), "--dynamics", str(files["truth"]))
    result = run_command("recorder", "set-robot", str(link), "--robot", "fr3")
    assert result.returncode == 0, result.stderr
    meta = read_session_meta(target)[0]
    assert meta.robot == "fr3" and meta.dynamics is None


@pytest.mark.parametrize("kind", ["dangling", "directory", "fifo", "read-only", "other arm",
                                  "no option"])
def test_set_robot_refuses_in_one_line(files, tmp_path, kind) -> None:
    link = tmp_path / "link.parquet"
    args = ["--dynamics", str(files["truth"])]
    if kind == "dangling":
        link.symlink_to(tmp_path / "gone.parquet")
    elif kind == "directory":
        (tmp_path / "dir").mkdir()
        link.symlink_to(tmp_path / "dir")
    elif kind == "fifo":
        os.mkfifo(tmp_path / "fifo")
        link.symlink_to(tmp_path / "fifo")
    elif kind == "read-only":
        (tmp_path / "ro.parquet").write_bytes(files["plain"].read_bytes())
        (tmp_path / "ro.parquet").chmod(0o444)
        link.symlink_to(tmp_path / "ro.parquet")
    else:
        link.write_bytes(files["plain"].read_bytes())
        args = ["--robot", "fr3", *args] if kind == "other arm" else []
    before = {p.name: p.lstat().st_mtime_ns for p in tmp_path.iterdir()}
    result = run_command("recorder", "set-robot", str(link), *args)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert {p.name: p.lstat().st_mtime_ns for p in tmp_path.iterdir()} == before
    if kind == "other arm":
        assert "not a 'fr3'" in result.stderr


def _signed(doc: dict) -> dict:
    body = {k: v for k, v in doc.items() if k != "checksum"}
    return body | {"checksum": dynamics_checksum(body)}


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["links"][2].__setitem__(0, 1.5), "checksum"),  # changed, not re-signed
    (lambda d: _signed(d | {"robot": "fr3"}), "not a 'panda'"),  # another arm
    (lambda d: _signed(d | {"with_hand": False}), "without the hand"),
    (lambda d: _signed(d | {"links": [[-1.0, *d["links"][0][1:]], *d["links"][1:]]}),
     "mass"),
    (lambda d: _signed(d | {"armature_kgm2": [-0.1] * 7}), "armature"),
    (lambda d: d.update(format="x"), "not a dynamics file"),
    (lambda d: d.pop("friction") and None, "lacks"),
    (lambda d: "arm.json", "wrong type"),  # a path, not the values
    (lambda d: d["links"][0].__setitem__(0, float("nan")), "not finite"),
], ids=["tampered", "other-arm", "hand", "mass", "armature", "format", "missing", "path",
        "nan"])
def test_bad_dynamics_in_the_metadata_are_one_line_exit_2(files, tmp_path, edit,
                                                          message) -> None:
    def change(doc: dict) -> None:
        changed = edit(doc["dynamics"])
        if changed is not None:
            doc["dynamics"] = changed

    bad = _copy(files["stored"], tmp_path / "bad.parquet", change)
    for args in (("recorder", "info", str(bad)),
                 ("replay", str(bad), "--model", str(files["model"]), "--viewer", "none",
                  "--save", str(tmp_path / "x.rrd")),
                 ("classify", "predict", str(files["model"]), str(bad))):
        result = run_command(*args)
        assert result.returncode == 2, (args, result.stderr)
        err = " ".join(result.stderr.split())
        assert "Traceback" not in err and "bad.parquet" in err and "metadata dynamics" in err
        assert message in err, err
    assert not (tmp_path / "x.rrd").exists()


def test_info_shows_the_dynamics_or_nominal(files, tmp_path) -> None:
    result = run_command("recorder", "info", str(files["stored"]))
    assert result.returncode == 0, result.stderr
    line = " ".join(result.stdout.split())
    assert "dynamics" in line and "simulator's true parameters" in line
    assert "detector thresholds" in line
    doc = json.loads(run_command("recorder", "info", str(files["stored"]), "--json").stdout)
    assert doc["dynamics"]["robot"] == "panda" and "dynamics" not in doc["metadata"]
    assert doc["dynamics"]["checksum"].startswith("sha256:")
    plain = run_command("recorder", "info", str(files["plain"]))
    assert "nominal" in plain.stdout
    assert json.loads(run_command("recorder", "info", str(files["plain"]), "--json").stdout
                      )["dynamics"] == "nominal"


# -- live capture with identified dynamics --------------------------------------------------

def _values(files: dict[str, Path], **given) -> dict:
    return {"events": True, "model": files["model"], "calibration": None,
            "decide_after": None, "dynamics": files["truth"], "robot_load": False} | given


class _LoadedRobot:
    """A source that reports a configured load, as the franka source does once
    connected, and the arm ``robot``."""

    def __init__(self, robot: str = "panda") -> None:
        self.robot = robot

    def metadata(self) -> dict:
        return {"source": "franka", "robot": self.robot, "payload_kg": 1.2,
                "payload_com_m": [0.0, 0.0, 0.05], "source_info": {"m_load_kg": 1.2}}


def _chunk(path: Path, rows: int = 50) -> dict[str, np.ndarray]:
    table = pq.read_table(path)
    return {name: table.column(name).to_numpy()[:rows] for name in table.column_names}


def test_capture_events_run_live_with_the_dynamics(files, truth) -> None:
    from contactkit.cli.recorder import _start_events

    meta = read_session(files["plain"]).meta
    listener = _start_events(_values(files), meta, _LoadedRobot())
    assert meta.dynamics == truth.to_dict()
    live = listener.listener  # built before the capture
    assert live.chain.model.setup.dynamics == truth
    assert live.pipeline.detector.config.noise == NOISE
    listener.on_chunk(_chunk(files["plain"]))
    assert live.samples == 50 and listener.session_fields()["dynamics"] == truth.to_dict()
    # the robot's configured load becomes the identification's payload, from the first
    # chunk on (the live model too)
    meta = read_session(files["plain"]).meta
    listener = _start_events(_values(files, robot_load=True), meta, _LoadedRobot())
    listener.on_chunk(_chunk(files["plain"]))
    stored = listener.session_fields()["dynamics"]
    assert stored["payload"]["mass_kg"] == 1.2 and stored["links"][:6] == meta.dynamics[
        "links"][:6] == truth.to_dict()["links"][:6]
    assert stored["links"][6] != truth.to_dict()["links"][6]
    assert listener.listener.chain.model.setup.dynamics.payload.mass_kg == 1.2
    assert "events" in listener.session_fields()
    # a robot that names another arm once connected stops the capture at its first chunk
    listener = _start_events(_values(files), read_session(files["plain"]).meta,
                             _LoadedRobot("fr3"))
    with pytest.raises(InputError, match="not a 'fr3'"):
        listener.on_chunk(_chunk(files["plain"]))
    # without --events: stored all the same; --robot-load needs --dynamics
    meta = read_session(files["plain"]).meta
    listener = _start_events(_values(files, events=False, model=None), meta, _LoadedRobot())
    assert listener.listener is None and meta.dynamics == truth.to_dict()
    with pytest.raises(InputError, match="--robot-load needs --dynamics"):
        _start_events(_values(files, dynamics=None, robot_load=True), meta, None)


def test_simulated_capture_stores_the_dynamics(files, tmp_path, truth) -> None:
    out = tmp_path / "captured"
    result = run_command("recorder", "capture", "--pose", "B", "--action", "bump", "--link",
                         "5", "--duration", "1.5", "--planned-at", "0.7", "--rate", "250",
                         "--seed", "4", "--events", "--model", str(files["model"]),
                         "--dynamics", str(files["truth"]), "--out", str(out))
    assert result.returncode == 0, result.stderr
    meta = read_session(result.stdout.strip()).meta
    assert meta.dynamics == truth.to_dict() and isinstance(meta.events, list)
    # another arm's dynamics are refused before anything is recorded
    fr3 = save_dynamics(tmp_path / "fr3.json", ArmSimulator(
        SimConfig(robot="fr3", robot_seed=3)).true_dynamics())
    result = run_command("recorder", "capture", "--pose", "B", "--action", "none",
                         "--duration", "1", "--planned-at", "0.5", "--dynamics", str(fr3),
                         "--out", str(out))
    assert result.returncode == 2 and "not a 'panda'" in result.stderr
    assert len(list(out.glob("*.parquet"))) == 1


@pytest.mark.skipif(not all(__import__("importlib").util.find_spec(m)
                            for m in ("pylibfranka", "franky_sim")),
                    reason="pylibfranka and franky-sim not installed (contactkit[sim-robot])")
def test_franka_capture_with_dynamics_and_the_robot_load(files, tmp_path) -> None:
    """Against franky-sim (a simulated FR3 behind the FCI protocol, on loopback): the
    session carries the FR3's identified dynamics, their payload the load the robot
    reports, and the live events were found with them."""
    from tests.recorder.test_franka import start_server, stop_server

    fr3 = ArmSimulator(SimConfig(robot="fr3", robot_seed=3)).true_dynamics()
    path = save_dynamics(tmp_path / "fr3.json", replace(fr3, payload=replace(
        fr3.payload, mass_kg=0.4)))
    proc, host = start_server()
    try:
        result = run_command("recorder", "capture", "--source", "franka", "--host", host,
                             "--backend", "pylibfranka", "--robot", "fr3", "--pose", "A",
                             "--action", "none", "--duration", "1", "--planned-at", "0.5",
                             "--events", "--model",
                             str(files["model"]), "--dynamics", str(path), "--robot-load",
                             "--out", str(tmp_path / "out"))
    finally:
        stop_server(proc)
    assert result.returncode == 0, result.stderr
    session = read_session(result.stdout.strip())
    meta = session.meta
    load = meta.source_info.get("m_load_kg")
    assert meta.robot == "fr3" and load is not None and isinstance(meta.events, list)
    assert meta.residual_agreement  # measured with the model the session carries
    stored = meta.arm_dynamics()
    assert stored.payload.mass_kg == meta.payload_kg == load
    assert stored.provenance_doc["payload"]["from"] == "the robot's configured load"
    assert stored.inertias[:6] == fr3.inertias[:6]


# -- training, evaluation and export --------------------------------------------------------

@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """Eight 1.5 s sessions (none and bump, four poses) at 200 Hz."""
    out = tmp_path_factory.mktemp("dataset")
    for seed, (action, pose) in enumerate([(a, p) for p in "ABCD" for a in ("none", "bump")]):
        make_session(out, seed=seed, action=action, pose=pose, link=5, duration_s=1.5,
                     planned_at_s=0.7, rate_hz=200.0)
    return out


def test_train_and_evaluate_take_dynamics(files, dataset, tmp_path, monkeypatch, truth) -> None:
    from contactkit.classify.grids import GridSpec, load_grids
    from contactkit.classify.kinds.kind import ModelOptions
    from contactkit.classify.modelfile import load_model
    from contactkit.classify.training import training_set

    monkeypatch.setenv("CONTACTKIT_CACHE", str(tmp_path / "cache"))
    options = ModelOptions(kind="svm", window="planned")
    nominal, identified = (training_set([dataset], options, dynamics=d).data.X
                           for d in (None, truth))
    assert np.abs(nominal - identified).max() > 0.01  # the cache keeps them apart
    spec = GridSpec(timeseries=("r",), steps=20)
    grids = [load_grids([dataset], spec, dynamics=d).X for d in (None, truth)]
    assert np.abs(grids[0] - grids[1]).max() > 0.01
    result = run_command("classify", "train", str(dataset), "--out", str(tmp_path / "m.skops"),
                         "--window", "planned", "--workers", "1", "--dynamics",
                         str(files["truth"]))
    assert result.returncode == 0, result.stderr
    model = load_model(tmp_path / "m.skops")  # a model file does not carry the dynamics
    assert model.meta["training"]["dynamics"] == truth.checksum
    result = run_command("classify", "evaluate", str(dataset), "--protocol", "thesis",
                         "--window", "planned", "--workers", "1", "--dynamics",
                         str(tmp_path / "missing.json"))
    assert result.returncode == 2 and "missing.json" in result.stderr


def test_export_mcap_carries_the_dynamics(files, tmp_path, truth, other) -> None:
    from contactkit.recorder.importers.bags import BagImporter

    for name, extra, expected in (("stored", [], truth), ("given", ["--dynamics",
                                                                    str(files["other"])], other)):
        result = run_command("recorder", "export-mcap", str(files["stored"]), "--out",
                             str(tmp_path / f"{name}.mcap"), *extra)
        assert result.returncode == 0, result.stderr
        back = BagImporter.read(tmp_path / f"{name}.mcap").metadata(None)
        assert back.arm_dynamics() == expected


def test_identify_reads_no_stored_dynamics(tmp_path, truth) -> None:
    """Identification reads the arm's name and hand, not an earlier identification a
    session carries: the same result with some sessions carrying dynamics."""
    from contactkit.features.identification import identify_sessions
    from contactkit.recorder.sim.dataset import simulate_dataset
    from contactkit.schemas.dataset import session_files

    simulate_dataset(tmp_path / "free", "free-motion", 4, 3, 1,
                     SimConfig(rate_hz=250.0, robot_seed=7))
    paths = session_files(tmp_path / "free")
    before = identify_sessions(paths).dynamics
    save_dynamics(tmp_path / "truth.json", truth)
    result = run_command("recorder", "set-robot", str(paths[0]), "--dynamics",
                         str(tmp_path / "truth.json"))
    assert result.returncode == 0, result.stderr
    after = identify_sessions(paths).dynamics
    assert replace(after, provenance="{}") == replace(before, provenance="{}")
