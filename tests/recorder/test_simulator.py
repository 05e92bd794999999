"""The simulated Panda: determinism, force ground truth per action, physics sanity."""

from __future__ import annotations

import numpy as np
import pytest

from contactkit.recorder.protocol import MAX_ONSET_DELAY_S, pose_q
from contactkit.recorder.sim.forces import PROFILE_RANGES
from contactkit.recorder.sim.simulator import ArmSimulator, SimConfig, plan_session
from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.schemas import InputError
from tests.conftest import simulate_columns

CONFIG = SimConfig(rate_hz=500.0)


def _spec(action: str, seed: int = 11, **kw):
    kw.setdefault("duration_s", 5.0)
    kw.setdefault("planned_at_s", 1.5)
    return plan_session(seed=seed, condition="static", action=action, pose="C", **kw)


def _force(cols):
    return np.linalg.norm(np.column_stack([cols["f_ext_x"], cols["f_ext_y"], cols["f_ext_z"]]),
                          axis=1)


def test_same_seed_same_data_and_batch_independence() -> None:
    specs = [_spec(a, seed=s) for s, a in enumerate(("shove", "none", "adjust"))]
    alone = simulate_columns(specs[0], CONFIG)
    again = simulate_columns(_spec("shove", seed=0), CONFIG)
    parts: dict[int, list] = {}
    for index, cols, _ in ArmSimulator(CONFIG).run(specs, chunk=37):
        parts.setdefault(index, []).append(cols)
    batched = {k: np.concatenate([c[k] for c in parts[0]]) for k in alone}
    for name in alone:
        assert np.array_equal(alone[name], again[name]), name
        assert np.array_equal(alone[name], batched[name]), name
    other = simulate_columns(_spec("shove", seed=1), CONFIG)
    assert not np.array_equal(alone["tau_1"], other["tau_1"])


def test_no_force_for_none() -> None:
    cols = simulate_columns(_spec("none"), CONFIG)
    assert not cols["contact"].any()
    assert np.all(_force(cols) == 0.0)
    q = np.column_stack([cols[f"q_{i}"] for i in range(1, 8)])
    assert np.abs(q - pose_q("C")).max() < 2e-3


@pytest.mark.parametrize("action", ["bump", "adjust", "shove"])
def test_force_ground_truth_matches_action(action: str) -> None:
    spec = _spec(action, link=6)
    cols = simulate_columns(spec, CONFIG)
    force, t = _force(cols), cols["t"]
    contact = cols["contact"]
    assert contact.any() and np.array_equal(contact, force > 0)
    onset, end = t[contact][0], t[contact][-1]
    assert spec.planned_at_s <= onset <= spec.planned_at_s + MAX_ONSET_DELAY_S + 0.01
    assert np.allclose(force, spec.contact.magnitude(t), atol=1e-9)
    persona = spec.contact.peak_n / force.max()
    assert 0.99 < persona < 1.01
    duration = end - onset
    lo_peak, hi_peak = PROFILE_RANGES[action]["peak_n"]
    if action == "bump":
        assert duration < 0.4 and force.max() < 2 * hi_peak
    elif action == "adjust":
        assert duration > 0.5
    else:
        assert force.max() > 0.5 * lo_peak and duration < 1.5
    direction = np.array(spec.contact.direction)
    f = np.column_stack([cols["f_ext_x"], cols["f_ext_y"], cols["f_ext_z"]])[contact]
    assert np.allclose(f / np.linalg.norm(f, axis=1, keepdims=True), direction)


