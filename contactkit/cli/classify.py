"""The ``classify`` command: features, training, evaluation, prediction, experiments.

A thin layer over the library (:mod:`contactkit.classify.training`,
:mod:`contactkit.classify.prediction`, :mod:`contactkit.classify.experiments.thesis`): it parses
options, draws progress bars and prints results.
"""

from __future__ import annotations

import json
import math
import sys
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeAlias, overload

import typer

from contactkit.classify.kinds.devices import DEVICES
from contactkit.classify.kinds.kind import SEED, ModelOptions
from contactkit.classify.kinds.registry import (
    DEFAULT_KIND,
    DEFAULT_SEARCHED,
    get_kind,
    kind_names,
    searchable_kinds,
)
from contactkit.classify.names import EXPERIMENTS, GROUP_KEYS, PROTOCOLS
from contactkit.classify.schemes import SCHEMES
from contactkit.cli.common import (
    DynamicsOpt,
    RobotOpt,
    beyond_range_text,
    exit_if_failed,
    load_dynamics_option,
    new_app,
    print_problems,
    run_app,
    scheduler_of,
)
from contactkit.cli.flags import command_with_flags, owner_values, shared_flags
from contactkit.features.detector import (
    DetectorConfig,
    dynamics_detector,
    load_calibration,
    save_calibration,
)
from contactkit.features.names import ALL_TIMESERIES, GROUPS
from contactkit.features.scalars import SCALARS
from contactkit.features.windows import METHODS
from contactkit.schemas import InputError
from contactkit.schemas.dataset import source_sessions
from contactkit.util.atomic import check_target, write_text
from contactkit.util.owned import check_results
from contactkit.util.parallel import available_cpus
from contactkit.util.params import Param
from contactkit.util.progress import bar_callback, err_console, labelled_progress, progress_bar
from contactkit.util.text import printable

if TYPE_CHECKING:
    from contactkit.robots.dynamics import ArmDynamics, RobotChoice

# The commands import the library (scikit-learn, skops, the chain, torch for networks)
# inside their functions: `classify --help` loads none of it (tests/cli/test_startup.py).

app = new_app("classify", help="Turn sessions into features and contact predictions.",
              root_options=True)
DEFAULT_WORKERS = available_cpus()


def _choices(name: str, values) -> type[Enum]:
    return Enum(name, {v: v for v in values}, type=str)  # type: ignore[return-value]


if TYPE_CHECKING:  # the choices are known at run time: a member of any for the checker
    Kind: TypeAlias = Any
    Scheme: TypeAlias = Any
    Protocol: TypeAlias = Any
    Group: TypeAlias = Any
    Method: TypeAlias = Any
    Experiment: TypeAlias = Any
    Device: TypeAlias = Any
    Network: TypeAlias = Any
else:
    Kind = _choices("Kind", kind_names())
    Scheme = _choices("Scheme", SCHEMES)
    Protocol = _choices("Protocol", PROTOCOLS)
    Group = _choices("Group", GROUP_KEYS)
    Method = _choices("Method", METHODS)
    Experiment = _choices("Experiment", (*EXPERIMENTS, "augmentation"))
    Device = _choices("Device", DEVICES)
    Network = _choices("Network", searchable_kinds())


@overload
def _split(value: str) -> tuple[str, ...]: ...


@overload
def _split(value: None) -> None: ...


def _split(value: str | None) -> tuple[str, ...] | None:
    return None if value is None else tuple(v.strip() for v in value.split(",") if v.strip())


def _refuse_existing(out: Path, overwrite: bool) -> None:
    """Refuse an existing ``out`` without ``--overwrite`` (a directory that does not
    exist yet holds nothing to refuse; commands that write results create it)."""
    if out.parent.is_dir():
        check_target(out, overwrite=overwrite)


