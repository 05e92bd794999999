"""Latency of the online event pipeline: per sample and per decision.

Per sample, a live robot runs the streaming feature chain (observer) and then the
event pipeline (detector, and the window bookkeeping of an open event). Once per
contact the pipeline decides: event features of the window since onset and the
intent classifier. This measures, on the real free-motion log (1 kHz, 20 544
samples, no hand), the pipeline's per-sample time on its own and with the chain, and
the decision (features + classifier of the default model's kind: scaled RBF SVM,
through the compiled online path), each against a baseline measured in the same
run: numpy's norm of one 7-vector. Prints median and p99 [us] and p99 / baseline.

    .venv/bin/python benchmarks/bench_events.py
"""

from __future__ import annotations

import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from contactkit.classify.events import (
    EVENT_FEATURES,
    EventModel,
    EventPipeline,
    event_features,
)
from contactkit.classify.fast import fast_predictor
from contactkit.classify.models import svm_pipeline
from contactkit.features.detector import DetectorConfig
from contactkit.features.timeseries import TimeseriesChain
from contactkit.recorder.importers.arrays import load_joint_arrays
from contactkit.robots import RobotSetup

GAZ = Path(__file__).resolve().parents[2] / "shared" / "reference" / "gaz2019-exciting-traj"
REPEATS = 2000


def timed(fn, n: int) -> np.ndarray:
    """Wall time [us] of ``fn(i)`` for i in range(n)."""
    out = np.empty(n)
    for i in range(n):
        start = time.perf_counter()
        fn(i)
        out[i] = time.perf_counter() - start
    return out * 1e6


def row(name: str, times: np.ndarray, base: float, width: int = 40) -> str:
    """One table line: median, p99 [us] and p99 / baseline p99 (name padded to ``width``)."""
    p99 = float(np.percentile(times, 99))
    return f"{name:<{width}} {np.median(times):>10.1f} {p99:>9.1f} {p99 / base:>13.1f}"


def main() -> None:
    data = load_joint_arrays(*(GAZ / f for f in ("time.txt", "positions.txt", "velocity.txt",
                                                 "torques.txt")))
    t, q, dq, tau = data["t"], data["q"], data["dq"], data["tau"]
    n = len(t)
    vector = np.ones(7)
    base = float(np.percentile(timed(lambda i: np.linalg.norm(vector), REPEATS), 99))
    chain = TimeseriesChain(robot=RobotSetup(with_hand=False), names=["r"])
    r = np.array([chain.update(t[k], q[k], dq[k], tau[k])["r"] for k in range(n)])
    # thresholds low enough that the log holds many events: the worst case per sample
    pipeline = EventPipeline(DetectorConfig(noise=(0.5,) * 7, speed=(0.0,) * 7,
                                            accel=(0.0,) * 7))
    per_sample = timed(lambda k: pipeline.update(t[k], r[k], dq[k]), n)
    chain = TimeseriesChain(robot=RobotSetup(with_hand=False), names=["r"])
    pipeline = EventPipeline(DetectorConfig(noise=(0.5,) * 7, speed=(0.0,) * 7,
                                            accel=(0.0,) * 7))

    def both(k: int) -> None:
        out = chain.update(t[k], q[k], dq[k], tau[k])
        pipeline.update(t[k], out["r"], dq[k])

    with_chain = timed(both, n)
    rng = np.random.default_rng(0)
    X = np.abs(rng.normal(2.0, 1.0, (400, len(EVENT_FEATURES))))
    y = np.array(["bump", "adjust", "shove", "none"] * 100)
    model = EventModel(svm_pipeline(10.0).fit(X, y), ["adjust", "bump", "none", "shove"])
    predict = fast_predictor(model.estimator)
    window_t, window_e = t[:150], r[:150]  # 0.15 s at 1 kHz

    def decide(_: int) -> None:
        x = event_features(window_t, window_e, float(window_t[0]))
        predict(x[None, :])
        model.out_of_range(x)

    decision = timed(decide, REPEATS)
    print(f"{'step':<40} {'median us':>10} {'p99 us':>9} {'p99/baseline':>13}")
    print(f"{'baseline: numpy norm of a 7-vector':<40} {base:>10.1f} {base:>9.1f} {1.0:>13.1f}")
    print(row("event pipeline per sample", per_sample, base))
    print(row("chain + event pipeline per sample", with_chain, base))
    print(row("decision (features + SVM, 0.15 s)", decision, base))
    print(f"events in the log at these thresholds: {len(pipeline.finish())}")


if __name__ == "__main__":
    main()
