"""Regenerate docs/results.md: classifiers on thesis-sized simulated datasets.

    .venv/bin/python docs/results.py --data data --workers 2

Simulates ``thesis-static`` and ``thesis-dynamic`` into DATA/static and
DATA/dynamic when they are missing (about 15 minutes on 2 cores; existing sessions
are kept), computes features (cached in contactkit's cache directory), and
evaluates the SVM and the per-joint ensembles under the thesis protocol (25 random 80/20 splits)
and the group protocol (leave one pose out), on the static, dynamic and combined
sets. Then it breaks the best model's leave-one-pose-out predictions down by the
touched link. Everything is seeded; re-running gives the same page. The sections
written by docs/networks.py ("Networks"), docs/real.py ("On a real Panda") and
docs/thesis_events.py ("Thesis presets, event level") are kept as they are.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from networks import SECTION as NETWORKS_SECTION
from networks import touched_links
from real import SECTION as REAL_SECTION
from thesis_events import SECTION as THESIS_EVENTS_SECTION

from contactkit.classify.data import FeatureSet, load_features
from contactkit.classify.evaluate import Report, evaluate
from contactkit.classify.kinds.registry import make_estimator
from contactkit.classify.schemes import scheme_classes
from contactkit.features.extract import SessionFeatures
from contactkit.util.atomic import write_text

ROOT = Path(__file__).resolve().parents[1]
CLASSES = scheme_classes("full")


@dataclass(frozen=True)
class Config:
    """A feature and model configuration to report."""

    name: str
    extractor: SessionFeatures
    c: float


CONFIGS = (
    Config("thesis best: range(dq, tau, r), difference window, C=1",
           SessionFeatures(), 1.0),
    Config("shape-aware: range + Hjorth(dq, tau, r), planned window, C=100",
           SessionFeatures(scalars=["range", "hjorth_mob", "hjorth_comp"], window="planned"),
           100.0),
)


def ensure_dataset(directory: Path, preset: str, workers: int) -> None:
    """Simulate a preset into ``directory`` unless it is complete."""
    recorder = Path(sys.executable).parent / "recorder"
    subprocess.run([str(recorder), "simulate", str(directory), "--preset", preset, "--workers",
                    str(workers)], check=True)


def run(data: FeatureSet, kind: str, protocol: str, c: float) -> Report:
    """Evaluate one model kind under one protocol (leave-one-pose-out for group)."""
    groups = data.groups("pose") if protocol == "group" else None
    return evaluate(data.X, data.labels(), lambda: make_estimator(kind, data.names, c=c),
                    protocol=protocol, groups=groups, group_by="pose", model=kind,
                    classes=CLASSES, seed=0)


def per_link(data: FeatureSet, report: Report) -> list[tuple[str, int, float]]:
    """Accuracy by touched link of a leave-one-pose-out report's predictions."""
    links = touched_links(data.info["dataset"], data.info["file"])
    correct = report.out_of_fold == data.labels()
    return [(link, int((links == link).sum()), float(correct[links == link].mean()))
            for link in ["none", *[str(k) for k in range(1, 8)]] if (links == link).any()]


def row(dataset: str, config: Config, report: Report) -> str:
    """One Markdown table row."""
    protocol = "thesis 25x80/20" if report.protocol == "thesis" else "leave one pose out"
    return (f"| {dataset} | {report.model} | {protocol} | {report.n_sessions} | "
            f"{report.accuracy.text()} | {100 * report.split_accuracy_mean:.1f} ± "
            f"{100 * report.split_accuracy_std:.1f} | {report.balanced_accuracy.text()} | "
            f"{report.recall['shove'].text()} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT / "data")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "results.md")
    args = parser.parse_args()
    started = time.time()
    static, dynamic = args.data / "static", args.data / "dynamic"
    ensure_dataset(static, "thesis-static", args.workers)
    ensure_dataset(dynamic, "thesis-dynamic", args.workers)
    sections = []
    for config in CONFIGS:
        sets = {}
        for name, sources in (("static", [static]), ("dynamic", [dynamic]),
                              ("combined", [static, dynamic])):
            data = load_features(sources, config.extractor, args.workers)
            data.info["dataset"] = np.array(
                [str(static) if c == "static" else str(dynamic) for c in data.info["condition"]],
                dtype=object)
            sets[name] = data
        lines = [f"### {config.name}", "",
                 "| data | model | protocol | sessions | accuracy [95 % CI] | accuracy over "
                 "splits (mean ± sd) | balanced accuracy [95 % CI] | shove recall [95 % CI] |",
                 "|---|---|---|---|---|---|---|---|"]
        for name, data in sets.items():
            for kind in ("svm", "per-joint", "three-joint"):
                for protocol in ("thesis", "group"):
                    report = run(data, kind, protocol, config.c)
                    lines.append(row(name, config, report))
                    print(row(name, config, report), flush=True)
                    if (name, kind, protocol) == ("combined", "svm", "group"):
                        combined_svm = report
        lines += ["", "Leave-one-pose-out accuracy of the SVM by touched link (combined):", "",
                  "| link | sessions | accuracy |", "|---|---|---|"]
        lines += [f"| {link} | {n} | {100 * acc:.1f} % |"
                  for link, n, acc in per_link(sets["combined"], combined_svm)]
        sections.append("\n".join(lines))
    header = (ROOT / "docs" / "results_intro.md").read_text()
    footer = f"\n\n_Generated by `docs/results.py` in {(time.time() - started) / 60:.0f} min._\n"
    previous = args.out.read_text() if args.out.exists() else ""
    for generated_elsewhere in (NETWORKS_SECTION, REAL_SECTION, THESIS_EVENTS_SECTION):
        kept = generated_elsewhere.search(previous)
        if kept:
            sections.append(kept.group(0))
    write_text(args.out, header + "\n\n" + "\n\n".join(sections) + footer, overwrite=True)
    print(args.out)


if __name__ == "__main__":
    main()
