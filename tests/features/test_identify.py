"""Identifying an arm's dynamics from free motion, the dynamics file and its checks."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from contactkit.classify.modelfile.model_file import load_model
from contactkit.errors import InputError
from contactkit.features import identification
from contactkit.features.detector import DetectorConfig, dynamics_detector
from contactkit.features.identification import Motion, identify, identify_sessions
from contactkit.features.timeseries import ChainConfig, TimeseriesChain
from contactkit.recorder.sim.dataset import preset_specs, simulate_dataset, simulate_specs
from contactkit.recorder.sim.presets import PRESETS
from contactkit.recorder.sim.simulator import ArmSimulator, SimConfig
from contactkit.robots import RobotSetup
from contactkit.robots.dynamics import (
    MAX_BYTES,
    ArmDynamics,
    ArmOverride,
    consistent,
    dynamics_checksum,
    from_pseudo_inertia,
    load_dynamics,
    pseudo_inertia,
    save_dynamics,
)
from contactkit.schemas import read_session, write_session
from contactkit.schemas.dataset import session_files
from tests.conftest import make_session, run_command, save_quick_model

ROBOT_SEED = 7
RATE_HZ = 250.0


@pytest.fixture(scope="module")
def free_motion(tmp_path_factory) -> list[Path]:
    """Eight 8 s free-motion sessions of one simulated Panda instance at 250 Hz."""
    out = tmp_path_factory.mktemp("free")
    config = SimConfig(rate_hz=RATE_HZ, robot_seed=ROBOT_SEED)
    simulate_dataset(out, "free-motion", 8, 3, 1, config)
    return session_files(out)


@pytest.fixture(scope="module")
def mixed_motion(tmp_path_factory) -> list[Path]:
    """Eight 8 s sessions of the same instance, moving: two without contact, then a
    bump, an adjust and a shove on the way, each at two poses."""
    out = tmp_path_factory.mktemp("mixed")
    specs = preset_specs(PRESETS["mixed-motion"], 32, 3)
    simulate_specs([specs[k] for k in (0, 1, 8, 9, 16, 17, 24, 25)],
                   SimConfig(rate_hz=RATE_HZ, robot_seed=ROBOT_SEED), out)
    return session_files(out)


@pytest.fixture(scope="module")
def quick_model(tmp_path_factory) -> Path:
    return save_quick_model(tmp_path_factory.mktemp("model") / "m.skops", events=True)


@pytest.fixture(scope="module")
def identified(free_motion) -> ArmDynamics:
    return identify_sessions(free_motion[:6]).dynamics


def _rms(paths: list[Path], setup: RobotSetup) -> np.ndarray:
    chain = TimeseriesChain(robot=setup, names=["r"])
    residuals = []
    for path in paths:
        s = read_session(path)
        residuals.append(chain.compute(s.t, s.q, s.dq, s.tau)["r"][s.t > 0.5])
    return np.sqrt((np.concatenate(residuals) ** 2).mean(axis=0))


def test_identification_reaches_the_true_parameter_floor(free_motion, identified) -> None:
    setup = RobotSetup("panda", True)
    truth = ArmSimulator(SimConfig(rate_hz=RATE_HZ, robot_seed=ROBOT_SEED)).true_dynamics()
    held_out = free_motion[6:]
    before = _rms(held_out, setup)
    after = _rms(held_out, replace(setup, dynamics=identified))
    floor = _rms(held_out, replace(setup, dynamics=truth))
    assert (after < before).all()
    assert all(consistent(np.array(link)) for link in identified.inertias)
    assert (after <= 1.5 * floor + 0.01).all(), (before, after, floor)
    # friction amplitudes within 15 % of the instance's (scaled +-40 % from nominal)
    phi1, true_phi1 = np.array(identified.friction[0]), np.array(truth.friction[0])
    assert np.abs(phi1 / true_phi1 - 1).max() < 0.15
    detector = dynamics_detector(identified)
    assert detector is not None and detector.robot == "panda"


def test_file_round_trip_and_checksum(tmp_path, identified) -> None:
    path = save_dynamics(tmp_path / "arm.json", identified)
    again = load_dynamics(path, RobotSetup("panda"))
    assert again == identified and again.checksum == identified.checksum
    assert hash(again) == hash(identified)
    with pytest.raises(InputError, match="exists"):
        save_dynamics(path, identified)


def _signed(doc: dict) -> dict:
    body = {k: v for k, v in doc.items() if k != "checksum"}
    return body | {"checksum": dynamics_checksum(body)}


@pytest.mark.parametrize(("change", "message"), [
    (lambda d: d["links"][2].__setitem__(0, 1.5), "checksum"),  # tampered, not re-signed
    (lambda d: _signed(d | {"robot": "nonexistent"}), "unknown robot"),
    (lambda d: _signed(d | {"links": [[-1.0, *d["links"][0][1:]], *d["links"][1:]]}),
     "mass"),
    (lambda d: _signed(d | {"links": [[d["links"][0][0], *d["links"][0][1:4], 1.0, 0.0,
                                       0.0, 0.0, 0.0, 0.0], *d["links"][1:]]}),
     "not physically consistent"),
    (lambda d: _signed(d | {"armature_kgm2": [-0.1] * 7}), "armature"),
])
def test_a_failing_check_is_refused_in_one_line(tmp_path, identified, change,
                                                 message) -> None:
    doc = identified.to_dict()
    changed = change(doc)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(changed if changed is not None else doc))
    with pytest.raises(InputError, match=message) as err:
        load_dynamics(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_non_finite_huge_and_deep_files_are_refused(tmp_path, identified) -> None:
    text = json.dumps(identified.to_dict()).replace(
        str(identified.to_dict()["links"][3][0]), "NaN", 1)
    cases = {"nan.json": (text, "not finite"),
             "huge.json": (" " * (MAX_BYTES + 1), "larger than"),
             "deep.json": ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
             "other.json": ("{}", "not a dynamics file")}
    for name, (content, message) in cases.items():
        path = tmp_path / name
        path.write_text(content)
        with pytest.raises(InputError, match=message):
            load_dynamics(path)


def test_dynamics_of_another_arm_or_hand_are_refused(tmp_path, identified,
                                                      quick_model) -> None:
    path = save_dynamics(tmp_path / "arm.json", identified)
    with pytest.raises(InputError, match="not a 'fr3'"):
        load_dynamics(path, RobotSetup("fr3"))
    with pytest.raises(InputError, match="with the hand"):
        load_dynamics(path, RobotSetup("panda", with_hand=False))
    session = make_session(tmp_path, robot="fr3", action="none", link=None)
    result = run_command("replay", str(session), "--dynamics", str(path), "--model",
                         str(quick_model), "--viewer", "none", "--save", str(tmp_path / "x.rrd"))
    assert result.returncode == 2 and not (tmp_path / "x.rrd").exists()
    assert "'panda', not a 'fr3'" in result.stderr and str(path) in result.stderr


def test_dynamics_reach_replay_and_predict(tmp_path, free_motion, identified,
                                          quick_model) -> None:
    from contactkit.classify.modelfile import load_model
    from contactkit.classify.prediction import predict_sources
    from contactkit.replay.engine import ReplayStream

    model = load_model(quick_model)
    override = ArmOverride(None, identified)
    plain = ReplayStream(free_motion[6], model)
    streams = [plain, ReplayStream(free_motion[6], model, robot=override)]
    r = [np.vstack([block.r for block in stream.blocks()]) for stream in streams]
    assert np.abs(r[0] - r[1]).max() > 0.1
    assert streams[1].detector.noise == dynamics_detector(identified).noise
    assert streams[1].detector.noise != plain.detector.noise
    found = [predict_sources(model, [free_motion[6]], robot)[0][0].probabilities
             for robot in (None, override)]
    assert found[0] != found[1]
    path = save_dynamics(tmp_path / "arm.json", identified)
    result = run_command("classify", "predict", str(quick_model), str(free_motion[6]),
                         "--dynamics", str(path))
    assert result.returncode == 0, result.stderr


def test_the_result_uses_no_simulator_metadata(tmp_path, free_motion) -> None:
    stripped = []
    for path in free_motion[:3]:
        session = read_session(path)
        session.meta.simulator = None
        out = tmp_path / path.name
        write_session(out, session.table, session.meta)
        stripped.append(out)
    first = identify_sessions(free_motion[:3]).dynamics
    second = identify_sessions(stripped).dynamics
    assert replace(first, provenance="{}") == replace(second, provenance="{}")


def test_batch_and_per_sample_agree_with_viscous_and_offset(free_motion) -> None:
    s = read_session(free_motion[0])
    friction = ((0.5,) * 7, (8.0,) * 7, (0.02,) * 7, (0.3,) * 7, (0.2, -0.1, 0, 0, 0.1, 0, 0))
    base = ArmSimulator(SimConfig(rate_hz=RATE_HZ, robot_seed=ROBOT_SEED)).true_dynamics()
    setup = RobotSetup("panda", True, dynamics=replace(base, friction=friction))
    n = 300
    batch = TimeseriesChain(robot=setup, names=["r"]).compute(
        s.t[:n], s.q[:n], s.dq[:n], s.tau[:n])["r"]
    chain = TimeseriesChain(robot=setup, names=["r"])
    stepped = np.vstack([chain.update(s.t[k], s.q[k], s.dq[k], s.tau[k])["r"]
                         for k in range(n)])
    assert np.abs(stepped - batch).max() <= 1e-9
    without = TimeseriesChain(robot=replace(setup, dynamics=base), names=["r"]).compute(
        s.t[:n], s.q[:n], s.dq[:n], s.tau[:n])["r"]
    assert np.abs(without - batch).max() > 0.05  # the terms are used


def test_chain_cache_key_changes_with_the_dynamics(free_motion, identified) -> None:
    from contactkit.features.chain_cache import _key

    session = read_session(free_motion[0])
    keys = {_key(session, ChainConfig()), _key(session, ChainConfig(dynamics=identified))}
    assert len(keys) == 2


def test_motion_that_determines_nothing_is_refused(free_motion) -> None:
    s = read_session(free_motion[0])
    still = Motion(s.t, np.repeat(s.q[:1], len(s.t), axis=0), np.zeros_like(s.dq),
                   np.repeat(s.tau[:1], len(s.t), axis=0))
    with pytest.raises(InputError, match="no joint moves"):
        identify([still], RobotSetup())
    short = Motion(s.t[:300], s.q[:300], s.dq[:300], s.tau[:300])
    with pytest.raises(InputError, match="too little free motion"):
        identify([short], RobotSetup())


def test_identify_cli_refuses_bad_input_in_one_line(tmp_path, free_motion) -> None:
    out = tmp_path / "arm.json"
    shove = make_session(tmp_path, action="shove")
    result = run_command("recorder", "identify", str(shove), "--out", str(out))
    assert result.returncode == 2 and not out.exists()
    assert "has contact" in result.stderr and "no free-motion session" in result.stderr
    fr3 = make_session(tmp_path, robot="fr3", action="none", link=None, duration_s=4.0)
    result = run_command("recorder", "identify", str(free_motion[0]), str(fr3),
                         "--out", str(out))
    assert result.returncode == 2 and not out.exists()
    assert "sessions of different arms" in result.stderr
    assert len([line for line in result.stderr.splitlines() if "error" in line]) == 1
    index = free_motion[0].parent / "index.parquet"
    result = run_command("recorder", "identify", str(free_motion[0]), str(index),
                         str(free_motion[1]), "--out", str(out))
    assert out.exists() and "index" in result.stderr
    assert "determined:" in result.stdout
    assert "detector (leave-one-session-out)" in result.stdout
    assert "beyond a dynamic torque of" in result.stdout  # where its thresholds grow more
    assert load_dynamics(out).provenance_doc["method"]["held_out"] == "leave-one-session-out"


def test_write_dynamics_gives_the_simulated_instance(tmp_path) -> None:
    out = tmp_path / "true.json"
    result = run_command("recorder", "simulate", str(tmp_path / "d"), "--preset", "smoke",
                         "--sessions", "1", "--robot-seed", "5", "--write-dynamics", str(out))
    assert result.returncode == 0, result.stderr
    truth = ArmSimulator(SimConfig(robot_seed=5)).true_dynamics()
    assert load_dynamics(out).inertias == truth.inertias
    result = run_command("recorder", "simulate", str(tmp_path / "e"), "--preset", "smoke",
                         "--sessions", "1", "--robot-seed", "6", "--write-dynamics", str(out))
    assert result.returncode == 2 and "other parameters" in result.stderr


def test_stats_deep_takes_the_dynamics(tmp_path, free_motion, identified) -> None:
    path = save_dynamics(tmp_path / "arm.json", identified)
    reports = []
    for extra in ([], ["--dynamics", str(path)]):
        out = tmp_path / f"report{len(extra)}.json"
        result = run_command("recorder", "stats", str(free_motion[0].parent), "--deep",
                             "--format", "json", "--out", str(out), "--workers", "1", *extra)
        assert result.returncode == 0, result.stderr
        reports.append(json.loads(out.read_text()))
    assert reports[0]["deep"] != reports[1]["deep"]
    result = run_command("recorder", "stats", str(free_motion[0].parent), "--dynamics",
                         str(path), "--out", str(tmp_path / "r.json"), "--format", "json")
    assert result.returncode == 2 and "needs --deep" in result.stderr


def _held_out(monkeypatch, motions: list[Motion]) -> tuple[ArmDynamics, list, dict]:
    """Identify ``motions`` and return the result, the held-out (motion, dynamics) pairs
    the detector was calibrated on, and the detector's source."""
    seen: list = []
    calibrate = identification._detector

    def spy(held_out, setup, source, outliers=False):
        seen.extend(held_out)
        return calibrate(held_out, setup, source, outliers)

    monkeypatch.setattr(identification, "_detector", spy)
    result = identify(motions, RobotSetup()).dynamics
    detector = dynamics_detector(result)
    assert detector is not None
    return result, seen, detector.source


