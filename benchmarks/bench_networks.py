"""Per-window inference latency of the networks, torch against ONNX, and MiniRocket.

Trains each network briefly on random grids, then times one-window predictions on
one CPU thread: torch, the exported ONNX model in onnxruntime, MiniRocket, and as
the baseline measured in the same run the SVM's online path on the same window's
scalar features. Two shapes: the thesis's (21 channels x 300 steps; CNN depth 4,
width 2; LSTM depth 2, width 2) and the one docs/results.md compares (100 steps;
CNN depth 1, width 1). Prints median and p99 [ms] and p99 over the baseline's.

    .venv/bin/python benchmarks/bench_networks.py
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import onnxruntime as ort
import torch

from contactkit.classify.kinds.fast import fast_predictor
from contactkit.classify.kinds.registry import make_estimator
from contactkit.features.scalars import scalar_features

torch.set_num_threads(1)
REPEATS = 300


def timed(fn) -> tuple[float, float]:
    """Median and p99 [ms] of ``fn``."""
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e3), float(np.percentile(times, 99) * 1e3)


CASES = (("thesis CNN, 300 steps", "cnn", {}, 300),
         ("thesis LSTM, 300 steps", "lstm", {}, 300),
         ("thesis CNN, 100 steps", "cnn", {}, 100),
         ("CNN depth 1 width 1, 100 steps", "cnn", {"depth": 1, "width": 1.0}, 100),
         ("thesis LSTM, 100 steps", "lstm", {}, 100))


def main() -> None:
    rng = np.random.default_rng(0)
    y = np.array(["none", "bump", "adjust", "shove"] * 16)
    grids = {steps: rng.normal(size=(64, 21, steps)).astype(np.float32) for steps in (100, 300)}
    window = grids[300][:1]
    rows = []
    channels = [f"c{i}" for i in range(21)]
    features = np.array([scalar_features(x.T, ["range"], channels)[0] for x in grids[300]])
    svm = fast_predictor(make_estimator("svm", [f"range(tau_{i % 7 + 1})" for i in range(21)])
                         .fit(features, y))
    base = timed(lambda: svm(scalar_features(window[0].T, ["range"], channels)[0][None, :]))
    rows.append(("SVM online path (baseline)", *base))
    with tempfile.TemporaryDirectory() as tmp:
        for name, kind, params, steps in CASES:
            X, one = grids[steps], grids[steps][:1]
            net = make_estimator(kind, [], epochs=1, **params).fit(X, y)
            rows.append((f"{name}, torch", *timed(lambda net=net, one=one:
                                                  net.predict_proba(one))))
            path = Path(tmp) / f"{kind}{steps}.onnx"
            net.export_onnx(path, 21, steps)
            options = ort.SessionOptions()
            options.intra_op_num_threads = options.inter_op_num_threads = 1
            session = ort.InferenceSession(str(path), options)
            rows.append((f"{name}, ONNX", *timed(lambda s=session, one=one:
                                                 s.run(None, {"grid": one}))))
        for steps in (300, 100):
            rocket = make_estimator("minirocket", []).fit(grids[steps].astype(float), y)
            one = grids[steps][:1]
            rows.append((f"MiniRocket, {steps} steps",
                         *timed(lambda rocket=rocket, one=one: rocket.predict_proba(one))))
    print(f"{'model (one window, one thread)':<40} {'median ms':>10} {'p99 ms':>8} "
          f"{'p99/baseline':>13}")
    for name, median, p99 in rows:
        print(f"{name:<40} {median:>10.3f} {p99:>8.3f} {p99 / base[1]:>13.1f}")


if __name__ == "__main__":
    main()
