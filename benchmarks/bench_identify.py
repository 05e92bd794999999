"""Identifying an arm from 2 minutes of 1 kHz free motion (issue 37): time and result.

Simulates free motion (the ``free-motion`` preset's motion) of one robot instance at 1
kHz: 15 sessions of 8 s (2 minutes) to identify from and 4 more held out. Prints the
time of :func:`contactkit.features.identification.identify` on the 2 minutes (aim:
<= 30 s on one core) against the feature chain alone (the observer's residual) on the
same data, their ratio, and the held-out sessions' residual RMS per joint [Nm] with the
nominal model, the identified one, and the instance's true parameters (the floor,
``recorder simulate --write-dynamics``), with after / floor (aim: <= 1.5).

    .venv/bin/python benchmarks/bench_identify.py [ROBOT_SEED ...]   (default: 11 12)
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from contactkit.features.identification import Motion, identify
from contactkit.features.timeseries import TimeseriesChain
from contactkit.recorder.sim.dataset import simulate_dataset
from contactkit.recorder.sim.simulator import ArmSimulator, SimConfig
from contactkit.robots import RobotSetup
from contactkit.schemas import read_session
from contactkit.schemas.dataset import session_files

FIT_SESSIONS, HELD_OUT = 15, 4  # 8 s each: 2 minutes to identify from


def _rms(sessions: list, setup: RobotSetup) -> np.ndarray:
    chain = TimeseriesChain(robot=setup, names=["r"])
    r = [chain.compute(s.t, s.q, s.dq, s.tau)["r"][s.t > 0.5] for s in sessions]
    return np.sqrt((np.concatenate(r) ** 2).mean(axis=0))


def run(robot_seed: int, directory: Path) -> None:
    config = SimConfig(rate_hz=1000.0, robot_seed=robot_seed)
    simulate_dataset(directory, "free-motion", FIT_SESSIONS + HELD_OUT, robot_seed, 1, config)
    sessions = [read_session(p) for p in session_files(directory)]
    fit, held_out = sessions[:FIT_SESSIONS], sessions[FIT_SESSIONS:]
    motions = [Motion(s.t, s.q, s.dq, s.tau) for s in fit]
    setup = RobotSetup("panda", True)
    started = time.perf_counter()
    dynamics = identify(motions, setup).dynamics
    identify_s = time.perf_counter() - started
    started = time.perf_counter()
    chain = TimeseriesChain(robot=setup, names=["r"])
    for m in motions:
        chain.compute(m.t, m.q, m.dq, m.tau)
    chain_s = time.perf_counter() - started
    minutes = sum(float(m.t[-1] - m.t[0]) for m in motions) / 60.0
    before = _rms(held_out, setup)
    after = _rms(held_out, replace(setup, dynamics=dynamics))
    floor = _rms(held_out, replace(setup, dynamics=ArmSimulator(config).true_dynamics()))
    print(f"robot seed {robot_seed}: {minutes:.2f} min at 1 kHz; identify {identify_s:.1f} s "
          f"(aim <= 30 s), chain alone {chain_s:.1f} s, ratio {identify_s / chain_s:.2f}")
    print(f"  held-out residual RMS [Nm] nominal    {np.round(before, 3).tolist()}")
    print(f"                         identified {np.round(after, 3).tolist()}")
    print(f"                         floor      {np.round(floor, 3).tolist()}")
    print(f"  identified / floor {np.round(after / floor, 2).tolist()} (aim <= 1.5)")


def main() -> None:
    seeds = [int(s) for s in sys.argv[1:]] or [11, 12]
    for seed in seeds:
        with tempfile.TemporaryDirectory() as directory:
            run(seed, Path(directory))


if __name__ == "__main__":
    main()