def test_the_detector_is_calibrated_out_of_session(monkeypatch, free_motion) -> None:
    """Two sessions or more: each session whole, with the model fitted to the others;
    the final fit uses every session whole. One session: its last 25 %, with the fit."""
    motions = [identification.free_motion(path)[0] for path in free_motion[:3]]
    monkeypatch.setattr(identification, "PULLS", (1.0,))  # the same pull in every fit
    result, seen, source = _held_out(monkeypatch, motions)
    assert source["held_out"] == identification.LEAVE_ONE_OUT and source["sessions"] == 3
    assert json.loads(result.provenance)["method"]["held_out"] == identification.LEAVE_ONE_OUT
    assert [len(m.t) for m, _ in seen] == [len(m.t) for m in motions]
    fits = [d.inertias for _, d in seen]
    assert len(set(fits)) == 3 and result.inertias not in fits
    alone = identify([m for m in motions if m is not seen[0][0]], RobotSetup(),
                     calibrate_detector=False).dynamics
    # the others' fit, same settings (their normal equations subtracted from all, to
    # rounding)
    assert np.allclose(alone.inertias, seen[0][1].inertias, rtol=1e-8, atol=1e-12)
    samples = json.loads(result.provenance)["excitation"]["samples"]

    monkeypatch.undo()
    single, seen, source = _held_out(monkeypatch, motions[:1])
    assert source["held_out"] == identification.TAIL and source["share"] == identification.HOLDOUT
    assert json.loads(single.provenance)["method"]["held_out"] == identification.TAIL
    (tail, fitted), = seen
    assert len(tail.t) == pytest.approx(identification.HOLDOUT * len(motions[0].t), abs=1)
    assert fitted.inertias == single.inertias
    assert json.loads(single.provenance)["excitation"]["samples"] < samples / 3