@app.command("features")
def features_command(
    ctx: typer.Context,
    source: Annotated[Path, typer.Argument(help="A session file or a dataset directory.")],
    out: Annotated[Path, typer.Option(help="Output Parquet file.")],
    timeseries: Annotated[str, typer.Option(
        help=f"Comma-separated timeseries features or groups ({', '.join(GROUPS)}; "
             f"{', '.join(ALL_TIMESERIES)}).")] = "dq,tau,r",
    window: Annotated[Method, typer.Option(help="Window method.")] = "difference",
    window_s: Annotated[float, typer.Option(help="Window length [s].")] = 0.5,
    scalars: Annotated[str, typer.Option(
        help=f"Comma-separated scalar features: {', '.join(SCALARS)}.")] = "range",
    per_sample: Annotated[bool, typer.Option(
        help="Write every timeseries feature of every sample instead (r_1..r_7, g_*, "
             "tau_inv_*, ddq_*, p_int_*, p_ext_*, f_x.. m_norm).")] = False,
    workers: Annotated[int, typer.Option(help="Parallel processes.")] = DEFAULT_WORKERS,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output file.")] = False,
    robot: RobotOpt = None,
    dynamics: DynamicsOpt = None,
) -> None:
    """Compute features of a session or dataset: one row per session (scalar features
    of the interaction window), or with --per-sample one row per sample."""
    from contactkit.features.extract import SessionFeatures, feature_rows
    from contactkit.features.per_sample import write_per_sample_table
    from contactkit.features.timeseries import ChainConfig
    from contactkit.schemas.features import write_feature_table

    files = source_sessions([source])
    _refuse_existing(out, overwrite)
    identified = load_dynamics_option(dynamics)
    with progress_bar("per-sample features" if per_sample else "features") as bar:
        progress = bar_callback(bar, "sessions")
        if per_sample:
            _, problems = write_per_sample_table(files, out, progress,
                                                 ChainConfig(robot=robot, dynamics=identified),
                                                 overwrite=overwrite)
            print_problems(problems)
            print(printable(out))
            exit_if_failed(problems)
            return
        extractor = SessionFeatures(timeseries=list(_split(timeseries)), scalars=list(
            _split(scalars)), window=Method(window).value, window_s=window_s,
            robot=robot).fit(None)
        extractor.dynamics = identified
        result = feature_rows(files, extractor, workers, progress,
                              scheduler=scheduler_of(ctx))
    print_problems(result.problems)
    if not len(result):
        raise InputError("no session could be processed", source)
    write_feature_table(out, result.table(extractor.config()), overwrite=overwrite)
    err_console.print(f"{len(result)} sessions x {len(result.names)} features")
    print(printable(out))
    exit_if_failed(result.problems)


ModelOpt = Annotated[Kind, typer.Option(help="Classifier (networks need the nn extra).")]
FeaturesOpt = Annotated[str | None, typer.Option(
    "--features", help="Timeseries features (comma-separated, or groups sensor, model, "
                       "workspace): their scalar features feed an SVM, their raw window a "
                       "network (default dq,tau,r; q,dq,tau for cnn and minirocket).")]
ScalarsOpt = Annotated[str, typer.Option(help=f"Scalar features: {', '.join(SCALARS)}.")]
WindowOpt = Annotated[Method | None, typer.Option(
    help="Window method (default difference; planned for networks).")]
WindowSOpt = Annotated[float, typer.Option(help="Window length [s].")]
SchemeOpt = Annotated[Scheme, typer.Option(help="Class scheme.")]
LimitedOpt = Annotated[bool, typer.Option(
    help="Limited context: drop shove from static and adjust from dynamic.")]
COpt = Annotated[float, typer.Option("--C", help="SVM regularisation C.")]
SeedOpt = Annotated[int, typer.Option(help=SEED.help)]
WorkersOpt = Annotated[int, typer.Option(
    help="Parallel processes for features (and, for networks, for evaluation splits).")]
