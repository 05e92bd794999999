"""The simulator against the real Panda: observer residual statistics per joint.

Held pose: the real hand-mounted Panda in the MindLab recordings, no touch (at least
0.5 s from a labelled touch), against simulated ``none`` sessions of the thesis
poses. Free motion: the Gaz et al. exciting-trajectory log (no hand) against the
``free-motion`` preset's kind of motion on the simulated Panda without its hand.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from contactkit.features.timeseries import TimeseriesChain
from contactkit.recorder.importers.csv_import import read_csv_columns
from contactkit.recorder.importers.csv_map import load_csv_map, mindlab_map_path
from contactkit.recorder.sim.dataset import PRESETS, preset_specs
from contactkit.recorder.sim.noise import away_from_contact
from contactkit.recorder.sim.simulator import (
    ArmSimulator,
    SimConfig,
    plan_free_session,
    plan_session,
)
from contactkit.robots import RobotSetup
from tests.conftest import MINDLAB_FILES


def _joints(columns: dict[str, np.ndarray], prefix: str) -> np.ndarray:
    return np.column_stack([columns[f"{prefix}_{j}"] for j in range(1, 8)])


def _residual(columns: dict[str, np.ndarray], with_hand: bool = True) -> np.ndarray:
    return TimeseriesChain(robot=RobotSetup(with_hand=with_hand)).compute(
        columns["t"], _joints(columns, "q"), _joints(columns, "dq"), _joints(columns, "tau"),
        ["r"])["r"]


def simulate(specs, config: SimConfig) -> list[dict[str, np.ndarray]]:
    """Run specs through the simulator; return each session's columns."""
    parts: dict[int, list] = {}
    for index, columns, _ in ArmSimulator(config).run(specs):
        parts.setdefault(index, []).append(columns)
    return [{k: np.concatenate([c[k] for c in parts[i]]) for k in parts[i][0]}
            for i in sorted(parts)]


@pytest.fixture(scope="module")
def real_held_std(mindlab_dir: Path) -> np.ndarray:
    cmap = load_csv_map(mindlab_map_path())
    stds = []
    for name in MINDLAB_FILES:
        columns, _ = read_csv_columns(mindlab_dir / f"{name}.csv", cmap)
        r = _residual(columns)
        keep = away_from_contact(columns["t"], columns["contact"]) & (columns["t"] > 1.0)
        stds.append(r[keep].std(axis=0))
    return np.median(stds, axis=0)


def test_held_pose_residual_noise_matches_the_real_panda(real_held_std: np.ndarray) -> None:
    specs = [s for s in preset_specs(PRESETS["thesis-static"], 48, 0) if s.action == "none"]
    specs = [dataclasses.replace(s, duration_s=3.0, planned_at_s=1.5) for s in specs[:6]]
    sims = simulate(specs, SimConfig(rate_hz=500.0))
    sim_std = np.median([_residual(c)[c["t"] > 1.0].std(axis=0) for c in sims], axis=0)
    ratio = sim_std / real_held_std
    # Joint 5 is left out: its real residual (0.004 Nm) is at the simulator's floor.
    checked = [0, 1, 2, 3, 5, 6]
    assert ((ratio[checked] > 0.5) & (ratio[checked] < 1.5)).all(), (sim_std, real_held_std)
    assert (real_held_std[:4] > 0.03).all() and (real_held_std[:4] < 0.15).all()


def _moving_rms(columns: dict[str, np.ndarray]) -> np.ndarray:
    """RMS [Nm] of the residual (no hand) over the samples where a joint moves > 0.1 rad/s."""
    r = _residual(columns, with_hand=False)
    moving = (columns["t"] > 1.0) & (np.abs(_joints(columns, "dq")).max(axis=1) > 0.1)
    return np.sqrt((r[moving] ** 2).mean(axis=0))


def test_free_motion_residual_matches_the_real_log(reference_dir: Path) -> None:
    real = {"t": np.loadtxt(reference_dir / "time.txt")}
    for prefix, name in (("q", "positions"), ("dq", "velocity"), ("tau", "torques")):
        values = np.loadtxt(reference_dir / f"{name}.txt").reshape(-1, 7)
        real.update({f"{prefix}_{j}": values[:, j - 1] for j in range(1, 8)})
    real_rms = _moving_rms(real)
    specs = [plan_free_session(seed=100 + k, action="none", pose="ABCDEFGH"[k],
                               duration_s=8.0, pose_jitter_rad=0.1,
                               robot=RobotSetup(with_hand=False))
             for k in range(8)]
    # Two robot instances (each has its own true inertia and friction), four sessions each.
    sims = [c for robot in (0, 1) for c in simulate(
        specs[4 * robot:4 * robot + 4], SimConfig(rate_hz=1000.0, with_hand=False,
                                                  robot_seed=robot))]
    ratio = np.median([_moving_rms(c) for c in sims], axis=0) / real_rms
    assert ((ratio > 0.5) & (ratio < 1.5)).all(), ratio
    assert np.median([np.abs(_joints(c, "dq")).max() for c in sims]) > 1.0


def test_no_held_pose_is_noisier_than_the_real_panda(real_held_std: np.ndarray) -> None:
    """Every thesis pose held (not only the median over poses): at pose E (q2 = 0)
    joints 1 and 3 turning against each other once oscillated at the control's Nyquist
    frequency, 0.43 Nm on joints 1 and 3, 4.7 times the real arm's on joint 1."""
    poses = "ABCDEFGH"
    specs = [plan_session(seed=50 + k, condition="static", action="none", pose=pose,
                          duration_s=3.0, planned_at_s=1.5) for k, pose in enumerate(poses)]
    sims = simulate(specs, SimConfig(rate_hz=500.0))
    sim_std = np.array([_residual(c)[c["t"] > 1.0].std(axis=0) for c in sims])
    ratio = sim_std[:, :4] / real_held_std[:4]
    assert (ratio < 1.5).all(), dict(zip(poses, ratio.round(2).tolist(), strict=True))