def test_a_session_the_others_cannot_identify_without(monkeypatch, free_motion) -> None:
    """A short session with a long one: the fit of the short one alone determines
    nothing, so only the short one is held out (the long one's fit); the final fit uses
    both."""
    long = identification.free_motion(free_motion[0])[0]
    s = identification.free_motion(free_motion[1])[0]
    short = Motion(s.t[:250], s.q[:250], s.dq[:250], s.tau[:250], "short")
    _, seen, source = _held_out(monkeypatch, [long, short])
    assert source["held_out"] == identification.LEAVE_ONE_OUT and source["sessions"] == 1
    assert [m.name for m, _ in seen] == ["short"]


def test_the_prior_strength_is_chosen_on_the_left_out_sessions() -> None:
    """The pull toward the nominal model whose fits of the other sessions predict each
    left-out session best; 1 (the prior's own scales) on a tie; a session the others do
    not identify counts for none."""

    class Session:
        n = 10

        def __init__(self, best: float) -> None:
            self.best = best

        def rms(self, theta: np.ndarray) -> np.ndarray:
            return np.full(7, 1.0 + abs(float(theta[0]) - self.best))

    def fits(parts: list) -> Callable[[int, float], np.ndarray]:
        def fit(left_out: int, pull: float) -> np.ndarray:
            if len(parts) - 1 < 2:
                raise InputError("the motion determines no parameter")
            return np.array([pull])
        return fit

    parts = [(Session(0.25), None), (Session(0.5), None), (Session(0.25), None)]
    assert identification._choose_pull(parts, fits(parts)) == 0.25
    nine = [(Session(9.0), None)] * 3
    assert identification._choose_pull(nine, fits(nine)) == 2.0
    flat = [(Session(0.0), None)] * 3
    assert identification._choose_pull(
        flat, lambda left_out, pull: np.array([0.0])) == 1.0
    assert identification._choose_pull(parts[:2], fits(parts[:2])) == 1.0  # none identifies


