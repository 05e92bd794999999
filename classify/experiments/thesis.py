"""Experiments that regenerate the thesis's tables on any dataset.

* ``features``: feature identification (Appendix B): each timeseries feature, each
  group and the thesis's combinations with mean, variance and range (B.2); each
  scalar feature and combination on joint torques (B.3); the thesis's best input.
* ``rfe``: recursive feature elimination (future work 7.3.5) over every timeseries
  x scalar feature, selection fitted inside each split: accuracy against the number
  of features kept, and the features chosen on the whole data.
* ``speed``: accuracy by joint-speed band of dynamic sessions (Figure 6.5): at the
  band, at or below it, and at or below it with the static sessions added.
* ``window``: accuracy against window length (0.1, 0.2, 0.3, 0.5 s after the
  detected onset).

Each writes ``<name>.md`` (a table), ``<name>.json`` and ``<name>.png`` into the
output directory. Models are the whole-arm SVM without probability calibration
(labels only, as the thesis's feature tests), evaluated under the chosen protocol.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from itertools import pairwise
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from sklearn.feature_selection import RFE
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC, LinearSVC

from contactkit.classify.data import FeatureSet, load_features
from contactkit.classify.evaluate import Report, evaluate
from contactkit.classify.kinds.svm import SVM
from contactkit.classify.kinds.svm_estimators import svm_pipeline
from contactkit.classify.names import EXPERIMENTS
from contactkit.classify.schemes import scheme_classes
from contactkit.errors import check_choice
from contactkit.features.extract import SessionFeatures
from contactkit.features.scalars import SCALARS
from contactkit.features.timeseries import ALL_TIMESERIES, GROUPS, columns_of
from contactkit.schemas import InputError
from contactkit.util.atomic import write_text
from contactkit.util.owned import (
    check_results,
    owned_result,
    result_json,
    result_markdown,
    write_figure,
)

MVR = ("mean", "variance", "range")
WINDOW_LENGTHS = (0.1, 0.2, 0.3, 0.5)
SPEED_EDGES = (0.1, 0.2, 0.3, 0.4, 0.5)
Progress = Callable[[str, int, int], None]


@dataclass
class Setting:
    """How experiments evaluate: protocol, grouping, class scheme, seed, and where the
    features are computed (``workers`` processes, or the Dask ``scheduler``)."""

    protocol: str = "group"
    group_by: str = "pose"
    scheme: str = "full"
    seed: int = 0
    workers: int = 1
    c: float = 10.0
    scheduler: str | None = None


@dataclass
class Row:
    """One experiment row: a label, what it used, and its evaluation report."""

    label: str
    detail: str
    report: Report


def _select(data: FeatureSet, timeseries: Sequence[str], scalars: Sequence[str]) -> FeatureSet:
    channels = [c for name in timeseries for c in columns_of(name)]
    names = []
    for scalar in scalars:
        prefixes = [f"fft{j}" for j in range(3)] if scalar == "fft" else [scalar]
        names += [f"{p}({c})" for p in prefixes for c in channels]
    return data.columns(names)


def _evaluate(data: FeatureSet, setting: Setting) -> Report:
    y = data.labels(setting.scheme)
    groups = data.groups(setting.group_by) if setting.protocol == "group" else None
    return evaluate(data.X, y, lambda: svm_pipeline(setting.c, seed=setting.seed,
                                                    probability=False),
                    protocol=setting.protocol, model=SVM.name, groups=groups,
                    group_by=setting.group_by, scheme=setting.scheme,
                    classes=scheme_classes(setting.scheme), seed=setting.seed)


def _wide(sources: Sequence[Path], setting: Setting, window_s: float = 0.5,
          progress: Progress | None = None, label: str = "features") -> FeatureSet:
    extractor = SessionFeatures(timeseries=list(ALL_TIMESERIES), scalars=list(SCALARS),
                                window_s=window_s)
    report = None if progress is None else (lambda d, t: progress(label, d, t))
    return load_features(sources, extractor, setting.workers, report,
                         scheduler=setting.scheduler)


def feature_identification(data: FeatureSet, setting: Setting,
                           progress: Progress | None = None) -> list[Row]:
    """Appendix B's grid on a wide feature set; return one row per combination."""
    grid: list[tuple[str, tuple[str, ...], tuple[str, ...]]] = []
    for group, members in GROUPS.items():
        for name in members:
            grid.append((f"B.2 {group}", (name,), MVR))
        grid.append((f"B.2 {group}", members, MVR))
    for combo in (("dq", "tau"), ("tau", "r"), ("dq", "r"), ("dq", "tau", "r"), ("f", "r"),
                  ("dq", "tau", "r", "f"), ("dq", "tau", "r", "fm_norm"),
                  ("tau", "r", "fm_norm")):
        grid.append(("B.2 combination", combo, MVR))
    for scalar in SCALARS:
        grid.append(("B.3 scalar", ("tau",), (scalar,)))
    for combo in (MVR, ("range", "hjorth_mob", "hjorth_comp"), ("range", "fft"),
                  ("hjorth_mob", "hjorth_comp", "fft")):
        grid.append(("B.3 scalar combination", ("tau",), combo))
    grid.append(("thesis best", ("dq", "tau", "r"), ("range",)))
    grid.append(("shape-aware", ("dq", "tau", "r"), ("range", "hjorth_mob", "hjorth_comp")))
    rows = []
    for i, (section, timeseries, scalars) in enumerate(grid):
        report = _evaluate(_select(data, timeseries, scalars), setting)
        rows.append(Row(f"{'+'.join(timeseries)} / {'+'.join(scalars)}", section, report))
        if progress:
            progress("combinations", i + 1, len(grid))
    return rows


