"""The identified arm simulated (issue 41, part 4): `recorder capture --source sim
--dynamics` and `recorder simulate --dynamics` simulate an identified arm; the loop
excite -> simulated capture -> identify -> replay recovers the simulated arm's parameters
within what the excitation determines; the default model's recipe re-runs for an
identified arm, under its own cache key, and replay uses that model as any other."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from contactkit.cli.default_model import RECIPE, build_default_model, recipe_dir
from contactkit.recorder.excitation import ExcitationSettings, excite
from contactkit.recorder.protocol import pose_q
from contactkit.recorder.sim.simulator import ArmSimulator, SimConfig
from contactkit.recorder.trajectory import read_trajectory, write_trajectory
from contactkit.robots import RobotSetup
from contactkit.robots.dynamics import ArmDynamics, load_dynamics, save_dynamics
from contactkit.robots.model import RobotModel
from contactkit.schemas import InputError, read_session
from contactkit.schemas.dataset import session_files
from tests.conftest import make_session, run_command, save_quick_model

PANDA = RobotSetup("panda", True)
# 8 s, two periods: every joint moves (the loop of tests/recorder/test_excite.py)
SETTINGS = ExcitationSettings(duration_s=8.0, harmonics=5, base_hz=0.25, seed=2, budget_s=4.0)
# The recipe with a few sessions per preset (some 20 s): the build, not the model, is
# tested (smoke's first 6: poses A and B with none, bump and adjust)
TINY_RECIPE = {**RECIPE, "presets": {"smoke": 6},
               "event_presets": {"free-motion": 1, "mixed-motion": 2}, "range_presets": {}}


def _truth(robot_seed: int, robot: str = "panda") -> ArmDynamics:
    return ArmSimulator(SimConfig(robot=robot, robot_seed=robot_seed)).true_dynamics()


@pytest.fixture(scope="module")
def trajectory(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An 8 s exciting trajectory of the Panda from pose A."""
    result = excite(PANDA, pose_q("A"), SETTINGS)
    return write_trajectory(tmp_path_factory.mktemp("traj") / "traj.csv",
                            result.trajectory.sampled("panda"))


@pytest.fixture(scope="module")
def quick_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_quick_model(tmp_path_factory.mktemp("model") / "m.skops", events=True)