def test_the_consistent_fit_steps_with_the_exact_jacobian() -> None:
    """The log-Cholesky coordinates' Jacobian (Levenberg-Marquardt's step in the
    consistent fit) is exact: it matches central differences; and the parameters of a
    stack of pseudo-inertias are those of each."""
    rng = np.random.default_rng(3)
    step = 1e-6
    for _ in range(4):
        factors = rng.normal(size=10)
        numeric = np.column_stack([
            (identification._from_factors(factors + step * e)
             - identification._from_factors(factors - step * e)) / (2 * step)
            for e in np.eye(10)])
        exact = identification._factors_jacobian(factors)
        assert np.abs(exact - numeric).max() <= 1e-7 * max(1.0, np.abs(exact).max())
    links = [identification._from_factors(rng.normal(size=10)) for _ in range(3)]
    stack = np.stack([pseudo_inertia(link) for link in links])
    assert np.allclose(from_pseudo_inertia(stack), links, rtol=1e-12, atol=1e-12)


def test_a_left_out_session_is_taken_out_of_the_merged_normal_equations() -> None:
    """The normal equations of every session but one (subtracted from the merged ones
    once) are those of the others merged anew, sessions without samples included."""
    rng = np.random.default_rng(5)
    parts = []
    for samples in (40, 0, 25, 60):
        normal = identification._Normal(4)
        if samples:
            normal.add(rng.normal(size=(samples, 7, 4)), rng.normal(size=(samples, 7)))
        normal.end_session()
        parts.append((normal, rng.random(7) > 0.5))
    sessions = identification._Sessions(parts)
    for i in range(len(parts)):
        others = [part for k, part in enumerate(parts) if k != i]
        normal, moving = sessions.others(i)
        expected = identification._Normal.merge([n for n, _ in others])
        assert normal.n == expected.n
        for got, want in ((normal.a, expected.a), (normal.b, expected.b),
                          (normal.c, expected.c)):
            assert np.allclose(got, want, rtol=1e-12, atol=1e-9)
        assert [m[1].tolist() for m in normal.means] == [m[1].tolist() for m in expected.means]
        assert moving.tolist() == np.logical_or.reduce([m for _, m in others]).tolist()


