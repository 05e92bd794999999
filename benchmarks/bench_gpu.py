"""The thesis's networks on the CPU and on a CUDA GPU: time per epoch, repeatability,
and how far the GPU's predictions are from the CPU's.

Imports only :mod:`contactkit.classify.kinds.networks` (numpy, scikit-learn, PyTorch), so it
runs on a GPU machine without the feature chain's dependencies:

    PYTHONPATH=<dir holding the contactkit package> python3 benchmarks/bench_gpu.py
    .venv/bin/python benchmarks/bench_gpu.py --device cpu --windows 64 --epochs 1

The windows are generated, of the thesis's shape: 21 channels (seven joints x three
timeseries: dq, tau, r for the LSTM, q, dq, tau for the CNN) x 300 time steps, four
classes whose windows differ by a bump of class-dependent height and length on a few
channels, over noise. For each network (the thesis's choices: LSTM depth 2, CNN depth
4, both width 2, dropout 0.02) it trains, with the same seed:

* on the CPU (one thread, as every contactkit worker trains), twice on a small subset,
  to check that the CPU is bit-repeatable;
* on the CPU and on CUDA, the full set for ``--epochs`` epochs (early stopping off),
  and prints seconds per epoch on each, their ratio, and the largest and mean absolute
  difference of the predicted probabilities and the share of windows whose predicted
  class differs.

Without CUDA (or with ``--device cpu``) the GPU part prints a skip line. The defaults
(512 windows, 2 epochs) take about 4 minutes on a loaded 2-core machine without a GPU,
almost all of it the CNN's CPU epochs (about 0.2 s per window and epoch on one core),
so well under 5 minutes on a 16-core machine with an H100.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # before CUDA starts

import numpy as np

from contactkit.classify.kinds.networks import CNNClassifier, LSTMClassifier, require_torch

NETWORKS = {"lstm": LSTMClassifier, "cnn": CNNClassifier}
CLASSES = np.array(["none", "bump", "adjust", "shove"])


def windows(n: int, channels: int, steps: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Return ``n`` generated windows (n, channels, steps) float32 and their class labels."""
    rng = np.random.default_rng(seed)
    y = CLASSES[np.arange(n) % len(CLASSES)]
    X = rng.normal(scale=0.3, size=(n, channels, steps)).astype(np.float32)
    t = np.linspace(0.0, 1.0, steps)
    for k in range(1, len(CLASSES)):
        rows = np.flatnonzero(y == CLASSES[k])
        onset = rng.uniform(0.1, 0.4, size=len(rows))
        length = 0.1 * k
        bump = np.exp(-0.5 * ((t[None, :] - onset[:, None] - length / 2) / (length / 3)) ** 2)
        height = rng.normal(0.6 * k, 0.2, size=(len(rows), 1))
        for channel in range(k, channels, 3):
            X[rows, channel] += (height * bump).astype(np.float32)
    return X, y


def fit_timed(network: type, X: np.ndarray, y: np.ndarray, epochs: int, device: str,
              seed: int) -> tuple[object, float]:
    """Train with early stopping off; return the fitted network and seconds per epoch."""
    model = network(epochs=epochs, patience=epochs + 1, seed=seed, device=device)
    start = time.perf_counter()
    model.fit(X, y)
    return model, (time.perf_counter() - start) / model.n_epochs_


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default="lstm,cnn", help="networks, comma-separated")
    parser.add_argument("--windows", type=int, default=512, help="training windows")
    parser.add_argument("--steps", type=int, default=300, help="time steps of a window")
    parser.add_argument("--channels", type=int, default=21, help="channels of a window")
    parser.add_argument("--epochs", type=int, default=2, help="epochs of the timed runs")
    parser.add_argument("--repeat-windows", type=int, default=128,
                        help="windows of the CPU repeatability check")
    parser.add_argument("--device", choices=("auto", "cpu"), default="auto",
                        help="auto: also train on CUDA where PyTorch sees a GPU")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch = require_torch()
    cuda = args.device == "auto" and torch.cuda.is_available()
    print(f"torch {torch.__version__}, python {sys.version.split()[0]}, "
          f"{os.cpu_count()} CPU cores; CUDA: "
          + (torch.cuda.get_device_name(0) if cuda else "none"), flush=True)
    if not cuda:
        print("GPU part skipped: PyTorch sees no CUDA GPU" if args.device == "auto"
              else "GPU part skipped: --device cpu")
    X, y = windows(args.windows, args.channels, args.steps, args.seed)
    for name in args.models.split(","):
        network = NETWORKS[name.strip()]
        print(f"\n{name}: {args.windows} windows of {args.channels} x {args.steps}, "
              f"{args.epochs} epochs", flush=True)
        small = slice(0, min(args.repeat_windows, args.windows))
        first, _ = fit_timed(network, X[small], y[small], 1, "cpu", args.seed)
        second, _ = fit_timed(network, X[small], y[small], 1, "cpu", args.seed)
        same = all(torch.equal(a, b) for a, b in zip(first.model_.state_dict().values(),
                                                     second.model_.state_dict().values(),
                                                     strict=True))
        print(f"  cpu bit-repeatable: {'yes' if same else 'NO'} (two 1-epoch trainings on "
              f"{len(X[small])} windows, same seed)", flush=True)
        cpu, cpu_epoch = fit_timed(network, X, y, args.epochs, "cpu", args.seed)
        print(f"  cpu  {cpu_epoch:8.3f} s per epoch", flush=True)
        if not cuda:
            continue
        gpu, gpu_epoch = fit_timed(network, X, y, args.epochs, "cuda", args.seed)
        p_cpu, p_gpu = cpu.predict_proba(X), gpu.predict_proba(X)
        diff = np.abs(p_cpu - p_gpu)
        changed = float(np.mean(p_cpu.argmax(axis=1) != p_gpu.argmax(axis=1)))
        print(f"  cuda {gpu_epoch:8.3f} s per epoch   cpu/cuda {cpu_epoch / gpu_epoch:6.1f}x")
        print(f"  cuda vs cpu probabilities: max |diff| {diff.max():.2e}, mean "
              f"{diff.mean():.2e}; predicted class differs on {100 * changed:.1f} % of "
              "windows", flush=True)


if __name__ == "__main__":
    main()
