"""The simulator never drops a session (issue 38): a joint a person drives past its limit
stops the arm by its reflex, as on a real Franka, and the session says so."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from contactkit.features.limits import ROBOT_MODE_REFLEX, session_limit_violation
from contactkit.recorder.sim.dataset import simulate_dataset, simulate_specs
from contactkit.recorder.sim.presets import PRESETS
from contactkit.recorder.sim.simulator import ROBOT_MODE_MOVE, SimConfig, plan_session
from contactkit.recorder.stats.deep import session_summary
from contactkit.recorder.stats.summary import beyond_limits
from contactkit.robots import get_robot
from contactkit.schemas import read_session


def _hard_wrist_shove(duration_s: float = 2.0):
    """The shove of ``recorder simulate --preset smoke --sessions 32 --seed 9`` (its
    session 7, refused as unstable before the reflex): 89 N on the hand, link 7, pose B,
    which drives joint 6 past its speed limit."""
    spec = plan_session(seed=3, condition="static", action="shove", pose="B", link=7,
                        duration_s=duration_s, planned_at_s=0.8)
    contact = replace(spec.contact, onset_s=0.8, point_local=(-0.00617, 0.00078, 0.17287),
                      direction=(-0.27311, -0.49955, 0.82211), peak_n=89.32, rise_s=0.1177,
                      hold_s=0.227, fall_s=0.1317)
    return replace(spec, contact=contact)


def test_a_shove_past_a_joints_speed_limit_stops_the_arm_and_is_recorded(
        tmp_path: Path) -> None:
    config = SimConfig(rate_hz=500.0)
    (path,) = simulate_specs([_hard_wrist_shove()], config, tmp_path)
    session = read_session(path)
    mode = session.column("robot_mode")
    stop = int(np.argmax(mode == ROBOT_MODE_REFLEX))
    assert stop > 0 and (mode[:stop] == ROBOT_MODE_MOVE).all()
    assert (mode[stop:] == ROBOT_MODE_REFLEX).all()
    reflex = session.meta.simulator["reflex"]
    assert reflex["joint"] == 6 and reflex["quantity"] == "dq"
    assert abs(reflex["value"]) > reflex["limit"] == pytest.approx(2.61)
    assert reflex["t_s"] == pytest.approx(session.t[stop], abs=2.5e-3)
    limits = get_robot("panda").limits
    dq = session.dq
    # Braked to rest within the acceleration limits, and held there.
    assert np.abs(dq).max(axis=0)[5] < 1.05 * limits.dq_max[5]
    assert np.abs(dq[session.t > reflex["t_s"] + 0.2]).max() < 0.05
    assert np.ptp(session.q[session.t > reflex["t_s"] + 0.2], axis=0).max() < 1e-3
    # The brakes hold against the person: the torque sensor of joint 6 reads the push,
    # beyond what its motor could give, and the session is not "beyond the limits".
    pushed = session.column("contact") & (mode == ROBOT_MODE_REFLEX)
    assert np.abs(session.tau[pushed, 5]).max() > limits.tau_max[5]
    assert session_limit_violation(session) is None
    assert beyond_limits(session_summary(str(path))) is None  # stats --deep agrees
    assert (session.joints("dq_d")[mode == ROBOT_MODE_REFLEX] == 0.0).all()


def test_a_session_without_a_reflex_says_move_throughout(tmp_path: Path) -> None:
    spec = plan_session(seed=4, condition="static", action="bump", pose="C", link=3,
                        duration_s=1.5, planned_at_s=0.5)
    (path,) = simulate_specs([spec], SimConfig(rate_hz=200.0), tmp_path)
    session = read_session(path)
    assert (session.column("robot_mode") == ROBOT_MODE_MOVE).all()
    assert "reflex" not in session.meta.simulator


@pytest.mark.slow
@pytest.mark.parametrize("preset", sorted(PRESETS))
@pytest.mark.parametrize(("seed", "robot_seed"), [(9, 0), (5, 12), (4242, 3)])
def test_every_preset_writes_every_session(tmp_path: Path, preset: str, seed: int,
                                           robot_seed: int) -> None:
    config = SimConfig(rate_hz=200.0, robot_seed=robot_seed)
    result = simulate_dataset(tmp_path, preset, 16, seed, 1, config=config)
    assert result.failed == [] and result.written == 16