StepsOpt = Annotated[int, typer.Option(help="Networks: time steps of a window grid.")]
DatasetsArg = Annotated[list[Path], typer.Argument(
    help="Dataset directories (or feature tables from `classify features`); several are "
         "combined, e.g. a static and a dynamic set.")]
MODEL_OPTIONS = {"--out", "--model", "--features", "--scalars", "--window", "--window-s",
                 "--scheme", "--limited", "--no-limited", "--seed", "--workers", "--overwrite",
                 "--no-overwrite", "--steps", "--protocol", "--group", "--json", "--dynamics",
                 "--help"}
"""The options of train and evaluate themselves, which no kind's parameter may take."""
KIND_FLAGS, _ = shared_flags({name: get_kind(name).params for name in kind_names()},
                             MODEL_OPTIONS, what="models")
"""Every kind's parameters as options of train and evaluate (a kind whose parameter
clashes with a command's option or another kind's of another type gets none)."""


def _options(ctx: typer.Context, model: str, features: str | None, scalars: str,
             window: str | None, window_s: float, seed: int, steps: int) -> ModelOptions:
    """Return the model options of the command line, the kind's parameters among them
    (from its generated options, ``ctx.meta["params"]``), checked for their kind before
    any data is read (or a progress bar drawn)."""
    kind = get_kind(Kind(model).value)
    options = ModelOptions(
        kind=kind.name, timeseries=_split(features), scalars=_split(scalars),
        window=None if window is None else Method(window).value, window_s=window_s,
        steps=steps, seed=seed,
        params=owner_values(KIND_FLAGS, ctx.meta["params"], kind.name, "model"))
    return kind.check_options(options)


@command_with_flags(app, "train", list(KIND_FLAGS.values()), key="params")
def train_command(
    ctx: typer.Context,
    datasets: DatasetsArg,
    out: Annotated[Path, typer.Option(
        help="Model file to write: .skops (SVMs, MiniRocket) or .onnx (CNN, LSTM).")],
    model: ModelOpt = DEFAULT_KIND, features: FeaturesOpt = None,
    scalars: ScalarsOpt = "range", window: WindowOpt = None, window_s: WindowSOpt = 0.5,
    scheme: SchemeOpt = "full", limited: LimitedOpt = False, seed: SeedOpt = 0,
    workers: WorkersOpt = DEFAULT_WORKERS,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing model file.")] = False,
    steps: StepsOpt = 300,
    dynamics: DynamicsOpt = None,
) -> None:
    """Train a classifier on every session of the datasets and save it as a safe model file
    (.skops; a CNN or LSTM as .onnx). The model's own parameters are the options after
    --dynamics (each names the models that take it). Each session's features come from
    the identified dynamics it carries (recorder set-robot --dynamics), unless --dynamics
    gives others for all."""
    from contactkit.classify.training import train

    _refuse_existing(out, overwrite)
    options = _options(ctx, model, features, scalars, window, window_s, seed, steps)
    identified = load_dynamics_option(dynamics)
    with progress_bar("train") as bar:
        trained = train(datasets, out, options, scheme=Scheme(scheme).value, limited=limited,
                        workers=workers, overwrite=overwrite, progress=labelled_progress(bar),
                        scheduler=scheduler_of(ctx), dynamics=identified)
    print_problems(trained.problems)
    err_console.print(f"trained {trained.kind} on {trained.sessions} sessions, classes "
                      f"{', '.join(trained.classes)}")
    print(printable(trained.path))
    exit_if_failed(trained.problems)