def recursive_elimination(data: FeatureSet, setting: Setting, sizes: Sequence[int] = (1, 3, 7,
                          14, 21, 42, 84), progress: Progress | None = None
                          ) -> tuple[list[Row], list[str]]:
    """RFE with a linear SVM ranking inside each split, an RBF SVM on the kept features.

    Returns one row per number of kept features and the features RFE keeps on the
    whole data at the best size.
    """
    y = data.labels(setting.scheme)
    groups = data.groups(setting.group_by) if setting.protocol == "group" else None
    sizes = [s for s in sizes if s <= data.X.shape[1]]

    def pipeline(n: int) -> Pipeline:
        ranker = LinearSVC(C=0.1, dual=False, max_iter=5000)
        return Pipeline([("scale", StandardScaler()),
                         ("rfe", RFE(ranker, n_features_to_select=n, step=0.2)),
                         ("svc", SVC(C=setting.c, random_state=setting.seed))])

    rows = []
    for i, n in enumerate(sizes):
        report = evaluate(data.X, y, partial(pipeline, n), protocol=setting.protocol,
                          groups=groups, group_by=setting.group_by, model=f"rfe-{n}",
                          scheme=setting.scheme, classes=scheme_classes(setting.scheme),
                          seed=setting.seed)
        rows.append(Row(f"{n} features", "RFE (linear SVM ranking)", report))
        if progress:
            progress("feature counts", i + 1, len(sizes))
    best = max(rows, key=lambda r: r.report.balanced_accuracy.value)
    best_n = int(best.label.split()[0])
    fitted = pipeline(best_n).fit(data.X, y)
    chosen = [n for n, keep in zip(data.names, fitted.named_steps["rfe"].support_, strict=True)
              if keep]
    return rows, chosen


def speed_bands(data: FeatureSet, setting: Setting, progress: Progress | None = None
                ) -> list[Row]:
    """Accuracy by speed band of dynamic sessions, in the three series of Figure 6.5."""
    speed = data.info["speed_rad_s"]
    dynamic = data.info["condition"] == "dynamic"
    static = data.info["condition"] == "static"
    if not dynamic.any():
        raise InputError("the speed experiment needs dynamic sessions")
    rows = []
    bands = list(pairwise(SPEED_EDGES))
    for i, (lo, hi) in enumerate(bands):
        series = {"at band": dynamic & (speed >= lo) & (speed < hi + 1e-9),
                  "at or below": dynamic & (speed < hi + 1e-9),
                  "at or below + static": (dynamic & (speed < hi + 1e-9)) | static}
        for name, mask in series.items():
            part = data.subset(mask)
            if len(set(part.labels(setting.scheme))) < 2 or len(part) < 10:
                continue
            try:
                report = _evaluate(part, setting)
            except (InputError, ValueError):
                continue
            rows.append(Row(f"{lo:.1f}-{hi:.1f} rad/s", name, report))
        if progress:
            progress("speed bands", i + 1, len(bands))
    return rows


def window_lengths(sources: Sequence[Path], setting: Setting,
                   progress: Progress | None = None) -> list[Row]:
    """Accuracy of the thesis's best input against window length after the onset."""
    rows = []
    for length in WINDOW_LENGTHS:
        extractor = SessionFeatures(window="difference", window_s=length)
        report_progress = None if progress is None else (
            lambda d, t, length=length: progress(f"window {length} s", d, t))
        data = load_features(sources, extractor, setting.workers, report_progress,
                             scheduler=setting.scheduler)
        rows.append(Row(f"{length:.1f} s", "range(dq, tau, r), difference window",
                        _evaluate(data, setting)))
    return rows


