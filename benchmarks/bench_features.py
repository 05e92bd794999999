"""Feature-chain speed against the bare pinocchio calls it needs, measured in the same run.

For a simulated 12 s session at 1 kHz and for the real reference recording, prints:
the per-sample cost of the whole batch chain (every timeseries feature), the cost
of a bare per-sample loop of the pinocchio calls the chain needs (M, C, g, J and
inverse dynamics), their ratio, the real-time factor at 1 kHz on one core, and the
streaming update's per-sample latency (median, p99).

    .venv/bin/python benchmarks/bench_features.py
"""

from __future__ import annotations

import gc
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pinocchio as pin

from contactkit.features.timeseries import TimeseriesChain
from contactkit.recorder.importers.arrays import load_joint_arrays
from contactkit.recorder.sim.simulator import SimConfig, plan_session
from contactkit.recorder.sources.sim import SIM_COLUMNS, SimSource
from contactkit.robots import RobotSetup
from contactkit.schemas import read_session, write_session

REFERENCE = Path(__file__).resolve().parents[2] / "shared/reference/gaz2019-exciting-traj"


def simulated_session() -> tuple[str, dict[str, np.ndarray], bool]:
    """A 12 s static shove at 1 kHz."""
    config = SimConfig(rate_hz=1000.0)
    spec = plan_session(seed=3, condition="static", action="shove", pose="B", link=6)
    source = SimSource(spec, config, chunk=200)
    chunks = list(source.stream())
    data = {k: np.concatenate([c[k] for c in chunks]) for k in SIM_COLUMNS}
    with tempfile.TemporaryDirectory() as tmp:
        path = write_session(Path(tmp) / "s.parquet", data,
                             source.session_meta())
        session = read_session(path)
    return "simulated 12 s", {"t": session.t, "q": session.q, "dq": session.dq,
                              "tau": session.tau}, True


def reference_session() -> tuple[str, dict[str, np.ndarray], bool]:
    """The real Panda recording (21 s, irregular steps, no hand)."""
    arrays = load_joint_arrays(*(REFERENCE / f for f in ("time.txt", "positions.txt",
                                                          "velocity.txt", "torques.txt")))
    return "real reference", arrays, False


def best_of(repeats: int, fn) -> float:
    """Smallest wall time of ``repeats`` runs of ``fn`` [s]."""
    times = []
    for _ in range(repeats):
        gc.collect()
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def bare_calls(chain: TimeseriesChain, data: dict[str, np.ndarray]) -> None:
    """The pinocchio calls the chain needs, one sample at a time, results discarded."""
    model, dat = chain.model.model, chain.model.data
    fid = chain.model.frame_id(chain.model.end_effector)
    q, dq = data["q"], data["dq"]
    for k in range(len(q)):
        pin.crba(model, dat, q[k])
        pin.computeCoriolisMatrix(model, dat, q[k], dq[k])
        pin.computeGeneralizedGravity(model, dat, q[k])
        pin.rnea(model, dat, q[k], dq[k], dq[k])
        pin.computeFrameJacobian(model, dat, q[k], fid, pin.LOCAL_WORLD_ALIGNED)


def main() -> None:
    print(f"{'recording':<16} {'samples':>7} {'chain us':>9} {'bare us':>8} {'ratio':>6} "
          f"{'RT @1kHz':>9} {'stream p50':>11} {'stream p99':>11}")
    for name, data, with_hand in (simulated_session(), reference_session()):
        chain = TimeseriesChain(robot=RobotSetup(with_hand=with_hand))
        n = len(data["t"])
        chain_s = best_of(3, lambda chain=chain, data=data: chain.compute(
            data["t"], data["q"], data["dq"], data["tau"]))
        bare_s = best_of(3, lambda chain=chain, data=data: bare_calls(chain, data))
        online = TimeseriesChain(robot=RobotSetup(with_hand=with_hand))
        latencies = np.empty(n)
        gc.collect()
        for k in range(n):
            start = time.perf_counter()
            online.update(data["t"][k], data["q"][k], data["dq"][k], data["tau"][k])
            latencies[k] = time.perf_counter() - start
        per_sample = chain_s / n * 1e6
        print(f"{name:<16} {n:>7} {per_sample:>9.2f} {bare_s / n * 1e6:>8.2f} "
              f"{chain_s / bare_s:>6.2f} {1e6 / 1000 / per_sample:>8.0f}x "
              f"{np.percentile(latencies, 50) * 1e6:>9.1f}us "
              f"{np.percentile(latencies, 99) * 1e6:>9.1f}us")


if __name__ == "__main__":
    main()