@command_with_flags(app, "evaluate", list(KIND_FLAGS.values()), key="params")
def evaluate_command(
    ctx: typer.Context,
    datasets: DatasetsArg,
    protocol: Annotated[Protocol, typer.Option(
        help="thesis: 25 random 80/20 splits; group: no group on both sides of a split.")
                        ] = "group",
    group: Annotated[Group, typer.Option(help="Grouping for the group protocol.")] = "pose",
    model: ModelOpt = DEFAULT_KIND, features: FeaturesOpt = None,
    scalars: ScalarsOpt = "range", window: WindowOpt = None, window_s: WindowSOpt = 0.5,
    scheme: SchemeOpt = "full", limited: LimitedOpt = False, seed: SeedOpt = 0,
    workers: WorkersOpt = DEFAULT_WORKERS,
    json_out: Annotated[Path | None, typer.Option(
        "--json", help="Also write the report as JSON.")] = None,
    steps: StepsOpt = 300,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing --json file.")] = False,
    dynamics: DynamicsOpt = None,
) -> None:
    """Evaluate a classifier honestly and print accuracy, balanced accuracy, macro-F1,
    per-class recall with 95 % confidence intervals, and the confusion matrix. The
    model's own parameters are the options after --dynamics (each names the models
    that take it). Each session's features come from the identified dynamics it
    carries (recorder set-robot --dynamics), unless --dynamics gives others for all."""
    from contactkit.classify.evaluate import report_markdown
    from contactkit.classify.training import evaluate_kind

    if json_out is not None:
        check_target(json_out, overwrite=overwrite)
    options = _options(ctx, model, features, scalars, window, window_s, seed, steps)
    identified = load_dynamics_option(dynamics)
    with progress_bar("evaluate") as bar:
        report, problems = evaluate_kind(
            datasets, options, protocol=Protocol(protocol).value, group=Group(group).value,
            scheme=Scheme(scheme).value, limited=limited, workers=workers,
            progress=labelled_progress(bar), scheduler=scheduler_of(ctx),
            dynamics=identified)
    print_problems(problems)
    print(report_markdown(report))
    if json_out is not None:
        write_text(json_out, json.dumps(report.as_dict(), indent=2), overwrite=overwrite)
    exit_if_failed(problems)


@app.command("predict")
def predict_command(
    model_path: Annotated[Path, typer.Argument(metavar="MODEL", help="Model file.")],
    sessions: Annotated[list[Path], typer.Argument(
        help="Session files or directories, or a feature table.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON lines.")] = False,
    events: Annotated[bool, typer.Option(
        "--events", help="Report contact events (detect, decide, hold) instead of one "
                         "label per session.")] = False,
    calibration: Annotated[Path | None, typer.Option(
        help="Contact detector calibration (overrides the model's detector).")] = None,
    decide_after: Annotated[float | None, typer.Option(
        help="Time after onset at which an event's intent is decided [s] (default: "
             "the model's); a weak contact waits for the model's later delay.")] = None,
    identify: Annotated[bool | None, typer.Option(
        "--identify/--no-identify",
        help="With --events: identify the arm from these sessions themselves first, "
             "cross-fitted (the sessions of half the poses are scored with the arm "
             "identified from the other half, around the contacts the model's detector "
             "finds; labels are never read). Default: so when no --dynamics or "
             "--calibration is given, no session carries identified dynamics, and each "
             "half holds at least a minute of motion (a moving arm's dataset); "
             "--no-identify: the arm's nominal model.")] = None,
    robot: RobotOpt = None,
    dynamics: DynamicsOpt = None,
    workers: Annotated[int, typer.Option(
        help="With --events: parallel processes that score the sessions (and identify "
             "the two halves of a moving arm's dataset at once).")] = DEFAULT_WORKERS,
) -> None:
    """Predict the contact class of sessions with a trained model, or (--events) the
    contact events the model's detector finds and the intent decided for each. With
    --dynamics, the detector thresholds stored in the dynamics file are used unless
    --calibration is given. A moving arm's dataset is scored with its arm identified
    from itself (see --identify), which finds light touches the nominal model's error
    hides; a line on stderr says so."""
    from contactkit.classify.modelfile.model_file import load_model
    from contactkit.classify.prediction import predict_sources
    from contactkit.robots.dynamics import arm_override

    if identify is not None and not events:
        raise InputError("--identify/--no-identify is for --events")
    if identify and (dynamics is not None or calibration is not None):
        raise InputError("--identify identifies the arm from the sessions themselves: "
                         "give it without --dynamics and --calibration")
    model = load_model(model_path, lazy=True)
    identified = load_dynamics_option(dynamics)
    arm = arm_override(robot, identified)
    if events or calibration is not None:
        detector = (load_calibration(calibration) if calibration is not None
                    else dynamics_detector(identified))
        if detector is None and model.detector_config() is None:
            raise InputError("model carries no contact detector; give --calibration",
                             model_path)
        paths = source_sessions(sessions)
        own = {} if identify is False or dynamics is not None or calibration is not None \
            else _self_identified(model, paths, robot, forced=bool(identify),
                                  workers=workers)
        event_problems = _print_events(model, paths, detector, decide_after, as_json, arm,
                                       own, workers)
        print_problems(event_problems)
        exit_if_failed(event_problems)
        return
    predictions, problems = predict_sources(model, sessions, arm)
    print_problems(problems)
    if not predictions:
        raise InputError("nothing to predict")
    for p in predictions:
        if as_json:
            print(json.dumps({"session": p.source, "predicted": p.predicted,
                              "true": p.recorded, "probabilities":
                              {c: round(v, 4) for c, v in p.probabilities.items()}}))
        else:
            probs = " ".join(f"{c}={v:.2f}" for c, v in p.probabilities.items())
            print(f"{printable(p.source)}: {p.predicted} ({probs}; recorded action "
                  f"{p.recorded})")
    exit_if_failed(problems)