def test_identified_around_the_contacts_of_a_dataset(free_motion, mixed_motion) -> None:
    """Sessions with touches, cut around the contacts a detector finds (their labels are
    not read): the fit reaches the instance's floor on free motion it never saw, as
    from free motion, and the file says how it was made."""
    touched = [p for p in mixed_motion if read_session(p).meta.action != "none"]
    assert len(touched) == 6
    result = identify_sessions(mixed_motion, around_contacts=DetectorConfig())
    setup = RobotSetup("panda", True)
    truth = ArmSimulator(SimConfig(rate_hz=RATE_HZ, robot_seed=ROBOT_SEED)).true_dynamics()
    before = _rms(free_motion, setup)
    after = _rms(free_motion, replace(setup, dynamics=result.dynamics))
    floor = _rms(free_motion, replace(setup, dynamics=truth))
    assert (after < before).all() and (after <= 1.5 * floor + 0.01).all(), (after, floor)
    doc = result.dynamics.provenance_doc
    assert doc["around_contacts"]["before_s"] == identification.AROUND_BEFORE_S
    assert len(doc["sessions"]) == len(mixed_motion)
    detector = dynamics_detector(result.dynamics)
    assert detector is not None and "dropped_share" in detector.source["outliers"]
    session = read_session(touched[0])
    motion, _ = identification.motion_around_contacts(touched[0], DetectorConfig())
    assert 0 < len(motion.t) < len(session.t)
    contact = session.t[session.column("contact").astype(bool)]
    assert not ((motion.t >= contact[0]) & (motion.t <= contact[-1])).all()


