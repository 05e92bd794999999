"""Latency of classifying one window: scalar features of the window + the model.

Online, the streaming chain produces timeseries features sample by sample (see
bench_features.py); every hop the classifier turns the last window into scalar
features and class probabilities. This measures that step for a 0.5 s window at
1 kHz (500 samples x 21 channels) with each model kind trained on a small simulated
dataset, against a baseline measured in the same run: numpy's own max-min over the
same window. Prints median and p99 [us] for scikit-learn's predict_proba and for
the online path replay uses (:mod:`contactkit.classify.kinds.fast`, the same numbers without
scikit-learn's per-call input checks).

    .venv/bin/python benchmarks/bench_predict.py
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from contactkit.classify.data import load_features
from contactkit.classify.kinds.fast import fast_predictor
from contactkit.classify.kinds.registry import make_estimator
from contactkit.features.extract import SessionFeatures
from contactkit.features.scalars import scalar_features
from contactkit.features.timeseries import columns_of
from contactkit.recorder.sim.dataset import simulate_specs
from contactkit.recorder.sim.simulator import SimConfig, plan_session

REPEATS = 2000


def small_dataset(directory: Path) -> Path:
    """32 short static sessions (4 poses x 4 actions x 2)."""
    specs = [plan_session(seed=100 * r + 10 * p + a, condition="static", action=action,
                          pose=pose, duration_s=4.0, planned_at_s=2.5)
             for r in range(2) for p, pose in enumerate("ABCD")
             for a, action in enumerate(("none", "bump", "adjust", "shove"))]
    simulate_specs(specs, SimConfig(rate_hz=250.0), directory)
    return directory


def percentiles(fn) -> tuple[float, float]:
    """Median and p99 of ``fn``'s wall time [us]."""
    times = np.empty(REPEATS)
    for i in range(REPEATS):
        start = time.perf_counter()
        fn()
        times[i] = time.perf_counter() - start
    return float(np.median(times) * 1e6), float(np.percentile(times, 99) * 1e6)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        extractor = SessionFeatures()
        data = load_features([small_dataset(Path(tmp))], extractor, workers=2, cache=False)
    window = np.random.default_rng(0).normal(size=(500, 21))
    channels = [c for name in ("dq", "tau", "r") for c in columns_of(name)]
    base = percentiles(lambda: window.max(axis=0) - window.min(axis=0))
    print(f"{'step':<34} {'median us':>10} {'p99 us':>9} {'p99/baseline':>13}")
    print(f"{'baseline: numpy max-min':<34} {base[0]:>10.1f} {base[1]:>9.1f} {1.0:>13.1f}")
    feats = percentiles(lambda: scalar_features(window, ["range"], channels))
    print(f"{'scalar features (range)':<34} {feats[0]:>10.1f} {feats[1]:>9.1f} "
          f"{feats[1] / base[1]:>13.1f}")
    for kind in ("svm", "per-joint", "three-joint"):
        model = make_estimator(kind, data.names).fit(data.X, data.labels())
        for label, predict in (("sklearn", model.predict_proba),
                               ("online", fast_predictor(model))):

            def step(predict=predict) -> None:
                row, _ = scalar_features(window, ["range"], channels)
                predict(row[None, :])

            med, p99 = percentiles(step)
            name = f"features + {kind} ({label})"
            print(f"{name:<34} {med:>10.1f} {p99:>9.1f} {p99 / base[1]:>13.1f}")


if __name__ == "__main__":
    main()
