"""The thesis's network grid search (section 5.2.2), over the executor seam.

A trial is one configuration of a kind that declares a search grid on some of its
parameters (the thesis's networks: depth and width multipliers, dropout), with the
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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, cast

from contactkit.classify.data import FeatureSet
from contactkit.classify.evaluate import Report, evaluate
from contactkit.classify.grids import session_paths
from contactkit.classify.kinds.kind import ModelKind, ModelOptions
from contactkit.classify.kinds.registry import DEFAULT_SEARCHED, get_kind, searchable_kinds
from contactkit.classify.names import PROTOCOLS
from contactkit.classify.schemes import check_scheme, scheme_classes
from contactkit.classify.training import TrainedModel, train, training_set
from contactkit.errors import check_choice
from contactkit.schemas import InputError
from contactkit.util.atomic import write_text
from contactkit.util.owned import owned_result, result_json, result_markdown
from contactkit.util.parallel import map_ordered, resolve_scheduler
from contactkit.util.progress import LabelledProgress

MIN_STEPS = 4
"""The fewest time steps a grid may have."""


@dataclass(frozen=True)
class Trial:
    """One configuration of the grid: the searched parameters' values (in the kind's
    declaration order), the time steps of a window grid and its input timeseries."""

    params: tuple[tuple[str, Any], ...]
    steps: int
    inputs: tuple[str, ...]

    def label(self) -> str:
        """Return a short name, for example ``depth=2 width=1 dropout=0.1 steps=300
        dq+tau+r``."""
        return " ".join([*(f"{name}={_text(value)}" for name, value in self.params),
                         f"steps={self.steps}", "+".join(self.inputs)])


def _text(value: Any) -> str:
    """Return a parameter value as a table shows it (numbers without trailing zeros)."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def searched_params(kind: ModelKind) -> list[str]:
    """Return the names of the parameters of ``kind`` that declare a search grid."""
    return [p.name for p in kind.params if p.grid]


def grid_trials(kind: ModelKind, grid: Mapping[str, Sequence], steps: Sequence[int],
                inputs: Sequence[Sequence[str]]) -> list[Trial]:
    """Return every combination of the given values as trials (inputs varying slowest,
    then steps, then the parameters in ``kind``'s declaration order, so trials that
    share a grid are neighbours). ``grid`` maps some of the kind's searched parameters to
    the values to try; the others take their declared grid.

    Raises InputError on an empty list, a parameter ``kind`` does not search, or a value
    its declaration refuses.
    """
    declared = {p.name: p for p in kind.params if p.grid}
    unknown = sorted(set(grid) - set(declared))
    if unknown:
        raise InputError(f"model {kind.name!r} searches no parameter {unknown[0]!r} (it "
                         f"searches {', '.join(declared) or 'none'})")
    values = {name: list(grid.get(name, p.grid)) for name, p in declared.items()}
    for name, given in (*values.items(), ("steps", steps), ("inputs", inputs)):
        if not given:
            raise InputError(f"the grid needs at least one value of {name}")
    values = {name: [declared[name].check(v, f"model {kind.name!r}") for v in given]
              for name, given in values.items()}
    if min(steps) < MIN_STEPS:
        raise InputError(f"steps must be at least {MIN_STEPS}, got {min(steps)}")
    names = list(values)
    return [Trial(tuple(zip(names, combo, strict=True)), int(s), tuple(i))
            for i, s, *combo in itertools.product(inputs, steps, *values.values())]