@pytest.fixture(scope="module")
def truth_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The true parameters of simulated Panda instance 5, as a dynamics file."""
    return save_dynamics(tmp_path_factory.mktemp("dyn") / "truth5.json", _truth(5))


def _capture(out: Path, *args: str) -> Path:
    done = run_command("recorder", "capture", "--source", "sim", "--pose", "A", "--seed", "4",
                       "--out", str(out), *args)
    assert done.returncode == 0, done.stderr
    return Path(done.stdout.strip())


def _torque(dynamics: ArmDynamics | None, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
            ) -> np.ndarray:
    """Return the joint torque [Nm] (n, 7) the model (None: nominal) predicts for a motion."""
    model = RobotModel(PANDA if dynamics is None else replace(PANDA, dynamics=dynamics))
    tau = np.array([model.inverse_dynamics(*row) for row in zip(q, dq, ddq, strict=True)])
    return tau if model.friction is None else tau + model.friction.torque(dq)


def _centred_rms(values: np.ndarray) -> np.ndarray:
    """Return each column's RMS about its mean: a constant per joint (a torque sensor's
    bias, which moves between sessions) is not what a motion determines."""
    return np.sqrt(((values - values.mean(axis=0)) ** 2).mean(axis=0))


def _residual_rms(session: Path, dynamics: ArmDynamics | None) -> np.ndarray:
    """Return the observer residual's RMS about its mean per joint [Nm] after 0.5 s, as
    replay computes it with the model of ``dynamics`` (None: nominal)."""
    from contactkit.features.timeseries import TimeseriesChain

    s = read_session(session)
    setup = PANDA if dynamics is None else replace(PANDA, dynamics=dynamics)
    r = TimeseriesChain(robot=setup, names=["r"]).compute(s.t, s.q, s.dq, s.tau)["r"]
    return _centred_rms(r[s.t > 0.5])


def _loop(trajectory: Path, tmp_path: Path, model: Path, truth: ArmDynamics, *capture: str
          ) -> dict[str, np.ndarray]:
    """Capture the trajectory on the simulated arm, identify it with `recorder identify`,
    replay it with the identification; return the figures the tests check."""
    session = _capture(tmp_path / "sessions", "--trajectory", str(trajectory),
                       "--action", "none", *capture)
    out = tmp_path / "identified.json"
    done = run_command("recorder", "identify", str(session), "--out", str(out))
    assert done.returncode == 0, done.stderr
    identified = load_dynamics(out, PANDA)
    # the torques the trajectory asks of the arm, as each model predicts them (every 5th
    # sample): what the excitation determines is these, up to a constant per joint
    path = read_trajectory(trajectory, "panda")
    q, dq, ddq = path.q[::5], path.dq[::5], path.ddq[::5]
    true_tau = _torque(truth, q, dq, ddq)
    replayed = run_command("replay", str(session), "--model", str(model),
                           "--dynamics", str(out), "--viewer", "none",
                           "--save", str(tmp_path / "r.rrd"))
    assert replayed.returncode == 0, replayed.stderr
    assert "no contact event" in replayed.stdout + replayed.stderr
    return {"torque_nominal": _centred_rms(_torque(None, q, dq, ddq) - true_tau),
            "torque_identified": _centred_rms(_torque(identified, q, dq, ddq) - true_tau),
            "r_nominal": _residual_rms(session, None),
            "r_identified": _residual_rms(session, identified),
            "r_floor": _residual_rms(session, truth)}




def _check_recovered(figures: dict[str, np.ndarray]) -> None:
    """The identification predicts the trajectory's torques of the true arm to a few
    hundredths of what the nominal model misses, and its replay residual is at the
    true-parameter floor, well below the nominal model's excess over it."""
    nominal, identified = figures["torque_nominal"], figures["torque_identified"]
    assert (identified < 0.02).all() and identified.sum() < 0.1 * nominal.sum(), figures
    floor = figures["r_floor"]
    assert (figures["r_identified"] <= 1.05 * floor + 0.002).all(), figures
    excess = np.sqrt(np.maximum(figures["r_nominal"] ** 2 - floor ** 2, 0.0))
    excess_identified = np.sqrt(np.maximum(figures["r_identified"] ** 2 - floor ** 2, 0.0))
    assert excess_identified.sum() < 0.1 * excess.sum(), figures


def test_loop_recovers_a_random_instance(trajectory: Path, quick_model: Path,
                                        tmp_path: Path) -> None:
    """excite -> capture on robot instance 11 -> identify -> replay (issue 41's loop)."""
    _check_recovered(_loop(trajectory, tmp_path, quick_model, _truth(11), "--robot-seed",
                           "11"))


def test_loop_recovers_a_simulated_identified_arm(trajectory: Path, truth_file: Path,
                                                  quick_model: Path, tmp_path: Path) -> None:
    """The same loop on an arm given as a dynamics file (capture --dynamics): the file is
    the simulated arm's truth, so identifying its recording gives it back."""
    _check_recovered(_loop(trajectory, tmp_path, quick_model, load_dynamics(truth_file),
                           "--dynamics", str(truth_file)))


