"""Evaluation protocols and honest metrics.

* ``thesis`` (section 4.3.3): 25 random 80/20 splits; mean and standard deviation
  of accuracy over the splits, confusion matrix row-normalised per split and summed
  over the splits (as the thesis's Figure 6.6).
* ``group``: no group on both sides of a split. Leave-one-group-out when there are
  at most 12 groups (poses, operators), otherwise stratified group 5-fold (sessions).

Every report gives accuracy, balanced accuracy, macro-F1, per-class recall and the
confusion matrix of the pooled out-of-split predictions, each with a 95 %
confidence interval from a cluster bootstrap (1000 resamples of whole groups, or of
whole sessions for the thesis protocol, whose sessions recur across its 25 test
sets), plus the mean and standard deviation of accuracy over splits. Scaling and any
feature selection are part of the model, so they are fitted inside each split.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from sklearn.base import clone
from sklearn.model_selection import LeaveOneGroupOut, ShuffleSplit, StratifiedGroupKFold

from contactkit.classify.schemes import check_two_classes
from contactkit.schemas import InputError
from contactkit.util.parallel import map_ordered

THESIS_SPLITS = 25
LOGO_MAX_GROUPS = 12
BOOTSTRAP = 1000


def _codes(labels: np.ndarray, classes: list[str]) -> np.ndarray:
    index = {c: i for i, c in enumerate(classes)}
    return np.array([index[v] for v in labels], dtype=int)


def _confusion_codes(t: np.ndarray, p: np.ndarray, k: int) -> np.ndarray:
    return np.bincount(t * k + p, minlength=k * k).reshape(k, k)


def confusion(y_true: np.ndarray, y_pred: np.ndarray, classes: list[str]) -> np.ndarray:
    """Return the confusion matrix of counts, rows true class, columns predicted."""
    return _confusion_codes(_codes(y_true, classes), _codes(y_pred, classes), len(classes))


def metrics_from_confusion(matrix: np.ndarray) -> dict[str, Any]:
    """Return accuracy, balanced accuracy, macro-F1 and per-class recall of a confusion
    matrix (classes with no true sample are left out of the averages)."""
    total = matrix.sum()
    diag = np.diag(matrix).astype(float)
    true_count = matrix.sum(axis=1)
    pred_count = matrix.sum(axis=0)
    present = true_count > 0
    recall = np.divide(diag, true_count, out=np.full(len(diag), np.nan), where=present)
    precision = np.divide(diag, pred_count, out=np.zeros(len(diag)), where=pred_count > 0)
    f1 = np.divide(2 * precision * recall, precision + recall, out=np.zeros(len(diag)),
                   where=(precision + recall) > 0)
    return {"accuracy": float(diag.sum() / total) if total else float("nan"),
            "balanced_accuracy": float(np.nanmean(recall[present])),
            "macro_f1": float(np.mean(f1[present])),
            "recall": recall.tolist()}


@dataclass
class Interval:
    """A point estimate with its 95 % confidence interval."""

    value: float
    low: float
    high: float

    def text(self, percent: bool = True) -> str:
        """Return ``87.1 % [84.0, 90.2]``."""
        if percent:
            return f"{100 * self.value:.1f} % [{100 * self.low:.1f}, {100 * self.high:.1f}]"
        return f"{self.value:.3f} [{self.low:.3f}, {self.high:.3f}]"


@dataclass
class Report:
    """The result of one evaluation (see the module docstring)."""

    protocol: str
    group_by: str | None
    model: str
    scheme: str
    classes: list[str]
    n_sessions: int
    n_splits: int
    accuracy: Interval
    balanced_accuracy: Interval
    macro_f1: Interval
    recall: dict[str, Interval]
    confusion_counts: list[list[int]]
    confusion_normalised: list[list[float]]
    split_accuracy_mean: float
    split_accuracy_std: float
    split_accuracies: list[float] = field(default_factory=list)
    out_of_fold: np.ndarray | None = field(default=None, repr=False, compare=False)

    def as_dict(self) -> dict:
        """Return the report as JSON-ready values (without the per-session predictions)."""
        doc = asdict(self)
        doc.pop("out_of_fold")
        return doc


def _bootstrap(y_true, y_pred, clusters, classes, rng) -> dict[str, np.ndarray]:
    """Resample whole clusters (groups or sessions) with replacement, BOOTSTRAP times."""
    t, p, k = _codes(y_true, classes), _codes(y_pred, classes), len(classes)
    unique, inverse = np.unique(clusters, return_inverse=True)
    per_cluster = np.stack([_confusion_codes(t[inverse == g], p[inverse == g], k)
                            for g in range(len(unique))])
    samples: dict[str, list[Any]] = {"accuracy": [], "balanced_accuracy": [], "macro_f1": [],
                                     "recall": []}
    for _ in range(BOOTSTRAP):
        pick = rng.integers(len(unique), size=len(unique))
        m = metrics_from_confusion(per_cluster[pick].sum(axis=0))
        for key in samples:
            samples[key].append(m[key])
    return {k: np.array(v, dtype=float) for k, v in samples.items()}


def _interval(value: float, draws: np.ndarray) -> Interval:
    finite = draws[np.isfinite(draws)]
    if finite.size == 0:
        return Interval(value, float("nan"), float("nan"))
    low, high = np.percentile(finite, [2.5, 97.5])
    return Interval(float(value), float(low), float(high))


def splits(protocol: str, y: np.ndarray, groups: np.ndarray | None, seed: int):
    """Return the list of (train, test) index arrays of a protocol."""
    if protocol == "thesis":
        return list(ShuffleSplit(THESIS_SPLITS, test_size=0.2, random_state=seed).split(y))
    if protocol != "group":
        raise InputError(f"unknown protocol {protocol!r} (expected thesis or group)")
    n_groups = 0 if groups is None else len(np.unique(groups))
    if n_groups < 2:
        raise InputError("the group protocol needs at least two groups")
    if n_groups <= LOGO_MAX_GROUPS:
        return list(LeaveOneGroupOut().split(y, y, groups))
    folds = StratifiedGroupKFold(5, shuffle=True, random_state=seed)
    return list(folds.split(np.zeros(len(y)), y, groups))


def _fit_predict(task: tuple) -> np.ndarray:
    """Fit one ``(estimator, X_train, y_train, X_test)`` task; return its predictions on
    the test sessions."""
    estimator, X_train, y_train, X_test = task
    return estimator.fit(X_train, y_train).predict(X_test)


def fit_predict_many(tasks: Iterable[tuple], workers: int = 1,
                     progress: Callable[[int, int], None] | None = None,
                     total: int | None = None, *,
                     scheduler: str | None = None) -> list[np.ndarray]:
    """Fit and predict every ``(estimator, X_train, y_train, X_test)`` task; return the
    predictions in task order.

    With ``workers`` > 1 the tasks run in that many fresh (spawned) processes, at
    most two per worker held in memory at once; the results do not depend on it.
    ``tasks`` may be a generator, so training sets are built only when needed.
    As with any spawned pool, a script that calls this with ``workers`` > 1 must do
    so under ``if __name__ == "__main__":``. A Dask ``scheduler`` runs them on its
    cluster instead.
    """
    return list(map_ordered(_fit_predict, tasks, workers=workers, progress=progress,
                            total=total, spawn=True, in_flight=2, scheduler=scheduler))


def evaluate(X: np.ndarray, y: np.ndarray, make_estimator: Callable[[], object], *,
             protocol: str, model: str, groups: np.ndarray | None = None,
             group_by: str | None = None, scheme: str = "full", classes: list[str] | None = None,
             seed: int = 0, progress: Callable[[int, int], None] | None = None,
             workers: int = 1, scheduler: str | None = None) -> Report:
    """Evaluate a classifier under a protocol; return the :class:`Report`.

    ``make_estimator()`` returns a fresh, unfitted estimator for each split; ``model``
    names it in the report (a kind's name, or what an experiment evaluates). With
    ``workers`` > 1 the splits are fitted in that many processes (worth it for
    networks, whose training is single-threaded), or on the Dask ``scheduler``; the
    result does not depend on it.
    """
    classes = classes or sorted(set(y))
    check_two_classes(y, "evaluation")
    classes = [c for c in classes if c in set(y)]
    folds = splits(protocol, y, groups, seed)
    tasks = ((clone(make_estimator()), X[train], y[train], X[test]) for train, test in folds)
    try:
        predictions = fit_predict_many(tasks, min(workers, len(folds)), progress, len(folds),
                                       scheduler=scheduler)
    except ValueError as err:
        raise InputError(f"cannot fit a split of {len(folds)}: {err}") from err
    true_all, pred_all, cluster_all = [], [], []
    split_acc, normalised = [], np.zeros((len(classes), len(classes)))
    sessions = np.arange(len(y)) if protocol == "thesis" or groups is None else groups
    for (_, test), pred in zip(folds, predictions, strict=True):
        counts = confusion(y[test], pred, classes)
        split_acc.append(float(np.trace(counts) / counts.sum()))
        rows = counts.sum(axis=1, keepdims=True)
        normalised += np.divide(counts, rows, out=np.zeros_like(counts, dtype=float),
                                where=rows > 0)
        true_all.append(y[test])
        pred_all.append(pred)
        cluster_all.append(sessions[test])
    y_true, y_pred = np.concatenate(true_all), np.concatenate(pred_all)
    clusters = np.concatenate(cluster_all)
    counts = confusion(y_true, y_pred, classes)
    point = metrics_from_confusion(counts)
    draws = _bootstrap(y_true, y_pred, clusters, classes, np.random.default_rng(seed))
    row_sums = normalised.sum(axis=1, keepdims=True)
    return Report(
        protocol=protocol, group_by=group_by if protocol == "group" else None, model=model,
        scheme=scheme, classes=classes, n_sessions=len(y), n_splits=len(folds),
        accuracy=_interval(point["accuracy"], draws["accuracy"]),
        balanced_accuracy=_interval(point["balanced_accuracy"], draws["balanced_accuracy"]),
        macro_f1=_interval(point["macro_f1"], draws["macro_f1"]),
        recall={c: _interval(point["recall"][i], draws["recall"][:, i])
                for i, c in enumerate(classes)},
        confusion_counts=counts.tolist(),
        confusion_normalised=np.divide(normalised, row_sums, out=np.zeros_like(normalised),
                                       where=row_sums > 0).tolist(),
        split_accuracy_mean=float(np.mean(split_acc)),
        split_accuracy_std=float(np.std(split_acc)),
        split_accuracies=split_acc,
        out_of_fold=_out_of_fold(folds, predictions, len(y)) if protocol == "group" else None)


def _out_of_fold(folds: list, predictions: list[np.ndarray], n: int) -> np.ndarray:
    """Return each session's prediction from the split that tested it."""
    out = np.empty(n, dtype=object)
    for (_, test), pred in zip(folds, predictions, strict=True):
        out[test] = pred
    return out


def report_markdown(report: Report) -> str:
    """Return a Markdown rendering of a report."""
    how = "25 random 80/20 splits" if report.protocol == "thesis" else \
        f"group protocol by {report.group_by} ({report.n_splits} splits)"
    lines = [f"**{report.model}**, scheme {report.scheme}, {report.n_sessions} sessions, {how}",
             "",
             "| metric | value [95 % CI] |", "|---|---|",
             f"| accuracy | {report.accuracy.text()} |",
             f"| balanced accuracy | {report.balanced_accuracy.text()} |",
             f"| macro-F1 | {report.macro_f1.text()} |",
             f"| accuracy over splits | {100 * report.split_accuracy_mean:.1f} ± "
             f"{100 * report.split_accuracy_std:.1f} % |"]
    lines += [f"| recall {c} | {iv.text()} |" for c, iv in report.recall.items()]
    lines += ["", "Confusion matrix (rows true, columns predicted; row-normalised):", "",
              "| true \\ predicted | " + " | ".join(report.classes) + " |",
              "|---|" + "---|" * len(report.classes)]
    for c, row in zip(report.classes, report.confusion_normalised, strict=True):
        lines.append(f"| {c} | " + " | ".join(f"{v:.2f}" for v in row) + " |")
    return "\n".join(lines) + "\n"
