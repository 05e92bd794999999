"""Networks beside the SVM under leave-one-pose-out: writes docs/networks.md.

    .venv/bin/python docs/networks.py --data data/static --sessions 480 --steps 100

Takes a balanced subset of a static dataset (the first N sessions in file order of
each pose and action), evaluates the shape-aware SVM, the LSTM, MiniRocket and the
CNN on the same leave-one-pose-out folds, and writes a table with 95 % confidence
intervals. Network sizes, grid length and epochs are arguments because the
thesis's CNN (depth 4, width 2, 300 steps) takes hours per fold on a CPU; the page
states what was run.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from classify.data import load_features
from classify.evaluate import Report, evaluate
from classify.grids import CNN_INPUT, LSTM_INPUT, GridSpec, load_grids
from classify.models import make_model
from classify.nn import make_network
from classify.schemes import scheme_classes
from features.extract import SessionFeatures

ROOT = Path(__file__).resolve().parents[1]
CLASSES = scheme_classes("full")


def balanced_subset(data, per_cell: int) -> np.ndarray:
    """Return a mask keeping the first ``per_cell`` sessions of every pose x action."""
    keep = np.zeros(len(data), dtype=bool)
    groups = data.groups("pose")
    for pose in np.unique(groups):
        for action in CLASSES:
            cell = np.flatnonzero((groups == pose) & (data.info["action"] == action))
            keep[cell[:per_cell]] = True
    return keep


def row(name: str, detail: str, report: Report, seconds: float) -> str:
    """One Markdown row."""
    return (f"| {name} | {detail} | {report.n_sessions} | {report.balanced_accuracy.text()} | "
            f"{report.accuracy.text()} | {report.recall['shove'].text()} | "
            f"{seconds / 60:.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT / "data" / "static")
    parser.add_argument("--sessions", type=int, default=480)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "networks.md")
    args = parser.parse_args()
    per_cell = max(1, args.sessions // (8 * len(CLASSES)))
    lines = ["# Networks beside the SVM (leave one pose out)", "",
             f"`docs/networks.py --data {args.data} --sessions {args.sessions} --steps "
             f"{args.steps} --epochs {args.epochs}`: a balanced subset of {per_cell} sessions "
             "per pose and action, the same leave-one-pose-out folds for every model, "
             "balanced accuracy and accuracy with 95 % cluster-bootstrap intervals. The "
             "thesis reports, on its real data and random splits: CNN up to 93 %, LSTM up "
             "to 84 %, SVM 87 %.", "",
             "| model | input | sessions | balanced accuracy | accuracy | shove recall | "
             "minutes |", "|---|---|---|---|---|---|---|"]
    svm_data = load_features([args.data], SessionFeatures(
        scalars=["range", "hjorth_mob", "hjorth_comp"], window="planned"), args.workers)
    keep = balanced_subset(svm_data, per_cell)
    svm_data = svm_data.subset(keep)
    runs = [("SVM (C=100)", "range + Hjorth of dq, tau, r", svm_data,
             lambda: make_model("svm", svm_data.names, 0, 100.0))]
    for kind, inputs, params in (
            ("lstm", LSTM_INPUT, {"depth": 1, "width": 1.0}),
            ("minirocket", CNN_INPUT, {}),
            ("cnn", CNN_INPUT, {"depth": 1, "width": 1.0})):
        grids = load_grids([args.data], GridSpec(timeseries=inputs, steps=args.steps),
                           args.workers)
        grids = grids.subset(balanced_subset(grids, per_cell))
        label = f"{kind} " + ", ".join(f"{k} {v}" for k, v in params.items())
        runs.append((label.strip(), f"{args.steps}-step grid of {', '.join(inputs)}", grids,
                     lambda kind=kind, params=params: make_network(kind, 0, args.epochs,
                                                                   **params)))
    for name, detail, data, factory in runs:
        started = time.time()
        report = evaluate(data.X, data.labels(), factory, protocol="group",
                          groups=data.groups("pose"), group_by="pose", model=name,
                          classes=CLASSES, seed=0)
        lines.append(row(name, detail, report, time.time() - started))
        print(lines[-1], flush=True)
        args.out.write_text("\n".join(lines) + "\n")
    print(args.out)


if __name__ == "__main__":
    main()