def _self_identified(model, paths: list[Path], robot: str | None, forced: bool,
                     workers: int = 1) -> dict[Path, ArmDynamics]:
    """Return the arm each session of ``paths`` is scored with when the sessions
    identify their own arm (cross-fitted, :mod:`contactkit.features.self_identification`):
    always when ``forced`` (InputError when they cannot), else when they are a moving
    arm's dataset, falling back to the nominal model with a line on stderr when the
    identification fails. Empty: the nominal model (or what each session carries)."""
    from contactkit.features.self_identification import (
        cross_fitted_dynamics,
        dynamics_by_session,
        moving_dataset,
        survey,
    )

    surveyed = survey(paths)
    if not forced and moving_dataset(surveyed) is not None:
        return {}
    finder = model.detector_config()
    if finder is None:
        if forced:
            raise InputError("the model carries no contact detector to find the contacts "
                             "to identify around")
        return {}
    motion = sum(s.motion_s for s in surveyed)
    err_console.print(f"Identifying the arm from these {len(surveyed)} sessions "
                      f"({motion:.0f} s of motion), cross-fitted over two halves of their "
                      "poses (--no-identify: the nominal model).")
    try:
        with progress_bar() as bar:
            folds = cross_fitted_dynamics(surveyed, finder, robot, labelled_progress(bar),
                                          workers=workers)
    except InputError as err:
        if forced:
            raise
        err_console.print(f"Not identified ({err.problem}): the nominal model is used.")
        return {}
    for k, fold in enumerate(folds, 1):
        report = fold.identified.excitation
        err_console.print(
            f"  half {k} ({len(fold.scored)} sessions) scored with the arm identified from "
            f"the other: {len(report.determined)} parameters determined; residual RMS "
            f"[Nm] nominal {[round(v, 2) for v in report.rms_before_nm]}, identified "
            f"{[round(v, 2) for v in report.rms_after_nm]}")
    return dynamics_by_session(folds)