def test_the_simulated_arm_is_the_file(truth_file: Path, tmp_path: Path) -> None:
    """The plant carries the file's links, friction and armature unperturbed; its values
    are in the session's simulator metadata and make its id; without dynamics a
    configuration's document has no such entry (session ids and cache keys unchanged)."""
    truth = load_dynamics(truth_file)
    assert ArmSimulator(SimConfig(dynamics=truth)).true_dynamics().to_dict()["links"] == \
        truth.to_dict()["links"]
    heavier = replace(truth, armature_kgm2=(0.05,) * 7)
    assert ArmSimulator(SimConfig(dynamics=heavier)).plant.model.armature.tolist() == \
        pytest.approx([0.15] * 4 + [0.05] * 3)  # the motors' 0.1 on joints 1-4, plus the file's
    assert "dynamics" not in SimConfig().to_dict()
    with_file = _capture(tmp_path, "--dynamics", str(truth_file), "--action", "none",
                         "--duration", "3", "--planned-at", "1")
    nominal = _capture(tmp_path, "--action", "none", "--duration", "3", "--planned-at", "1")
    meta = read_session(with_file).meta
    simulated = meta.simulator["config"]["dynamics"]
    assert simulated["checksum"] == truth.checksum and simulated["links"] == \
        json.loads(truth_file.read_text())["links"]
    assert "dynamics" not in read_session(nominal).meta.simulator["config"]
    assert meta.session_id != read_session(nominal).meta.session_id
    # one --dynamics: the sim source simulates the arm and the session carries it
    assert meta.dynamics is not None and meta.dynamics["checksum"] == truth.checksum
    assert read_session(nominal).meta.dynamics is None
    # the same file, the same session: simulate --dynamics writes it under the same name
    again = run_command("recorder", "simulate", str(tmp_path / "set"), "--preset", "smoke",
                        "--sessions", "1", "--workers", "1", "--dynamics", str(truth_file),
                        "--write-dynamics", str(tmp_path / "written.json"))
    assert again.returncode == 0, again.stderr
    written = load_dynamics(tmp_path / "written.json")
    assert written.inertias == truth.inertias and written.friction == truth.friction
    (first,) = session_files(tmp_path / "set")
    assert read_session(first).meta.simulator["config"]["dynamics"]["checksum"] == \
        truth.checksum


def _tampered(source: Path, target: Path) -> Path:
    doc = json.loads(source.read_text())
    doc["links"][2][0] *= 1.1
    target.write_text(json.dumps(doc))
    return target


BAD = {
    "another arm": (lambda tmp, truth: save_dynamics(tmp / "fr3.json", _truth(5, "fr3")),
                    (), "not a 'panda'"),
    "another hand": (lambda tmp, truth: truth, ("--no-hand",), "with the hand"),
    "tampered": (lambda tmp, truth: _tampered(truth, tmp / "bad.json"), (), "checksum"),
    "missing": (lambda tmp, truth: tmp / "none.json", (), ""),
    "with an instance": (lambda tmp, truth: truth, ("--robot-seed", "3"), "--robot-seed"),
}


@pytest.mark.parametrize("case", sorted(BAD))
@pytest.mark.parametrize("command", ["capture", "simulate"])
def test_bad_dynamics_are_refused_in_one_line(truth_file: Path, tmp_path: Path, case: str,
                                              command: str) -> None:
    make, extra, message = BAD[case]
    if command == "simulate" and extra == ("--no-hand",):
        pytest.skip("simulate has no --no-hand (its presets carry the hand)")
    path = make(tmp_path, truth_file)
    if command == "capture":
        args = ("capture", "--source", "sim", "--pose", "A", "--action", "none",
                "--out", str(tmp_path / "out"))
    else:
        args = ("simulate", str(tmp_path / "out"), "--preset", "smoke", "--sessions", "1",
                "--workers", "1")
    done = run_command("recorder", *args, "--dynamics", str(path), *extra)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines
    assert "--robot-seed" in message or str(path) in lines[0]
    assert not list(tmp_path.rglob("*.parquet"))


def test_default_model_cache_key(truth_file: Path) -> None:
    """The default model keeps its key; an identified arm's differs, and with any of its
    simulated values, and with its checksum (which names the whole file)."""
    truth = load_dynamics(truth_file)
    assert recipe_dir() == recipe_dir(None, RECIPE)
    keyed = recipe_dir(truth)
    assert keyed != recipe_dir()
    friction = tuple(tuple(v * (1.01 if i == 0 else 1.0) for v in row)
                     for i, row in enumerate(truth.friction))
    assert recipe_dir(replace(truth, friction=friction)) != keyed
    assert recipe_dir(replace(truth, provenance="{}")) != keyed  # the checksum names it
    assert recipe_dir(truth, TINY_RECIPE) not in (keyed, recipe_dir(None, TINY_RECIPE))


