"""Per-window inference latency of the networks, torch against ONNX, and MiniRocket.

Trains each network briefly on random grids of the default shape (21 channels x
300 steps; the thesis's CNN: depth 4, width 2; LSTM: depth 2, width 2), then
times one-window predictions on one CPU thread: torch, the exported ONNX model in
onnxruntime, MiniRocket, and as the baseline measured in the same run the SVM's
online path on the same window's scalar features. Prints median and p99 [ms].

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

from classify.fast import fast_predictor
from classify.models import make_model
from classify.nn import make_network
from features.scalars import scalar_features

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


def main() -> None:
    rng = np.random.default_rng(0)
    X = rng.normal(size=(64, 21, 300)).astype(np.float32)
    y = np.array(["none", "bump", "adjust", "shove"] * 16)
    window = X[:1]
    rows = []
    channels = [f"c{i}" for i in range(21)]
    features = np.array([scalar_features(x.T, ["range"], channels)[0] for x in X])
    svm = fast_predictor(make_model("svm", [f"range(tau_{i % 7 + 1})" for i in range(21)])
                         .fit(features, y))
    base = timed(lambda: svm(scalar_features(window[0].T, ["range"], channels)[0][None, :]))
    rows.append(("SVM online path (baseline)", *base))
    with tempfile.TemporaryDirectory() as tmp:
        for kind in ("cnn", "lstm"):
            net = make_network(kind, epochs=1).fit(X, y)
            rows.append((f"{kind} torch", *timed(lambda net=net: net.predict_proba(window))))
            path = Path(tmp) / f"{kind}.onnx"
            net.export_onnx(path, 21, 300)
            options = ort.SessionOptions()
            options.intra_op_num_threads = options.inter_op_num_threads = 1
            session = ort.InferenceSession(str(path), options)
            rows.append((f"{kind} ONNX", *timed(lambda s=session: s.run(None, {"grid": window}))))
        rocket = make_network("minirocket").fit(X.astype(float), y)
        rows.append(("MiniRocket", *timed(lambda: rocket.predict_proba(window))))
    print(f"{'model (one window, one thread)':<30} {'median ms':>10} {'p99 ms':>8} "
          f"{'p99/baseline':>13}")
    for name, median, p99 in rows:
        print(f"{name:<30} {median:>10.3f} {p99:>8.3f} {p99 / base[1]:>13.1f}")


if __name__ == "__main__":
    main()