def _print_events(model, paths: list[Path], detector: DetectorConfig | None,
                  decide_after: float | None, as_json: bool, robot: RobotChoice,
                  own: dict[Path, ArmDynamics], workers: int) -> list[tuple[str, str]]:
    """Print the contact events of each session of ``paths``
    (:func:`~contactkit.classify.prediction.predict_events`, ``workers`` processes), in
    order; return the sessions that failed as ``(path, problem)``."""
    from contactkit.classify.events.listener import contact_text
    from contactkit.classify.prediction import predict_events

    problems = []
    for path, found, problem in predict_events(model, paths, detector, decide_after, robot,
                                               own, workers=workers):
        if found is None:
            problems.append((str(path), problem or "not scored"))
            continue
        for event in found:
            if as_json:
                print(json.dumps({"session": str(path), "event": event.to_dict()}))
            else:
                release = "open" if event.release_s is None else f"{event.release_s:.2f} s"
                print(f"{printable(path)}: contact {event.label} onset {event.onset_s:.2f} s, "
                      f"release {release}; at the decision "
                      f"{contact_text(event.contact_at_decision)}; at the peak "
                      f"{contact_text(event.contact_at_peak)}")
    return problems


@app.command("calibrate")
def calibrate_command(
    ctx: typer.Context,
    sessions: Annotated[list[Path], typer.Argument(
        help="No-contact sessions (action none, or with a contact column), files or "
             "directories.")],
    out: Annotated[Path, typer.Option(help="Calibration file to write (JSON).")],
    margin: Annotated[float, typer.Option(
        help="Factor on the fitted thresholds.")] = 1.5,
    motion_margin: Annotated[float | None, typer.Option(
        help="Factor on the thresholds' growth with speed, acceleration and dynamic "
             "torque (default: --margin). Wider when calibrating on another arm than the "
             "one it runs on, such as a simulated one.")] = None,
    dynamic: Annotated[bool, typer.Option(
        help="Let each joint's threshold also grow with its own dynamic torque "
             "|M ddq + C dq| + 0.5 s |dg/dt| (the chain's tau_dyn), fitted with the "
             "speed and acceleration terms: for data from several arms of one type. The "
             "file then also records each joint's largest dynamic torque in the data; "
             "beyond it the thresholds grow further.")
    ] = False,
    workers: Annotated[int, typer.Option(help="Parallel worker processes.")] = 1,
    robot: RobotOpt = None,
    dynamics: DynamicsOpt = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing --out file.")] = False,
) -> None:
    """Calibrate the contact detector on a robot's no-contact sessions: record a minute
    of free motion and holds, calibrate, then pass --calibration robot.json to replay
    and predict."""
    from contactkit.classify.events.calibrate import calibrate_sessions
    from contactkit.robots.dynamics import arm_override

    check_target(out, overwrite=overwrite)
    identified = load_dynamics_option(dynamics)
    for flag, value in (("--margin", margin), ("--motion-margin", motion_margin)):
        if value is not None and not 1.0 <= value < math.inf:  # NaN fails too
            raise InputError(f"{flag} must be a finite number of at least 1, got {value}")
    paths = source_sessions(sessions)
    problems: list[tuple[str, str]] = []
    with progress_bar("calibrating") as bar:
        config = calibrate_sessions(paths, margin=margin, workers=workers,
                                    progress=bar_callback(bar, "sessions"),
                                    motion_margin=motion_margin,
                                    robot=arm_override(robot, identified),
                                    problems=problems, scheduler=scheduler_of(ctx),
                                    dynamic=dynamic)
    print_problems(problems)
    save_calibration(out, config, overwrite=overwrite)
    print(f"{printable(out)}: thresholds at rest {[round(v, 2) for v in config.noise]} Nm, "
          f"per rad/s {[round(v, 2) for v in config.speed]}, "
          f"per rad/s^2 {[round(v, 3) for v in config.accel]}"
          + (f", per Nm of dynamic torque {[round(v, 3) for v in config.dynamic]}"
             if dynamic else "") + beyond_range_text(config))
    exit_if_failed(problems)


