"""Free-motion plans and the free-motion / mixed-motion presets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contactkit.recorder.protocol import pose_q
from contactkit.recorder.sim.dataset import PRESETS, preset_specs, simulate_dataset
from contactkit.recorder.sim.motion import ACCEL_FRACTION, SPEED_FRACTION, free_motion_plan
from contactkit.recorder.sim.simulator import SimConfig, plan_free_session
from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.schemas import InputError, read_session

LIMITS = RobotModel(RobotSetup(with_hand=True)).limits


@pytest.mark.parametrize("seed", range(6))
def test_plan_stays_within_the_panda_limits(seed: int) -> None:
    plan = free_motion_plan(np.random.default_rng(seed), pose_q("ABCDEF"[seed]), 10.0, LIMITS)
    t = np.arange(0.0, 10.0, 0.001)
    q, dq = plan.sample(t)
    ddq = np.gradient(dq, t, axis=0)
    assert ((q > LIMITS.q_min) & (q < LIMITS.q_max)).all()
    assert (np.abs(dq) <= SPEED_FRACTION[1] * LIMITS.dq_max + 1e-9).all()
    assert (np.abs(ddq) <= ACCEL_FRACTION * LIMITS.ddq_max * 1.05).all()
    assert np.abs(np.diff(q, axis=0)).max() < 0.003  # continuous at 1 kHz
    assert np.allclose(np.gradient(q, t, axis=0)[1:-1], dq[1:-1], atol=0.02)
    assert plan.segments[0].kind == "hold" and np.abs(dq[t < 1.0]).max() == 0.0
    for seg in plan.segments[1:]:
        boundary = plan.sample(np.array([seg.start_s]))[1]
        assert np.abs(boundary).max() < 1e-9


def test_plans_reach_realistic_speeds() -> None:
    peaks = [np.abs(free_motion_plan(np.random.default_rng(s), pose_q("A"), 8.0, LIMITS)
                    .sample(np.arange(0.0, 8.0, 0.002))[1]).max() for s in range(10)]
    assert max(peaks) > 1.5 and np.median(peaks) > 1.0


def test_free_and_mixed_presets() -> None:
    free = preset_specs(PRESETS["free-motion"], 16, 0)
    assert {s.action for s in free} == {"none"} and all(s.motion for s in free)
    mixed = preset_specs(PRESETS["mixed-motion"], 32, 0)
    assert [sum(s.action == a for s in mixed) for a in ("none", "bump", "adjust", "shove")] \
        == [8, 8, 8, 8]
    for spec in mixed:
        moving = spec.motion.moving_intervals()
        assert any(a <= spec.planned_at_s <= b + 0.3 for a, b in moving)
        assert spec.planned_at_s < spec.duration_s - 1.0
    assert preset_specs(PRESETS["mixed-motion"], 4, 0) == mixed[:4]


def test_contact_timing_is_honoured() -> None:
    for seed in range(8):
        spec = plan_free_session(seed=seed, action="bump", pose="B", duration_s=8.0,
                                 contact_timing="moving")
        assert any(a <= spec.planned_at_s <= b for a, b in spec.motion.moving_intervals())
        spec = plan_free_session(seed=seed, action="shove", pose="C", duration_s=8.0,
                                 contact_timing="after-stop")
        assert any(b <= spec.planned_at_s <= b + 0.3
                   for _, b in spec.motion.moving_intervals())
    with pytest.raises(InputError, match="contact timing"):
        plan_free_session(seed=0, action="bump", pose="B", duration_s=8.0,
                          contact_timing="later")


def test_mixed_motion_sessions_simulate(tmp_path: Path) -> None:
    result = simulate_dataset(tmp_path, "mixed-motion", 3, 0, 1,
                              SimConfig(rate_hz=250.0))
    assert result.written == 3 and not result.index.problems
    sessions = [read_session(p) for p in sorted(tmp_path.glob("dynamic_*.parquet"))]
    assert len(sessions) == 3
    for session in sessions:
        assert np.abs(session.dq).max() > 0.5
        assert np.abs(session.q - session.joints("q_d")).max() < 0.1
        if session.meta.action != "none":
            assert session.column("contact").any()
