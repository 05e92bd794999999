"""The augmentation experiment (thesis Algorithm 3, section 5.3.5).

For each repetition, 15 % of the "real" dataset is held out as the test set
(stratified). For 50 %, 75 % and 100 % of the remaining real sessions, a network is
trained on the real sessions only, then with one copy of the simulated set (1xSim),
then with two identical copies (2xSim), then with the simulated set augmented
twice over: torque noise of 1, 5 and 10 times the measured sensor noise, once with
the observer gain 10 % lower and once 10 % higher. Every model is scored on the
same real test set; the table gives the mean balanced accuracy over repetitions
with a 95 % confidence interval (Student t), and two plots in the style of the
thesis's Figures 6.10 and 6.11.

The noise baseline is the thesis's statistic measured on the real set's no-contact
sessions (per joint, the standard deviation of the torque over a session, averaged
over sessions), or a noise file from ``recorder stats --deep`` (``--noise-file``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from scipy import stats
from sklearn.model_selection import train_test_split

from contactkit.classify.data import FeatureSet
from contactkit.classify.evaluate import confusion, fit_predict_many, metrics_from_confusion
from contactkit.classify.grids import Augmentation, GridSpec, load_grids
from contactkit.classify.kinds.inputs import GRIDS
from contactkit.classify.kinds.kind import ModelKind, ModelOptions
from contactkit.schemas import InputError, read_session
from contactkit.schemas.dataset import session_files
from contactkit.util.atomic import write_text
from contactkit.util.owned import (
    check_results,
    owned_result,
    result_json,
    result_markdown,
    write_figure,
)
from contactkit.util.safe_open import read_json

FRACTIONS = (0.5, 0.75, 1.0)
NOISE_LEVELS = (1, 5, 10)
GAIN_FACTORS = (0.9, 1.1)
Progress = Callable[[str, int, int], None]


def noise_baseline(real_dir: Path, noise_file: Path | None = None) -> np.ndarray:
    """Return the per-joint torque-noise baseline [Nm] (see the module docstring)."""
    if noise_file is not None:
        doc = read_json(noise_file, "noise file")
        try:
            values = doc.get("thesis_tau_std_nm") or doc["tau_sigma_nm"]
            baseline = np.asarray(values, dtype=float)
        except (OSError, KeyError, ValueError, TypeError, AttributeError) as err:
            raise InputError(f"not a noise file ({type(err).__name__}: "
                             f"{' '.join(str(err).split())[:200]})", noise_file) from err
        if baseline.shape != (7,) or not np.isfinite(baseline).all() or (baseline < 0).any():
            raise InputError("the torque noise baseline is not 7 finite non-negative numbers "
                             "[Nm]", noise_file)
        return baseline
    stds = []
    for path in session_files(real_dir):
        try:
            session = read_session(path)
        except InputError:
            continue
        if session.meta.action == "none":
            stds.append(np.nanstd(session.tau, axis=0))
    if not stds:
        raise InputError("no no-contact session to measure the noise baseline; give a "
                         "noise file from the dataset statistics", real_dir)
    return np.mean(stds, axis=0)


@dataclass
class Cell:
    """One experiment cell: real fraction, condition, and its scores over repetitions."""

    fraction: float
    condition: str
    scores: list[float]

    def interval(self) -> tuple[float, float, float]:
        """Mean and 95 % Student-t interval of the scores."""
        values = np.asarray(self.scores)
        mean = float(values.mean())
        if len(values) < 2:
            return mean, float("nan"), float("nan")
        half = float(stats.t.ppf(0.975, len(values) - 1) * values.std(ddof=1)
                     / np.sqrt(len(values)))
        return mean, mean - half, mean + half


def run_augmentation(real_dir: Path, sim_dir: Path, out_dir: Path, *, kind: ModelKind,
                     options: ModelOptions, repeats: int = 3, workers: int = 1,
                     noise_file: Path | None = None,
                     progress: Progress | None = None,
                     scheduler: str | None = None) -> list[Path]:
    """Run the experiment with a kind that takes grids (``options`` size the network and
    the grid; the seed of repetition r is ``options.seed + r``), in ``workers`` processes
    or on the Dask ``scheduler``; write augmentation.md, .json and .png; return their
    paths."""
    if kind.input.name != GRIDS.name:
        raise InputError(f"the augmentation experiment trains networks on grids; a "
                         f"{kind.name} model takes {kind.input.name}")
    if repeats < 1:
        raise InputError(f"repeats must be at least 1, got {repeats}")
    check_results(out_dir, [f"augmentation.{ext}" for ext in ("md", "json", "png")])
    options = kind.check_options(options)
    transformer: Any = kind.transformer(options)  # SessionGrids: the kind takes grids
    spec = transformer.spec
    seed = options.seed
    baseline = noise_baseline(real_dir, noise_file)

    def grids(source: Path, aug: Augmentation | None, label: str) -> FeatureSet:
        report = None if progress is None else (lambda d, t: progress(label, d, t))
        return load_grids([source], spec, workers, aug, report, scheduler=scheduler)

    real = grids(real_dir, None, "real grids")
    # a grid set per simulated condition; a list of them (one per gain) per noise level
    sim_sets: dict[str, Any] = {"1xSim": grids(sim_dir, None, "sim grids")}
    for level in NOISE_LEVELS:
        parts = [grids(sim_dir, Augmentation(level, tuple(baseline), factor, seed),
                       f"sim grids, noise x{level}, gain x{factor}")
                 for factor in GAIN_FACTORS]
        sim_sets[f"noise x{level}"] = parts
    classes = sorted(set(real.labels()))
    conditions = ["real", "1xSim", "2xSim", *[f"noise x{n}" for n in NOISE_LEVELS]]
    y_real = real.labels()
    plan = []
    for r in range(repeats):
        pool, test = train_test_split(np.arange(len(y_real)), test_size=0.15,
                                      random_state=seed + r, stratify=y_real)
        order = np.random.default_rng([seed, r]).permutation(pool)
        for fraction in FRACTIONS:
            chosen = order[:max(len(classes) * 2, round(fraction * len(pool)))]
            plan += [(r, fraction, condition, chosen, test) for condition in conditions]

    def tasks():
        for r, _, condition, chosen, test in plan:
            X, y = [real.X[chosen]], [y_real[chosen]]
            if condition in ("1xSim", "2xSim"):
                copies = 1 if condition == "1xSim" else 2
                X += [sim_sets["1xSim"].X] * copies
                y += [sim_sets["1xSim"].labels()] * copies
            elif condition.startswith("noise"):
                X += [part.X for part in sim_sets[condition]]
                y += [part.labels() for part in sim_sets[condition]]
            yield (kind.estimator(replace(options, seed=seed + r), real.names), np.concatenate(X),
                   np.concatenate(y), real.X[test])

    report = None if progress is None else (lambda d, t: progress("trainings", d, t))
    predictions = fit_predict_many(tasks(), workers, report, len(plan), scheduler=scheduler)
    cells = {(f, c): Cell(f, c, []) for f in FRACTIONS for c in conditions}
    for (_, fraction, condition, _, test), predicted in zip(plan, predictions, strict=True):
        score = metrics_from_confusion(confusion(y_real[test], predicted, classes))
        cells[(fraction, condition)].scores.append(float(score["balanced_accuracy"]))
    return _write(out_dir, cells, conditions, kind.name, spec, repeats, baseline, real_dir, sim_dir)


def _write(out_dir: Path, cells: dict, conditions: list[str], model: str, spec: GridSpec,
           repeats: int, baseline: np.ndarray, real_dir: Path, sim_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    header = "| real data | " + " | ".join(conditions) + " |"
    lines = ["# Augmentation experiment (thesis Algorithm 3)", "",
             f"{model.upper()} on {spec.steps}-step window grids of "
             f"{', '.join(spec.timeseries)}; {repeats} repetitions, each with its own "
             "held-out 15 % real test set. Balanced accuracy, mean [95 % CI].", "",
             f"Real: `{real_dir}`; simulated: `{sim_dir}`; torque-noise baseline [Nm]: "
             + ", ".join(f"{v:.3f}" for v in baseline), "", header,
             "|---|" + "---|" * len(conditions)]
    for fraction in FRACTIONS:
        row = []
        for condition in conditions:
            mean, lo, hi = cells[(fraction, condition)].interval()
            row.append(f"{100 * mean:.1f} [{100 * lo:.1f}, {100 * hi:.1f}]")
        lines.append(f"| {int(fraction * 100)} % | " + " | ".join(row) + " |")
    md, js, png = (out_dir / f"augmentation.{ext}" for ext in ("md", "json", "png"))
    write_text(md, result_markdown("\n".join(lines) + "\n"), owned=owned_result)
    write_text(js, json.dumps(result_json({
        "model": model, "grid": spec.as_dict(), "repeats": repeats,
        "noise_baseline_nm": baseline.tolist(),
        "cells": [{"fraction": c.fraction, "condition": c.condition,
                   "balanced_accuracy": c.scores, "mean_ci": c.interval()}
                  for c in cells.values()]}), indent=2), owned=owned_result)
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for fraction in FRACTIONS:
        for ax, names, labels in ((left, conditions[:3], ["real", "1xSim", "2xSim"]),
                                  (right, ["2xSim", *conditions[3:]], ["0", "1", "5", "10"])):
            means = np.array([cells[(fraction, c)].interval() for c in names])
            ax.errorbar(labels, 100 * means[:, 0],
                        yerr=[100 * (means[:, 0] - means[:, 1]),
                              100 * (means[:, 2] - means[:, 0])],
                        marker="o", capsize=3, label=f"{int(fraction * 100)} % real")
    left.set_title("adding simulated data")
    right.set_title("noise augmentation (x measured sensor noise)")
    left.set_ylabel("balanced accuracy [%] (95 % CI)")
    right.legend()
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    write_figure(png, fig, owned=owned_result, dpi=120)
    plt.close(fig)
    return [md, js, png]