@app.command("experiment")
def experiment_command(
    ctx: typer.Context,
    name: Annotated[Experiment, typer.Argument(help="The experiment.")],
    datasets: DatasetsArg,
    out: Annotated[Path, typer.Option(help="Directory for the .md, .json and .png.")],
    protocol: Annotated[Protocol, typer.Option(help="Evaluation protocol.")] = "group",
    group: Annotated[Group, typer.Option(help="Grouping for the group protocol.")] = "pose",
    scheme: SchemeOpt = "full", c: COpt = 10.0, seed: SeedOpt = 0,
    workers: WorkersOpt = DEFAULT_WORKERS,
    model: Annotated[Kind, typer.Option(
        help="augmentation: the network (the thesis used its CNN, hours per training on "
             "a CPU).")] = DEFAULT_SEARCHED,
    repeats: Annotated[int, typer.Option(
        help="augmentation: repetitions, each with its own real test split.")] = 3,
    epochs: Annotated[int, typer.Option(help="augmentation: the network's most training "
                                             "epochs, where it takes them.")] = 60,
    steps: StepsOpt = 300,
    noise_file: Annotated[Path | None, typer.Option(
        help="augmentation: noise baseline from `recorder stats --deep` (default: "
             "measured on the real set's no-contact sessions).")] = None,
    device: Annotated[Device, typer.Option(
        help="augmentation: where the network trains, where it takes a device.")] = "cpu",
) -> None:
    """Regenerate a thesis table on any dataset: features (Appendix B), rfe, speed
    (Figure 6.5), window (accuracy against window length), or augmentation REAL SIM
    (Algorithm 3: less real data, added simulated data and noise augmentation)."""
    from contactkit.classify.experiments.augmentation import run_augmentation
    from contactkit.classify.experiments.thesis import Setting, run_experiment

    name = Experiment(name).value
    setting = Setting(protocol=Protocol(protocol).value, group_by=Group(group).value,
                      scheme=Scheme(scheme).value, seed=seed, workers=workers, c=c,
                      scheduler=scheduler_of(ctx))
    with progress_bar(f"experiment {name}") as bar:
        progress = labelled_progress(bar)
        if name == "augmentation":
            if len(datasets) != 2:
                raise InputError("augmentation takes two datasets: REAL_DIR SIM_DIR")
            kind = get_kind(Kind(model).value)
            takes = {p.name for p in kind.params}
            params = {"epochs": epochs, "device": Device(device).value}
            options = ModelOptions(kind=kind.name, steps=steps, seed=seed, params={
                k: v for k, v in params.items() if k in takes})
            paths = run_augmentation(datasets[0], datasets[1], out, kind=kind,
                                     options=options, repeats=repeats, workers=workers,
                                     noise_file=noise_file, progress=progress,
                                     scheduler=setting.scheduler)
        else:
            paths = run_experiment(name, datasets, out, setting, progress)
    for path in paths:
        print(printable(path))


def _numbers(option: str, text: str, kind: type) -> list:
    """Return the comma-separated numbers of ``text`` converted by ``kind``; raise
    InputError naming ``option`` when one is not a number."""
    try:
        return [kind(v) for v in _split(text) or ()]
    except ValueError as err:
        raise InputError(f"{option}: {text!r} is not a list of numbers") from err


def _values_param(param: Param) -> Param:
    """Return the declaration of the grid search's option for a searched parameter: its
    values to try, comma-separated (``--depths`` for ``depth``)."""
    grid = ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in param.grid)
    return Param(f"{param.name}s", str, grid, f"{param.help.split(' (')[0].rstrip('.')}: "
                 f"values to try, comma-separated.", flag=f"{param.option[2:]}s")


GRID_OPTIONS = {"--out", "--model", "--steps", "--inputs", "--protocol", "--group", "--scheme",
                "--window", "--window-s", "--seed", "--workers", "--overwrite", "--no-overwrite",
                "--help"}
"""The grid search's own options, which no kind's parameter may take."""
GRID_FLAGS, _ = shared_flags({name: [_values_param(p) if p.grid else p
                                     for p in get_kind(name).params]
                              for name in searchable_kinds()}, GRID_OPTIONS, what="models")
"""The searchable kinds' parameters as options of the grid search: the values to try of
each searched parameter (``--depths``), the single value of the others (``--epochs``)."""


