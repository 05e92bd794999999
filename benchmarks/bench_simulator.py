"""Simulator speed: real-time factor against the bare pinocchio calls it makes.

Prints, for 1 kHz output with the default 5 sub-steps, the simulated seconds per
wall-clock second on one core for batches of 1, 8 and 32 sessions, next to the
cost of the pinocchio calls alone (per control tick: one gravity call, and five
forward-dynamics calls), measured in the same run.

    .venv/bin/python benchmarks/bench_simulator.py
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pinocchio as pin

from contactkit.recorder.sim.simulator import ArmSimulator, SimConfig, plan_session

SIM_SECONDS = 6.0


def bare_pinocchio_seconds_per_sim_second(config: SimConfig, batch: int) -> float:
    """Wall time of the batched pinocchio calls for one simulated second of ``batch``."""
    sim = ArmSimulator(config)
    q = np.asfortranarray(np.tile(np.array([0.0, -0.78, 0.0, -2.36, 0.0, 1.57, 0.78])[:, None],
                                  (1, batch)))
    v = np.asfortranarray(np.full_like(q, 0.1))
    tau, out = np.zeros_like(q, order="F"), np.zeros_like(q, order="F")
    ticks = int(config.rate_hz)
    start = time.perf_counter()
    for _ in range(ticks):
        pin.rneaInParallel(1, sim._nominal_pool, q, tau, tau, out)
        for _ in range(config.substeps):
            pin.abaInParallel(1, sim._plant_pool, q, v, tau, out)
    return time.perf_counter() - start


def simulate_seconds(config: SimConfig, batch: int) -> float:
    """Wall time to simulate ``batch`` static shove sessions of SIM_SECONDS each."""
    specs = [plan_session(seed=k, condition="static", action="shove", pose="C", link=7,
                          duration_s=SIM_SECONDS, planned_at_s=2.0) for k in range(batch)]
    sim = ArmSimulator(config)
    start = time.perf_counter()
    for _ in sim.run(specs):
        pass
    return time.perf_counter() - start


def main() -> None:
    config = SimConfig(rate_hz=1000.0)
    print(f"simulator, 1 kHz output, {config.substeps} sub-steps, one core")
    print(f"{'batch':>5} {'RT factor/core':>15} {'bare pinocchio RT':>18} {'sim/bare':>9}")
    for batch in (1, 8, 32):
        wall = simulate_seconds(config, batch)
        bare = bare_pinocchio_seconds_per_sim_second(config, batch)
        rt = SIM_SECONDS * batch / wall
        bare_rt = batch / bare
        print(f"{batch:>5} {rt:>14.1f}x {bare_rt:>17.1f}x {wall / (bare * SIM_SECONDS):>8.2f}x")


if __name__ == "__main__":
    main()
