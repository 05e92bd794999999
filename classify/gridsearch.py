"""The thesis's network grid search (section 5.2.2), over the executor seam.

A trial is one network configuration: depth and width multipliers, dropout, the
time steps of a window grid and its input timeseries. Every trial is evaluated under
the same protocol and seed, each split training with early stopping on its own
validation split, as one job of :func:`contactkit.util.parallel.map_ordered`: in
local processes or on a Dask cluster, with the same results in the same order. A
trial that fails is reported, not fatal.

The results table (Markdown and JSON) ranks the trials by balanced accuracy with
95 % cluster-bootstrap intervals; the best trial is trained on every session and
saved through the model registry (:func:`contactkit.classify.training.train`), so
``classify predict`` and ``replay --model`` use it as any other model file.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from contactkit.classify.data import FeatureSet
from contactkit.classify.evaluate import Report, evaluate
from contactkit.classify.grids import session_paths
from contactkit.classify.kind import ModelOptions
from contactkit.classify.names import NETWORKS, PROTOCOLS
from contactkit.classify.registry import get_kind
from contactkit.classify.schemes import check_scheme, scheme_classes
from contactkit.classify.training import TrainedModel, train, training_set
from contactkit.schemas import InputError
from contactkit.util.atomic import owned_result, write_text
from contactkit.util.parallel import map_ordered
from contactkit.util.progress import LabelledProgress


@dataclass(frozen=True)
class Trial:
    """One network configuration of the grid: layer and width multipliers, dropout,
    time steps of a window grid and its input timeseries."""

    depth: int
    width: float
    dropout: float
    steps: int
    inputs: tuple[str, ...]

    def label(self) -> str:
        """Return a short name, for example ``d2 w1 p0.1 s300 dq+tau+r``."""
        return (f"d{self.depth} w{self.width:g} p{self.dropout:g} s{self.steps} "
                + "+".join(self.inputs))


def grid_trials(depths: Sequence[int], widths: Sequence[float], dropouts: Sequence[float],
                steps: Sequence[int], inputs: Sequence[Sequence[str]]) -> list[Trial]:
    """Return every combination of the given values as trials (inputs varying slowest,
    then steps, so trials that share a grid are neighbours).

    Raises InputError on an empty list or a value outside its domain.
    """
    for name, values in (("depths", depths), ("widths", widths), ("dropouts", dropouts),
                         ("steps", steps), ("inputs", inputs)):
        if not values:
            raise InputError(f"the grid needs at least one value of {name}")
    if min(depths) < 1:
        raise InputError(f"depth must be at least 1, got {min(depths)}")
    if min(widths) <= 0:
        raise InputError(f"width must be positive, got {min(widths):g}")
    if not all(0 <= p < 1 for p in dropouts):
        raise InputError(f"dropout must be in [0, 1), got {max(dropouts):g}")
    if min(steps) < 4:
        raise InputError(f"steps must be at least 4, got {min(steps)}")
    return [Trial(int(d), float(w), float(p), int(s), tuple(i))
            for i, s, d, w, p in itertools.product(inputs, steps, depths, widths, dropouts)]


@dataclass(frozen=True)
class Protocol:
    """How every trial is trained and evaluated: network kind, evaluation protocol and
    grouping, class scheme, seed, most epochs, early-stopping patience [epochs],
    device, window method and window length [s]."""

    model: str = "lstm"
    protocol: str = "group"
    group_by: str = "pose"
    scheme: str = "full"
    seed: int = 0
    epochs: int = 100
    patience: int = 20
    device: str = "cpu"
    window: str = "planned"
    window_s: float = 0.5

    def options(self, trial: Trial) -> ModelOptions:
        """Return the model options of one trial under this protocol."""
        return ModelOptions(kind=self.model, timeseries=trial.inputs, window=self.window,
                            window_s=self.window_s, steps=trial.steps, seed=self.seed,
                            epochs=self.epochs, depth=trial.depth, width=trial.width,
                            dropout=trial.dropout, patience=self.patience,
                            device=self.device)

    def check(self) -> None:
        """Raise InputError now, before any data is read, for an unusable protocol."""
        if self.model not in NETWORKS:
            raise InputError(f"the grid search trains {' or '.join(NETWORKS)} networks, "
                             f"not {self.model!r}")
        if self.protocol not in PROTOCOLS:
            raise InputError(f"unknown protocol {self.protocol!r} (expected one of "
                             f"{', '.join(PROTOCOLS)})")
        check_scheme(self.scheme)
        get_kind(self.model).check_options(self.options(Trial(1, 1.0, 0.0, 20, ("q",))))


@dataclass
class TrialResult:
    """A trial and its evaluation report, or the problem that stopped it."""

    trial: Trial
    report: Report | None
    problem: str | None = None


def _trial_job(job: tuple[Trial, Protocol, FeatureSet | str]) -> TrialResult:
    """Evaluate one trial on its grids, or pass on the problem that kept the grids from
    being computed (a job of the executor)."""
    trial, protocol, data = job
    if isinstance(data, str):
        return TrialResult(trial, None, data)
    options = protocol.options(trial)
    template = get_kind(protocol.model).make(options, list(data.names))
    try:
        report = evaluate(data.X, data.labels(protocol.scheme), lambda: template,
                          protocol=protocol.protocol,
                          groups=data.groups(protocol.group_by)
                          if protocol.protocol == "group" else None,
                          group_by=protocol.group_by, model=protocol.model,
                          scheme=protocol.scheme, classes=scheme_classes(protocol.scheme),
                          seed=protocol.seed)
    except ValueError as err:
        return TrialResult(trial, None, str(err))
    report.out_of_fold = None
    return TrialResult(trial, report)


def run_trials(sources: Sequence[Path], trials: Sequence[Trial], protocol: Protocol, *,
               workers: int = 1, scheduler: str | None = None,
               progress: LabelledProgress | None = None,
               grids: Callable[[ModelOptions], FeatureSet] | None = None
               ) -> list[TrialResult]:
    """Evaluate every trial; return the results in the order of ``trials``.

    The grids of each distinct (inputs, steps) are computed once, when the first trial
    that needs them is submitted (by ``grids``, default the kind's input over
    ``sources`` with ``workers``); a trial whose grids cannot be computed is reported
    with the problem. Trials run as jobs on ``workers`` local processes or the Dask
    ``scheduler`` (default ``$CONTACTKIT_SCHEDULER``). ``progress(label, done, total)``
    reports grids and trials.
    """
    protocol.check()
    if not trials:
        raise InputError("the grid has no trials")
    kind = get_kind(protocol.model)
    for trial in trials:  # unknown inputs fail now, not once per trial
        kind.transformer(protocol.options(trial))

    if grids is None:
        session_paths(sources)  # a missing dataset fails now, not once per trial
    grids = grids or (lambda options: training_set(sources, options, workers=workers,
                                                   progress=progress).data)
    cache: dict[tuple, FeatureSet | str] = {}

    def jobs():
        for trial in trials:
            key = (trial.inputs, trial.steps)
            if key not in cache:
                try:
                    cache[key] = grids(protocol.options(trial))
                except InputError as err:
                    cache[key] = str(err)
            yield trial, protocol, cache[key]

    report = None if progress is None else (lambda d, t: progress("trials", d, t))
    return list(map_ordered(_trial_job, jobs(), workers=min(workers, len(trials)),
                            progress=report, total=len(trials), spawn=True, in_flight=1,
                            scheduler=scheduler))


def ranked(results: Sequence[TrialResult]) -> list[TrialResult]:
    """Return the successful results, best balanced accuracy first (ties: the smaller
    network first, by depth, then width, then dropout)."""
    good = [r for r in results if r.report is not None]
    return sorted(good, key=lambda r: (-r.report.balanced_accuracy.value, r.trial.depth,
                                       r.trial.width, r.trial.dropout))


def best_trial(results: Sequence[TrialResult]) -> Trial:
    """Return the best trial; raise InputError when every trial failed."""
    good = ranked(results)
    if not good:
        raise InputError("every trial of the grid search failed: "
                         + "; ".join(f"{r.trial.label()}: {r.problem}" for r in results))
    return good[0].trial


def results_markdown(results: Sequence[TrialResult], protocol: Protocol) -> str:
    """Return the ranked results table in Markdown, failed trials listed below it."""
    how = "25 random 80/20 splits" if protocol.protocol == "thesis" else \
        f"group protocol by {protocol.group_by}"
    lines = [f"# Grid search: {protocol.model}, {how}, seed {protocol.seed}", "",
             f"Scheme {protocol.scheme}; at most {protocol.epochs} epochs per training, "
             f"early stopping after {protocol.patience} without a better validation loss; "
             f"{protocol.window} window of {protocol.window_s:g} s; device "
             f"{protocol.device}.", "",
             "| rank | depth | width | dropout | steps | inputs | balanced accuracy "
             "[95 % CI] | accuracy [95 % CI] | macro-F1 [95 % CI] |",
             "|---|---|---|---|---|---|---|---|---|"]
    for rank, r in enumerate(ranked(results), 1):
        t, rep = r.trial, r.report
        lines.append(f"| {rank} | {t.depth} | {t.width:g} | {t.dropout:g} | {t.steps} | "
                     f"{'+'.join(t.inputs)} | {rep.balanced_accuracy.text()} | "
                     f"{rep.accuracy.text()} | {rep.macro_f1.text(percent=False)} |")
    failed = [r for r in results if r.report is None]
    if failed:
        lines += ["", "Failed trials:", ""]
        lines += [f"- {r.trial.label()}: {r.problem}" for r in failed]
    return "\n".join(lines) + "\n"


def results_json(results: Sequence[TrialResult], protocol: Protocol) -> dict:
    """Return the protocol and every trial with its report (or problem) as JSON values."""
    return {"protocol": asdict(protocol),
            "trials": [{"trial": {**asdict(r.trial), "inputs": list(r.trial.inputs)},
                        "report": None if r.report is None else r.report.as_dict(),
                        "problem": r.problem} for r in results]}


def write_results(out_dir: Path, results: Sequence[TrialResult], protocol: Protocol
                  ) -> tuple[Path, Path]:
    """Write ``gridsearch.md`` and ``gridsearch.json`` into ``out_dir``; return both paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    md, js = out_dir / "gridsearch.md", out_dir / "gridsearch.json"
    write_text(md, results_markdown(results, protocol), owned=owned_result)
    write_text(js, json.dumps(results_json(results, protocol), indent=1) + "\n",
               owned=owned_result)
    return md, js


def best_model_path(out_dir: Path, protocol: Protocol) -> Path:
    """Return where the best network is saved: ``best`` with its kind's file suffix."""
    return out_dir / f"best{get_kind(protocol.model).file_format.suffix}"


def train_best(sources: Sequence[Path], best: Trial, protocol: Protocol, out: Path, *,
               workers: int = 1, overwrite: bool = False,
               progress: LabelledProgress | None = None) -> TrainedModel:
    """Train the best trial's network on every session and save it through the model
    registry; return what was written."""
    return train(sources, out, protocol.options(best), scheme=protocol.scheme, workers=workers,
                 overwrite=overwrite, progress=progress)