@command_with_flags(app, "gridsearch", list(GRID_FLAGS.values()), key="params")
def gridsearch_command(
    ctx: typer.Context,
    datasets: DatasetsArg,
    out: Annotated[Path, typer.Option(
        help="Output directory: gridsearch.md, gridsearch.json and the best network "
             "trained on every session (best.onnx).")],
    model: Annotated[Network, typer.Option(help="The network.")] = DEFAULT_SEARCHED,
    steps: Annotated[str, typer.Option(help="Time steps of a window grid to try.")] = "300",
    inputs: Annotated[list[str] | None, typer.Option(
        "--inputs", help="Input timeseries of one set of trials, comma-separated; repeat "
                         "the option for more (default: the network's default inputs, "
                         "q,dq,tau for the CNN, dq,tau,r for the LSTM).")] = None,
    protocol: Annotated[Protocol, typer.Option(help="Evaluation protocol of every trial.")
                        ] = "group",
    group: Annotated[Group, typer.Option(help="Grouping for the group protocol.")] = "pose",
    scheme: SchemeOpt = "full", window: WindowOpt = None, window_s: WindowSOpt = 0.5,
    seed: SeedOpt = 0,
    workers: Annotated[int, typer.Option(
        help="Parallel processes: grids, then one trial per process.")] = DEFAULT_WORKERS,
    overwrite: Annotated[bool, typer.Option(help="Replace existing results.")] = False,
) -> None:
    """Search the network's declared grid (for the thesis's networks depth, width and
    dropout) with steps and inputs: every trial evaluated under the protocol with early
    stopping, a ranked table with 95 % intervals (gridsearch.md, .json), and the best
    network saved as a model file that predict and replay --model take. The network's
    parameters are the options after --overwrite."""
    from contactkit.classify.experiments.gridsearch import (
        RESULTS_JSON,
        RESULTS_MD,
        best_model_path,
        best_trial,
        grid_trials,
        run_trials,
        train_best,
        write_results,
    )
    from contactkit.classify.experiments.gridsearch import Protocol as GridProtocol

    kind = get_kind(Network(model).value)
    given = owner_values(GRID_FLAGS, ctx.meta["params"], kind.name, "model")
    grid = {p.name: _numbers(p.option + "s", given.pop(p.name + "s"), p.type)
            for p in kind.params if p.grid and p.name + "s" in given}
    setting = GridProtocol(model=kind.name, protocol=Protocol(protocol).value,
                           group_by=Group(group).value, scheme=Scheme(scheme).value,
                           seed=seed, params=given,
                           window=kind.default_window if window is None
                           else Method(window).value, window_s=window_s)
    setting.check()
    best_path = best_model_path(out, setting)
    _refuse_existing(best_path, overwrite)
    check_results(out, [RESULTS_MD, RESULTS_JSON])
    trials = grid_trials(kind, grid, _numbers("--steps", steps, int),
                         [_split(i) for i in inputs] if inputs else [kind.default_timeseries])
    with progress_bar("grid search") as bar:
        progress = labelled_progress(bar)
        results = run_trials(datasets, trials, setting, workers=workers, progress=progress,
                             scheduler=scheduler_of(ctx))
        md, _ = write_results(out, results, setting)
        best = best_trial(results)
        trained = train_best(datasets, best, setting, best_path, workers=workers,
                             overwrite=overwrite, progress=progress,
                             scheduler=scheduler_of(ctx))
    failed = [r for r in results if r.report is None]
    for r in failed:
        err_console.print(f"[yellow]failed[/] {r.trial.label()}: {r.problem}")
    err_console.print(f"{len(results) - len(failed)} of {len(results)} trials evaluated; "
                      f"best {best.label()}, saved as {trained.path}")
    print(md.read_text(), end="")


def main() -> None:
    """Entry point of the ``classify`` console script."""
    sys.exit(run_app(app, "classify"))