def test_identify_cli_around_contacts(tmp_path, mixed_motion, quick_model) -> None:
    out = tmp_path / "arm.json"
    directory = str(mixed_motion[0].parent)
    result = run_command("recorder", "identify", directory, "--out", str(out),
                         "--model", str(quick_model))
    assert result.returncode == 2 and "--model is for --around-contacts" in result.stderr
    assert "Traceback" not in result.stderr and not out.exists()
    result = run_command("recorder", "identify", directory, "--out", str(out),
                         "--around-contacts", "--model", str(quick_model))
    assert result.returncode == 0, result.stderr
    assert "left out as outliers" in result.stdout and "has contact" not in result.stderr
    assert load_dynamics(out).provenance_doc["around_contacts"]["after_s"] == 1.0


def _event_lines(stdout: str) -> list[dict]:
    return [json.loads(line) for line in stdout.splitlines() if line.startswith("{")]


def test_predict_events_identifies_a_moving_dataset_from_itself(
        tmp_path, monkeypatch, mixed_motion, quick_model) -> None:
    """classify predict --events on a moving arm's dataset scores each half of its poses
    with the arm identified from the other half: the events are those --dynamics gives
    with that half's identification; --no-identify, and too little motion, keep the
    nominal model."""
    from contactkit.features import self_identification as own

    directory = str(mixed_motion[0].parent)
    command = ("classify", "predict", str(quick_model), directory, "--events", "--json")
    nominal = run_command(*command)  # 8 sessions of 8 s: far less than a minute a half
    assert nominal.returncode == 0, nominal.stderr
    assert "Identifying" not in nominal.stderr
    monkeypatch.setattr(own, "MIN_MOTION_S", 5.0)
    identified = run_command(*command, "--workers", "2")  # both halves at once
    assert identified.returncode == 0, identified.stderr
    assert "Identifying the arm from these 8 sessions" in identified.stderr
    assert identified.stderr.count("scored with the arm identified from the other") == 2
    assert run_command(*command, "--workers", "1").stdout == identified.stdout
    assert run_command(*command, "--no-identify").stdout == nominal.stdout
    detector = load_model(quick_model, lazy=True).detector_config()
    by_fold = []
    for k, fold in enumerate(own.cross_fitted_dynamics(own.survey(mixed_motion), detector)):
        target = tmp_path / f"fold{k}.json"
        save_dynamics(target, fold.identified.dynamics)
        done = run_command("classify", "predict", str(quick_model), *map(str, fold.scored),
                           "--events", "--json", "--dynamics", str(target))
        assert done.returncode == 0, done.stderr
        by_fold += _event_lines(done.stdout)
    assert by_fold and sorted(map(json.dumps, _event_lines(identified.stdout))) == sorted(
        map(json.dumps, by_fold))