def _markdown(title: str, rows: list[Row], setting: Setting, extra: str = "") -> str:
    how = ("25 random 80/20 splits" if setting.protocol == "thesis"
           else f"group protocol by {setting.group_by}")
    lines = [f"# {title}", "", f"Whole-arm SVM (C = {setting.c}), scheme {setting.scheme}, "
             f"{how}, seed {setting.seed}. Values with 95 % confidence intervals.", "",
             "| input | what | sessions | accuracy | balanced accuracy | macro-F1 |",
             "|---|---|---|---|---|---|"]
    for row in rows:
        r = row.report
        lines.append(f"| {row.label} | {row.detail} | {r.n_sessions} | {r.accuracy.text()} | "
                     f"{r.balanced_accuracy.text()} | {r.macro_f1.text()} |")
    return "\n".join(lines) + "\n" + extra


def _plot(path: Path, title: str, rows: list[Row], series_key: bool = False) -> None:
    fig, ax = plt.subplots(figsize=(max(6.0, 0.35 * len(rows) + 3), 4.5))
    if series_key:
        for name in dict.fromkeys(r.detail for r in rows):
            part = [r for r in rows if r.detail == name]
            x = [r.label for r in part]
            v = np.array([r.report.balanced_accuracy.value for r in part]) * 100
            lo = v - np.array([r.report.balanced_accuracy.low for r in part]) * 100
            hi = np.array([r.report.balanced_accuracy.high for r in part]) * 100 - v
            ax.errorbar(x, v, yerr=[lo, hi], marker="o", capsize=3, label=name)
        ax.legend()
    else:
        v = np.array([r.report.balanced_accuracy.value for r in rows]) * 100
        lo = v - np.array([r.report.balanced_accuracy.low for r in rows]) * 100
        hi = np.array([r.report.balanced_accuracy.high for r in rows]) * 100 - v
        ax.bar(range(len(rows)), v, yerr=[lo, hi], capsize=3, color="#4c72b0")
        ax.set_xticks(range(len(rows)), [r.label for r in rows], rotation=70, ha="right",
                      fontsize=7)
    ax.set_ylabel("balanced accuracy [%] (95 % CI)")
    ax.set_ylim(0, 100)
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    write_figure(path, fig, owned=owned_result, dpi=120)
    plt.close(fig)


def run_experiment(name: str, sources: Sequence[Path], out_dir: Path, setting: Setting,
                   progress: Progress | None = None) -> list[Path]:
    """Run one experiment and write its Markdown, JSON and PNG; return the paths."""
    check_choice("experiment", name, EXPERIMENTS)
    check_results(out_dir, [f"{name}.{ext}" for ext in ("md", "json", "png")])
    out_dir.mkdir(parents=True, exist_ok=True)
    extra, series, doc_extra = "", False, {}
    if name == "features":
        rows = feature_identification(_wide(sources, setting, progress=progress), setting,
                                      progress)
        title = "Feature identification (thesis Appendix B)"
    elif name == "rfe":
        data = _wide(sources, setting, progress=progress)
        rows, chosen = recursive_elimination(data, setting, progress=progress)
        title = "Recursive feature elimination"
        extra = "\nFeatures kept at the best size (fitted on all data):\n\n" + \
            "\n".join(f"- `{c}`" for c in chosen) + "\n"
        doc_extra = {"chosen": chosen}
    elif name == "speed":
        extractor = SessionFeatures()
        data = load_features(sources, extractor, setting.workers,
                             None if progress is None else
                             (lambda d, t: progress("features", d, t)),
                             scheduler=setting.scheduler)
        rows = speed_bands(data, setting, progress)
        title, series = "Accuracy by joint speed (thesis Figure 6.5)", True
    else:
        rows = window_lengths(sources, setting, progress)
        title, series = "Accuracy against window length", True
    md, js, png = (out_dir / f"{name}.{ext}" for ext in ("md", "json", "png"))
    write_text(md, result_markdown(_markdown(title, rows, setting, extra)),
               owned=owned_result)
    write_text(js, json.dumps(result_json({
        "experiment": name, "setting": vars(setting), "sources": [str(s) for s in sources],
        "rows": [{"label": r.label, "detail": r.detail, "report": r.report.as_dict()}
                 for r in rows], **doc_extra}), indent=2), owned=owned_result)
    _plot(png, title, rows, series)
    return [md, js, png]