@dataclass(frozen=True)
class Protocol:
    """How every trial is trained and evaluated: the kind, evaluation protocol and
    grouping, class scheme, seed, the kind's parameters every trial shares (``params``,
    e.g. epochs, early-stopping patience and device; the others take their declared
    defaults), window method and window length [s]."""

    model: str = DEFAULT_SEARCHED
    protocol: str = "group"
    group_by: str = "pose"
    scheme: str = "full"
    seed: int = 0
    params: Mapping[str, Any] = field(default_factory=dict)
    window: str = "planned"
    window_s: float = 0.5

    def options(self, trial: Trial) -> ModelOptions:
        """Return the model options of one trial under this protocol."""
        return ModelOptions(kind=self.model, timeseries=trial.inputs, window=self.window,
                            window_s=self.window_s, steps=trial.steps, seed=self.seed,
                            params={**self.params, **dict(trial.params)})

    def shared_params(self) -> dict[str, Any]:
        """Return the value of every parameter of the kind that the grid does not vary."""
        kind = get_kind(self.model)
        checked = kind.check_options(self.options(Trial((), 20, ("q",)))).params
        return {k: v for k, v in checked.items() if k not in searched_params(kind)}

    def check(self) -> None:
        """Raise InputError now, before any data is read, for an unusable protocol."""
        searchable = searchable_kinds()
        if self.model not in searchable:
            raise InputError(f"the grid search trains {' or '.join(searchable)} (the kinds "
                             f"that declare a parameter grid), not {self.model!r}")
        check_choice("protocol", self.protocol, PROTOCOLS)
        check_scheme(self.scheme)
        self.shared_params()


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
    template = get_kind(protocol.model).estimator(options, data.names)
    try:
        report = evaluate(data.X, data.labels(protocol.scheme), lambda: template,
                          protocol=protocol.protocol, model=protocol.model,
                          groups=data.groups(protocol.group_by)
                          if protocol.protocol == "group" else None,
                          group_by=protocol.group_by, scheme=protocol.scheme,
                          classes=scheme_classes(protocol.scheme), seed=protocol.seed)
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
    ``scheduler``. ``progress(label, done, total)`` reports grids and trials.
    """
    # The GPUs of a cluster are its workers' business: this process checks, and computes
    # the grids, as if on the CPU (the device does not change the grids).
    on_cluster = resolve_scheduler(scheduler) is not None and "device" in protocol.params
    here = replace(protocol, params={**protocol.params, "device": "cpu"}) if on_cluster \
        else protocol
    here.check()
    if not trials:
        raise InputError("the grid has no trials")
    kind = get_kind(protocol.model)
    for trial in trials:  # unknown inputs fail now, not once per trial
        kind.transformer(protocol.options(trial))

    if grids is None:
        session_paths(sources)  # a missing dataset fails now, not once per trial
    grids = grids or (lambda options: training_set(sources, options, workers=workers,
                                                   progress=progress,
                                                   scheduler=scheduler).data)
    cache: dict[tuple, FeatureSet | str] = {}

    def jobs():
        for trial in trials:
            key = (trial.inputs, trial.steps)
            if key not in cache:
                try:
                    cache[key] = grids(here.options(trial))
                except InputError as err:
                    cache[key] = str(err)
            yield trial, protocol, cache[key]

    report = None if progress is None else (lambda d, t: progress("trials", d, t))
    return list(map_ordered(_trial_job, jobs(), workers=min(workers, len(trials)),
                            progress=report, total=len(trials), spawn=True, in_flight=1,
                            scheduler=scheduler))


def ranked(results: Sequence[TrialResult]) -> list[TrialResult]:
    """Return the successful results, best balanced accuracy first (ties: the smaller
    values of the searched parameters first, in declaration order: for the networks the
    smaller network)."""
    good = [r for r in results if r.report is not None]
    return sorted(good, key=lambda r: (-cast(Report, r.report).balanced_accuracy.value,
                                       *(value for _, value in r.trial.params)))


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
    searched = searched_params(get_kind(protocol.model))
    shared = ", ".join(f"{k} {_text(v)}" for k, v in protocol.shared_params().items())
    lines = [f"# Grid search: {protocol.model}, {how}, seed {protocol.seed}", "",
             f"Scheme {protocol.scheme}; every trial with {shared or 'no other parameter'}; "
             f"{protocol.window} window of {protocol.window_s:g} s.", "",
             f"| rank | {' | '.join(searched)} | steps | inputs | balanced accuracy "
             "[95 % CI] | accuracy [95 % CI] | macro-F1 [95 % CI] |",
             "|---|" + "---|" * (len(searched) + 5)]
    for rank, r in enumerate(ranked(results), 1):
        t, rep = r.trial, r.report
        assert rep is not None  # ranked keeps the successful results
        values = "".join(f"{_text(v)} | " for _, v in t.params)
        lines.append(f"| {rank} | {values}{t.steps} | "
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
            "trials": [{"trial": {"params": dict(r.trial.params), "steps": r.trial.steps,
                                  "inputs": list(r.trial.inputs)},
                        "report": None if r.report is None else r.report.as_dict(),
                        "problem": r.problem} for r in results]}


RESULTS_MD, RESULTS_JSON = "gridsearch.md", "gridsearch.json"
"""The names of the grid search's result files in its output directory."""


def write_results(out_dir: Path, results: Sequence[TrialResult], protocol: Protocol
                  ) -> tuple[Path, Path]:
    """Write ``gridsearch.md`` and ``gridsearch.json`` into ``out_dir``; return both paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    md, js = out_dir / RESULTS_MD, out_dir / RESULTS_JSON
    write_text(md, result_markdown(results_markdown(results, protocol)), owned=owned_result)
    write_text(js, json.dumps(result_json(results_json(results, protocol)), indent=1) + "\n",
               owned=owned_result)
    return md, js


def best_model_path(out_dir: Path, protocol: Protocol) -> Path:
    """Return where the best network is saved: ``best`` with its kind's file suffix."""
    return out_dir / f"best{get_kind(protocol.model).file_format.suffix}"


def train_best(sources: Sequence[Path], best: Trial, protocol: Protocol, out: Path, *,
               workers: int = 1, overwrite: bool = False,
               progress: LabelledProgress | None = None,
               scheduler: str | None = None) -> TrainedModel:
    """Train the best trial's network on every session (its input computed in
    ``workers`` processes or on the Dask ``scheduler``) and save it through the model
    registry; return what was written."""
    return train(sources, out, protocol.options(best), scheme=protocol.scheme, workers=workers,
                 overwrite=overwrite, progress=progress, scheduler=scheduler)