def test_both_halves_at_once_report_every_step_and_identify_the_same_arms(
        mixed_motion, quick_model) -> None:
    """cross_fitted_dynamics with two workers relays both identifications' steps
    (sessions read, regressors summed, held-out fits) from the worker processes to one
    bar, from 0 to three steps per session; the arms are those of one worker."""
    from contactkit.features import self_identification as own

    detector = load_model(quick_model, lazy=True).detector_config()
    surveyed = own.survey(mixed_motion)
    steps: dict[int, list[tuple[str, int, int]]] = {1: [], 2: []}
    arms = {}
    for workers in (1, 2):
        folds = own.cross_fitted_dynamics(
            surveyed, detector, workers=workers,
            progress=lambda label, done, total, w=workers: steps[w].append(
                (label, done, total)))
        arms[workers] = [(fold.scored, fold.identified.dynamics.inertias,
                          fold.identified.dynamics.friction,
                          fold.identified.dynamics.detector) for fold in folds]
    assert arms[1] == arms[2]
    assert {label for label, _, _ in steps[2]} == {
        "identifying the arm from both halves at once"}
    done = [d for _, d, _ in steps[2]]
    assert done[0] == 0 and done == sorted(done) and len(done) > 2 * len(mixed_motion)
    assert steps[2][-1][1:] == (3 * len(mixed_motion), 3 * len(mixed_motion))
    for half in {label for label, _, _ in steps[1]}:  # one bar per half with one worker
        ends = [(d, t) for label, d, t in steps[1] if label == half]
        assert ends[0][0] == 0 and ends[-1][0] == ends[-1][1] > 0


def test_predict_identify_options_are_checked_in_one_line(tmp_path, mixed_motion,
                                                         quick_model, identified) -> None:
    """--identify needs --events and no --dynamics; forced on sessions whose halves
    cannot be identified, it stops with one line."""
    dynamics = tmp_path / "arm.json"
    save_dynamics(dynamics, identified)
    model = str(quick_model)
    for args, why in (((str(mixed_motion[0]), "--identify"), "is for --events"),
                      ((str(mixed_motion[0]), "--events", "--identify", "--dynamics",
                        str(dynamics)), "without --dynamics and --calibration"),
                      ((str(mixed_motion[0]), "--events", "--identify"),
                       "cross-fitting needs sessions in both halves")):
        done = run_command("classify", "predict", model, *args)
        assert done.returncode == 2 and why in done.stderr, done.stderr
        assert "Traceback" not in done.stderr


def test_a_failed_self_identification_falls_back_to_the_nominal_model(
        monkeypatch, mixed_motion, quick_model) -> None:
    """Without --identify, an identification that fails says so in one line and the
    sessions are scored with the nominal model, as --no-identify scores them."""
    from contactkit.features import self_identification as own

    def fails(*args, **kwargs):
        raise InputError("the motion determines nothing")

    command = ("classify", "predict", str(quick_model), str(mixed_motion[0].parent),
               "--events", "--json")
    nominal = run_command(*command, "--no-identify")
    monkeypatch.setattr(own, "MIN_MOTION_S", 5.0)
    monkeypatch.setattr(own, "cross_fitted_dynamics", fails)
    done = run_command(*command)
    assert done.returncode == 0, done.stderr
    assert "Not identified (the motion determines nothing): the nominal model is used" \
        in " ".join(done.stderr.split())
    assert done.stdout == nominal.stdout