def test_arm_holds_against_a_slow_push_and_torque_shows_it() -> None:
    spec = _spec("adjust", seed=5, link=4)
    cols = simulate_columns(spec, CONFIG)
    model = RobotModel(RobotSetup(with_hand=True))
    t = cols["t"]
    tau = np.column_stack([cols[f"tau_{i}"] for i in range(1, 8)])
    q = np.column_stack([cols[f"q_{i}"] for i in range(1, 8)])
    f = np.column_stack([cols["f_ext_x"], cols["f_ext_y"], cols["f_ext_z"]])
    c = spec.contact
    hold = (t > c.onset_s + c.rise_s + 0.1) & (t < c.onset_s + c.rise_s + c.hold_s - 0.05)
    assert hold.sum() > 20
    k = np.flatnonzero(hold)[len(np.flatnonzero(hold)) // 2]
    jac = model.point_jacobian(q[k], c.link, np.array(c.point_local))
    expected = -(jac[:3].T @ f[k])
    before = tau[(t > 0.5) & (t < 1.4)].mean(axis=0)
    measured = tau[hold].mean(axis=0) - before
    assert np.linalg.norm(measured - expected) < 0.15 * np.linalg.norm(expected) + 0.3


def test_dynamic_condition_moves_to_target() -> None:
    spec = plan_session(seed=2, condition="dynamic", action="none", pose="A", target_pose="C",
                        speed_rad_s=0.5)
    assert spec.duration_s == pytest.approx(3 + spec.motion_duration_s + 5)
    assert spec.planned_at_s == pytest.approx(3 + spec.motion_duration_s / 2)
    cols = simulate_columns(spec, SimConfig(rate_hz=200.0))
    q_end = np.array([cols[f"q_{i}"][-1] for i in range(1, 8)])
    assert np.abs(q_end - pose_q("C")).max() < 5e-3
    dq = np.column_stack([cols[f"dq_d_{i}"] for i in range(1, 8)])
    assert np.abs(dq).max() <= 0.5 * 1.875 + 1e-9


def test_torque_noise_matches_reference_level() -> None:
    cols = simulate_columns(_spec("none", duration_s=3.0), SimConfig(rate_hz=1000.0))
    tau5 = cols["tau_5"]
    second = np.diff(tau5, n=2)
    sigma = 1.4826 * np.median(np.abs(second - np.median(second))) / np.sqrt(6)
    assert 0.02 < sigma < 0.08


def test_jitter_and_drops_keep_time_increasing() -> None:
    config = SimConfig(rate_hz=500.0, jitter_s=0.0008, drop_prob=0.05)
    cols = simulate_columns(_spec("bump"), config)
    steps = np.diff(cols["t"])
    assert (steps > 0).all() and steps.max() > 0.0035
    assert 0.85 * 2501 < len(cols["t"]) < 0.99 * 2501


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"pose": "Q"}, "unknown pose"),
    ({"action": "tickle"}, "unknown action"),
    ({"link": 8}, "unknown link"),
    ({"duration_s": 0.0}, "duration must be positive"),
    ({"planned_at_s": 9.0, "duration_s": 5.0}, "outside the session"),
    ({"condition": "floating"}, "unknown condition"),
    ({"target_pose": "B"}, "need the dynamic condition"),
])
def test_plan_rejects_bad_choices(kwargs: dict, message: str) -> None:
    args = {"seed": 0, "condition": "static", "action": "bump", "pose": "A", **kwargs}
    with pytest.raises(InputError, match=message):
        plan_session(**args)


def test_a_hard_shove_that_saturates_the_motors_does_not_diverge() -> None:
    """aug-sim session 63: a 135 N shove on link 7 at pose H saturates joints 1-2.
    Without anti-windup the integrators drove the arm unstable and it reached NaN."""
    from contactkit.recorder.sim.dataset import PRESETS, preset_specs

    preset = PRESETS["aug-sim"]
    config = SimConfig(rate_hz=preset.rate_hz, robot_seed=preset.robot_seed)
    spec = preset_specs(preset, 64, 0, config.setup)[63]
    assert spec.contact.peak_n > 130 and spec.contact.link == 7
    cols = simulate_columns(spec, config)
    dq = np.column_stack([cols[f"dq_{i}"] for i in range(1, 8)])
    assert np.isfinite(dq).all()
    settled = cols["t"] > spec.duration_s - 1.0
    assert np.abs(dq[settled]).max() < 0.05
