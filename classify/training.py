"""Training and evaluating any registered model kind on datasets: the library behind
``classify train`` and ``classify evaluate``, callable from a notebook.

Nothing here knows a kind by name: the kind (:mod:`contactkit.classify.kinds.registry`)
says which input it takes, how to build the estimator and how to save it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from contactkit.classify.data import GROUP_KEYS, FeatureSet
from contactkit.classify.evaluate import Report, evaluate
from contactkit.classify.kinds.kind import ModelKind, ModelOptions
from contactkit.classify.kinds.registry import get_kind
from contactkit.classify.modelfile.model_file import save_model
from contactkit.classify.names import PROTOCOLS
from contactkit.classify.schemes import check_scheme, check_two_classes, scheme_classes
from contactkit.errors import check_choice
from contactkit.robots.dynamics import ArmDynamics
from contactkit.robots.registry import canonical_robot_name
from contactkit.schemas import InputError
from contactkit.schemas.dataset import session_files
from contactkit.schemas.session import read_session_meta
from contactkit.util.atomic import check_target
from contactkit.util.progress import LabelledProgress


@dataclass
class TrainingSet:
    """A kind, its configured input transformer and the data it turned the datasets into."""

    kind: ModelKind
    transformer: object
    data: FeatureSet


def training_set(datasets: Sequence[Path], options: ModelOptions, *, workers: int = 1,
                 limited: bool = False, progress: LabelledProgress | None = None,
                 scheduler: str | None = None,
                 dynamics: ArmDynamics | None = None) -> TrainingSet:
    """Check ``options`` for their kind, then compute (or read from the dataset cache)
    the kind's input for every session of ``datasets`` (in ``workers`` processes or on
    the Dask ``scheduler``); sessions that fail are listed in ``data.problems``.
    ``limited`` keeps the limited context only. ``dynamics`` (``--dynamics``) are the
    arm's identified dynamics the chain uses for every session (None: those each
    session carries, else the nominal model)."""
    kind = get_kind(options.kind)
    options = kind.check_options(options)
    transformer = kind.transformer(options)
    if dynamics is not None:
        transformer.dynamics = dynamics  # type: ignore[attr-defined]  # both inputs take them
    report = None if progress is None else (
        lambda done, total: progress(f"{kind.input.name} of sessions", done, total))
    data = kind.input.load([Path(d) for d in datasets], transformer, workers, report,
                           scheduler=scheduler)
    return TrainingSet(kind, transformer, data.limited() if limited else data)


@dataclass
class TrainedModel:
    """What :func:`train` wrote: the file, the kind, sessions used, classes, skipped files."""

    path: Path
    kind: str
    sessions: int
    classes: list[str]
    problems: list[tuple[str, str]]


def trained_robots(datasets: Sequence[Path], robot: str | None = None,
                   used: set[str] | None = None) -> list[str] | None:
    """Return the arms (registry names, sorted) whose models computed the features of
    the sessions in ``datasets`` (those whose file names are in ``used``, None: all):
    ``robot`` where the features name one, else each session's own, read from the
    session files' footers. None when a dataset is a feature table, which does not say
    which arms its sessions come from. A session whose metadata cannot be read is left
    out (training lists it as a problem)."""
    if robot is not None:
        return [canonical_robot_name(robot)]
    robots = set()
    for source in datasets:
        if not Path(source).is_dir():
            return None
        for path in session_files(source):
            if used is not None and path.name not in used:
                continue
            try:
                robots.add(canonical_robot_name(read_session_meta(path)[0].robot))
            except InputError:
                continue
    return sorted(robots)


def train(datasets: Sequence[Path], out: Path, options: ModelOptions, *, scheme: str = "full",
          limited: bool = False, workers: int = 1, overwrite: bool = False,
          progress: LabelledProgress | None = None, detector: dict | None = None,
          events: tuple[object, dict] | None = None,
          scheduler: str | None = None, dynamics: ArmDynamics | None = None) -> TrainedModel:
    """Train a model of ``options.kind`` on every session of ``datasets`` and save it to
    ``out`` in the kind's file format; return what was written. ``detector`` and
    ``events`` (a contact detector's settings, an event classifier with its settings)
    travel in the model file (see :func:`contactkit.classify.modelfile.model_file.save_model`). The
    input is computed in ``workers`` processes or on the Dask ``scheduler``, with the
    identified ``dynamics`` when given (see :func:`training_set`; the model file names
    their checksum, it does not carry them)."""
    check_scheme(scheme)
    out = Path(out)
    check_target(out, overwrite=overwrite)
    kind = get_kind(options.kind)
    if out.suffix.lower() != kind.file_format.suffix:
        raise InputError(f"a {kind.name} model is saved as {kind.file_format.name}: the file "
                         f"name must end in {kind.file_format.suffix}", out)
    options = kind.check_options(options)
    found = training_set(datasets, options, workers=workers, limited=limited,
                         progress=progress, scheduler=scheduler, dynamics=dynamics)
    vars(found.transformer).pop("dynamics", None)  # not stored: each use gives its own
    data = found.data
    labels = data.labels(scheme)
    check_two_classes(labels, "training")
    estimator = kind.estimator(options, data.names)
    estimator.fit(data.X, labels)
    classes = [str(c) for c in estimator.classes_]
    training = {"datasets": [str(d) for d in datasets], "limited": limited,
                "sessions": len(data), "options": asdict(options),
                "epochs": getattr(estimator, "n_epochs_", None),
                "robots": trained_robots(datasets, getattr(found.transformer, "robot", None),
                                         set(data.info["file"])),
                "dynamics": None if dynamics is None else dynamics.checksum}
    path = save_model(out, estimator, kind=kind, transformer=found.transformer,
                      feature_names=list(data.names), classes=classes, scheme=scheme,
                      fingerprint=data.fingerprint(), training=training,
                      sample_shape=tuple(data.X.shape[1:]), overwrite=overwrite,
                      detector=detector, events=events)
    return TrainedModel(path, kind.name, len(data), classes, list(data.problems))


def evaluate_kind(datasets: Sequence[Path], options: ModelOptions, *, protocol: str = "group",
                  group: str = "pose", scheme: str = "full", limited: bool = False,
                  workers: int = 1, progress: LabelledProgress | None = None,
                  scheduler: str | None = None, dynamics: ArmDynamics | None = None
                  ) -> tuple[Report, list[tuple[str, str]]]:
    """Evaluate ``options.kind`` on ``datasets`` under a protocol (see
    :mod:`contactkit.classify.evaluate`), in ``workers`` processes or on the Dask
    ``scheduler``, with the identified ``dynamics`` when given (see
    :func:`training_set`); return the report and the skipped files."""
    check_scheme(scheme)
    check_choice("protocol", protocol, PROTOCOLS)
    check_choice("grouping", group, GROUP_KEYS)
    found = training_set(datasets, options, workers=workers, limited=limited,
                         progress=progress, scheduler=scheduler, dynamics=dynamics)
    data, kind = found.data, found.kind
    template = kind.estimator(options, data.names)
    report = None if progress is None else (
        lambda done, total: progress(f"{protocol} protocol splits", done, total))
    result = evaluate(data.X, data.labels(scheme), lambda: template, protocol=protocol,
                      groups=data.groups(group) if protocol == "group" else None,
                      group_by=group, model=kind.name, scheme=scheme,
                      classes=scheme_classes(scheme), seed=options.seed,
                      workers=workers if kind.parallel_fits else 1, progress=report,
                      scheduler=scheduler if kind.parallel_fits else None)
    return result, list(data.problems)