def test_identify_cross_fitted_stores_each_half_in_the_other(tmp_path, monkeypatch,
                                                            mixed_motion, quick_model) -> None:
    """recorder identify --cross-fitted stores in each session the arm identified from
    the other half of the poses: classify predict --events then gives the events it
    gives when it identifies by itself, and so does the catalog's replay (whose build
    said how, on the moving arm's dataset with its nominal model); a second run stores
    the same arms (the stored ones are never read)."""
    from contactkit.features import self_identification as own_arm

    dataset = tmp_path / "dataset"
    shutil.copytree(mixed_motion[0].parent, dataset)
    model = str(quick_model)
    catalog = tmp_path / "catalog"
    building = ("recorder", "catalog", str(dataset), "--out", str(catalog), "--model", model,
                "--workers", "1")
    monkeypatch.setattr(own_arm, "MIN_MOTION_S", 5.0)  # 8 sessions of 8 s: a moving arm's
    built = run_command(*building)
    assert built.returncode == 0, built.stderr
    assert "--cross-fitted` stores those arms" in " ".join(built.stderr.split())
    for args, why in ((("--cross-fitted", "--out", str(tmp_path / "a.json")), "no --out"),
                      ((), "give --out")):
        done = run_command("recorder", "identify", str(dataset), *args)
        assert done.returncode == 2 and why in done.stderr and "Traceback" not in done.stderr
    command = ("recorder", "identify", str(dataset), "--cross-fitted", "--model", model)
    done = run_command(*command)
    assert done.returncode == 0, done.stderr
    assert "half 1 of the poses" in done.stdout and "half 2 of the poses" in done.stdout
    stored = {p.name: read_session(p).meta.arm_dynamics() for p in session_files(dataset)}
    assert len(stored) == len(mixed_motion) and all(stored.values())
    assert len({d.inertias for d in stored.values() if d}) == 2  # one arm per half
    own = run_command("classify", "predict", model, str(mixed_motion[0].parent), "--events",
                      "--json", "--identify")
    assert own.returncode == 0, own.stderr
    after = run_command("classify", "predict", model, str(dataset), "--events", "--json")
    assert after.returncode == 0 and "Identifying" not in after.stderr, after.stderr

    def by_name(stdout: str) -> list[str]:
        lines = _event_lines(stdout)
        for line in lines:
            line["session"] = Path(line["session"]).name
        return sorted(map(json.dumps, lines))

    assert by_name(after.stdout) and by_name(after.stdout) == by_name(own.stdout)
    built = run_command(*building)  # the catalog's replay uses the stored arms too
    assert built.returncode == 0, built.stderr
    assert f"{len(mixed_motion)} replayed" in built.stderr and "--cross-fitted" not in \
        built.stderr
    query = run_command("recorder", "query", str(catalog), "SELECT s.file, e.onset_s, "
                        "e.label FROM events e JOIN sessions s USING (session_id)", "--json")
    assert query.returncode == 0, query.stderr
    rows = [json.loads(line) for line in query.stdout.splitlines() if line.startswith("{")]
    assert sorted((r["file"], round(r["onset_s"], 6), r["label"]) for r in rows) == sorted(
        (Path(e["session"]).name, round(e["event"]["onset_s"], 6), e["event"]["label"])
        for e in _event_lines(after.stdout))
    assert run_command(*command).returncode == 0
    again = {p.name: read_session(p).meta.arm_dynamics() for p in session_files(dataset)}
    assert {k: d and d.inertias for k, d in again.items()} == {
        k: d and d.inertias for k, d in stored.items()}