def test_a_model_trained_on_a_simulated_identified_arm_replays_as_any_other(
        truth_file: Path, tmp_path: Path) -> None:
    """Sessions captured on the identified arm train a model (`classify train`) that
    replay uses with --model and --dynamics."""
    data = tmp_path / "data"
    for seed, action in enumerate(("none", "shove", "none", "shove")):
        _capture(data, "--dynamics", str(truth_file), "--action", action, "--link", "6",
                 "--duration", "3", "--planned-at", "1", "--rate", "250",
                 "--seed", str(seed))
    model = tmp_path / "m.skops"
    trained = run_command("classify", "train", str(data), "--out", str(model), "--workers",
                          "1")
    assert trained.returncode == 0, trained.stderr
    session = make_session(tmp_path, seed=5, action="shove", link=6, duration_s=3.0)
    done = run_command("replay", str(session), "--model", str(model), "--dynamics",
                       str(truth_file), "--viewer", "none", "--save", str(tmp_path / "r.rrd"))
    assert done.returncode == 0, done.stderr
    assert "predicted" in done.stdout + done.stderr


@pytest.mark.slow
def test_a_default_model_built_for_an_identified_arm_replays_as_any_other(
        truth_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The recipe (a tiny one, some 20 s) re-run for an identified arm simulates that arm
    and trains a model replay uses with --model and --dynamics."""
    monkeypatch.setenv("CONTACTKIT_CACHE", str(tmp_path / "cache"))
    truth = load_dynamics(truth_file)
    model = build_default_model(workers=1, dynamics=truth, recipe=TINY_RECIPE)
    assert model.parent == recipe_dir(truth, TINY_RECIPE) and model.exists()
    for preset in ("smoke", "free-motion"):
        first = session_files(model.parent / preset)[0]
        assert read_session(first).meta.simulator["config"]["dynamics"]["checksum"] == \
            truth.checksum
    session = make_session(tmp_path, seed=5, action="shove", link=6, duration_s=3.0)
    done = run_command("replay", str(session), "--model", str(model), "--dynamics",
                       str(truth_file), "--viewer", "none", "--save", str(tmp_path / "r.rrd"))
    assert done.returncode == 0, done.stderr
    assert "contact event" in done.stdout + done.stderr


def test_replay_builds_the_default_model_for_an_identified_arm(
        truth_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`replay --build-default-model --dynamics FILE` passes the checked file to the
    recipe; a file for another arm than --robot is refused in one line."""
    import contactkit.cli.default_model as default_model

    built = []

    def build(**kwargs: object) -> Path:
        built.append(kwargs)
        return tmp_path / "model.skops"

    monkeypatch.setattr(default_model, "build_default_model", build)
    done = run_command("replay", "--build-default-model", "--dynamics", str(truth_file))
    assert done.returncode == 0, done.stderr
    assert built[0]["dynamics"] == load_dynamics(truth_file)
    assert built[0]["rebuild"] is False  # a cached model is kept unless --overwrite
    assert done.stdout.strip() == str(tmp_path / "model.skops")
    again = run_command("replay", "--build-default-model", "--dynamics", str(truth_file),
                        "--overwrite")
    assert again.returncode == 0, again.stderr
    assert built[1]["rebuild"] is True
    wrong = run_command("replay", "--build-default-model", "--dynamics", str(truth_file),
                        "--robot", "fr3")
    assert wrong.returncode == 2 and len(wrong.stderr.strip().splitlines()) == 1
    assert "not a 'fr3'" in wrong.stderr and len(built) == 2


def test_simulator_config_refuses_another_arms_dynamics(truth_file: Path) -> None:
    with pytest.raises(InputError, match="not a 'fr3'"):
        SimConfig(robot="fr3", dynamics=load_dynamics(truth_file))
