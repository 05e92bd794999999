"""The ``classify`` command: features, training, evaluation, prediction, experiments."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Annotated

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from contactkit.classify.augmentation import run_augmentation
from contactkit.classify.calibrate import calibrate_sessions
from contactkit.classify.data import GROUP_KEYS, FeatureSet, load_features
from contactkit.classify.evaluate import PROTOCOLS, evaluate, report_markdown
from contactkit.classify.events import session_events
from contactkit.classify.experiments import EXPERIMENTS, Setting, run_experiment
from contactkit.classify.grids import CNN_INPUT, LSTM_INPUT, GridSpec, load_grids, session_grid
from contactkit.classify.modelfile import load_model, model_meta, save_model
from contactkit.classify.models import MODEL_KINDS, make_model
from contactkit.classify.nn import NN_KINDS, check_available, make_network
from contactkit.classify.onnx_model import save_onnx_model
from contactkit.classify.schemes import SCHEMES, check_scheme, scheme_classes
from contactkit.features.detector import load_calibration, save_calibration
from contactkit.features.extract import SessionFeatures, feature_rows, timeseries_columns
from contactkit.features.scalars import SCALARS
from contactkit.features.timeseries import ALL_TIMESERIES, GROUPS
from contactkit.features.windows import METHODS, WindowSpec
from contactkit.schemas import InputError, read_session
from contactkit.schemas.dataset import session_files
from contactkit.schemas.features import FEATURES_KEY, write_feature_table
from contactkit.util.cli import run_app

app = typer.Typer(name="classify", no_args_is_help=True, add_completion=False,
                  pretty_exceptions_enable=False,
                  help="Turn sessions into features and contact predictions.")
err_console = Console(stderr=True)
DEFAULT_WORKERS = max(os.cpu_count() or 1, 1)


@app.callback()
def _root() -> None:
    """Turn sessions into features and contact predictions."""


def _split(value: str) -> list[str]:
    return [v.strip() for v in value.split(",") if v.strip()]


def _inputs(source: Path) -> list[Path]:
    if source.is_dir():
        files = session_files(source)
        if not files:
            raise InputError("no session files (*.parquet) in this directory", source)
        return files
    if not source.exists():
        raise InputError("no such file or directory", source)
    return [source]


def labelled_progress(bar: Progress):
    """Return a callback ``(label, done, total)`` that keeps one bar per label."""
    tasks: dict[str, int] = {}

    def progress(label: str, done: int, total: int) -> None:
        if label not in tasks:
            tasks[label] = bar.add_task(label, total=total)
        bar.update(tasks[label], completed=done, total=total, description=label)

    return progress


def progress_bar(label: str) -> Progress:
    """Return a progress bar on stderr for long work."""
    return Progress(TextColumn(f"[bold]{label}[/] {{task.description}}"), BarColumn(),
                    MofNCompleteColumn(),
                    TimeRemainingColumn(), console=err_console)


@app.command("features")
def features_command(
    source: Annotated[Path, typer.Argument(help="A session file or a dataset directory.")],
    out: Annotated[Path, typer.Option(help="Output Parquet file.")],
    timeseries: Annotated[str, typer.Option(
        help=f"Comma-separated timeseries features or groups ({', '.join(GROUPS)}; "
             f"{', '.join(ALL_TIMESERIES)}).")] = "dq,tau,r",
    window: Annotated[str, typer.Option(help=f"Window method: {', '.join(METHODS)}.")
                      ] = "difference",
    window_s: Annotated[float, typer.Option(help="Window length [s].")] = 0.5,
    scalars: Annotated[str, typer.Option(
        help=f"Comma-separated scalar features: {', '.join(SCALARS)}.")] = "range",
    per_sample: Annotated[bool, typer.Option(
        help="Write every timeseries feature of every sample instead (r_1..r_7, g_*, "
             "tau_inv_*, ddq_*, p_int_*, p_ext_*, f_x.. m_norm).")] = False,
    workers: Annotated[int, typer.Option(help="Parallel processes.")] = DEFAULT_WORKERS,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output file.")] = False,
) -> None:
    """Compute features of a session or dataset: one row per session (scalar features
    of the interaction window), or with --per-sample one row per sample."""
    files = _inputs(source)
    if out.exists() and not overwrite:
        raise InputError("output file already exists (pass --overwrite to replace it)", out)
    if per_sample:
        _write_per_sample(files, out)
        print(out)
        return
    extractor = SessionFeatures(timeseries=_split(timeseries), window=window, window_s=window_s,
                                scalars=_split(scalars))
    extractor.fit(None)
    with progress_bar("features") as bar:
        task = bar.add_task("sessions", total=len(files))
        result = feature_rows(files, extractor, workers,
                              lambda done, total: bar.update(task, completed=done))
    for name, problem in result.problems:
        err_console.print(f"[yellow]skipped[/] {name}: {problem}")
    if not result.rows:
        raise InputError("no session could be processed", source)
    write_feature_table(out, result.rows, result.names, extractor.config())
    err_console.print(f"{len(result.rows)} sessions x {len(result.names)} features")
    print(out)


def _write_per_sample(files: list[Path], out: Path) -> None:
    tmp = out.with_name(f".{out.name}.tmp")
    writer = None
    try:
        with progress_bar("per-sample features") as bar:
            task = bar.add_task("sessions", total=len(files))
            for path in files:
                bar.advance(task)
                try:
                    session = read_session(path)
                except InputError as err:
                    err_console.print(f"[yellow]skipped[/] {err}")
                    continue
                table = pa.table({"session_id": [session.meta.session_id] * session.n_samples,
                                  **timeseries_columns(session)})
                if writer is None:
                    writer = pq.ParquetWriter(tmp, table.schema, compression="zstd")
                writer.write_table(table)
        if writer is None:
            raise InputError("no session could be processed", files[0].parent)
        writer.close()
        tmp.replace(out)
    finally:
        if writer is not None:
            writer.close()
        tmp.unlink(missing_ok=True)


FeaturesOpt = Annotated[str | None, typer.Option(
    "--features", help="Timeseries features (comma-separated, or groups sensor, model, "
                       "workspace): their scalar features feed an SVM, their raw window a "
                       "network (default dq,tau,r; q,dq,tau for cnn and minirocket).")]
ScalarsOpt = Annotated[str, typer.Option(help=f"Scalar features: {', '.join(SCALARS)}.")]
WindowOpt = Annotated[str | None, typer.Option(
    help=f"Window method: {', '.join(METHODS)} (default difference; planned for networks).")]
SchemeOpt = Annotated[str, typer.Option(help=f"Class scheme: {', '.join(SCHEMES)}.")]
ModelOpt = Annotated[str, typer.Option(
    help=f"Classifier: {', '.join(MODEL_KINDS + NN_KINDS)} (networks need the nn extra).")]
WindowSOpt = Annotated[float, typer.Option(help="Window length [s].")]
LimitedOpt = Annotated[bool, typer.Option(
    help="Limited context: drop shove from static and adjust from dynamic.")]
COpt = Annotated[float, typer.Option("--C", help="SVM regularisation C.")]
EpochsOpt = Annotated[int, typer.Option(help="Networks: most training epochs (early "
                                             "stopping on a validation split).")]
StepsOpt = Annotated[int, typer.Option(help="Networks: time steps of a window grid.")]
SeedOpt = Annotated[int, typer.Option(help="Random seed (same seed, same result).")]
DepthOpt = Annotated[int | None, typer.Option(
    help="CNN/LSTM: layer multiplier (thesis grid 1, 2, 4; default CNN 4, LSTM 2).")]
WidthOpt = Annotated[float, typer.Option(
    help="CNN/LSTM: kernel and neuron multiplier (thesis grid 0.5, 1, 2).")]
DropoutOpt = Annotated[float, typer.Option(
    help="CNN/LSTM: dropout after each pooling and dense layer (thesis grid 0, 0.1, 0.25).")]
WorkersOpt = Annotated[int, typer.Option(
    help="Parallel processes for features (and, for networks, for evaluation splits).")]
DatasetsArg = Annotated[list[Path], typer.Argument(
    help="Dataset directories (or feature tables from `classify features`); several are "
         "combined, e.g. a static and a dynamic set.")]


def _extractor(features: str | None, scalars: str, window: str | None,
               window_s: float) -> SessionFeatures:
    extractor = SessionFeatures(timeseries=_split(features or "dq,tau,r"),
                                scalars=_split(scalars), window=window or "difference",
                                window_s=window_s)
    extractor.fit(None)
    return extractor


def _grid_spec(model: str, features: str | None, window: str | None, window_s: float,
               steps: int) -> GridSpec:
    check_available(model)
    default = LSTM_INPUT if model == "lstm" else CNN_INPUT
    spec = GridSpec(timeseries=tuple(_split(features)) if features else default,
                    window=window or "planned", window_s=window_s, steps=steps)
    try:
        spec.channels()
    except KeyError as err:
        raise InputError(f"unknown timeseries feature {err.args[0]!r}") from err
    WindowSpec(spec.window, spec.window_s)
    return spec


def _network(model: str, seed: int, epochs: int, depth: int | None, width: float,
             dropout: float):
    """Return an unfitted network with the size options checked."""
    if epochs < 1:
        raise InputError(f"--epochs must be at least 1, got {epochs}")
    if model == "minirocket":
        return make_network(model, seed)
    if depth is not None and depth < 1:
        raise InputError(f"--depth must be at least 1, got {depth}")
    if width <= 0:
        raise InputError(f"--width must be positive, got {width}")
    if not 0 <= dropout < 1:
        raise InputError(f"--dropout must be in [0, 1), got {dropout}")
    return make_network(model, seed, epochs, depth=depth, width=width, dropout=dropout)


def _grid_set(datasets: list[Path], spec: GridSpec, workers: int, limited: bool) -> FeatureSet:
    with progress_bar("window grids") as bar:
        task = bar.add_task("sessions", total=None)
        data = load_grids(datasets, spec, workers,
                          progress=lambda done, total: bar.update(task, completed=done,
                                                                  total=total))
    for name, problem in data.problems:
        err_console.print(f"[yellow]skipped[/] {name}: {problem}")
    return data.limited() if limited else data


def _feature_set(datasets: list[Path], extractor: SessionFeatures, workers: int,
                 limited: bool = False) -> FeatureSet:
    with progress_bar("features") as bar:
        task = bar.add_task("sessions", total=None)
        data = load_features(datasets, extractor, workers,
                             lambda done, total: bar.update(task, completed=done, total=total))
    for name, problem in data.problems:
        err_console.print(f"[yellow]skipped[/] {name}: {problem}")
    return data.limited() if limited else data


@app.command("train")
def train_command(
    datasets: DatasetsArg,
    out: Annotated[Path, typer.Option(
        help="Model file to write: .skops (SVMs, MiniRocket) or .onnx (CNN, LSTM).")],
    model: ModelOpt = "svm",
    features: FeaturesOpt = None,
    scalars: ScalarsOpt = "range",
    window: WindowOpt = None,
    window_s: WindowSOpt = 0.5,
    scheme: SchemeOpt = "full",
    limited: LimitedOpt = False,
    c: COpt = 1.0,
    seed: SeedOpt = 0,
    workers: WorkersOpt = DEFAULT_WORKERS,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing model file.")] = False,
    epochs: EpochsOpt = 100,
    steps: StepsOpt = 300,
    depth: DepthOpt = None,
    width: WidthOpt = 2.0,
    dropout: DropoutOpt = 0.02,
) -> None:
    """Train a classifier on every session of the datasets and save it as a safe model file
    (.skops; a CNN or LSTM as .onnx)."""
    check_scheme(scheme)
    if out.exists() and not overwrite:
        raise InputError("output file already exists (pass --overwrite to replace it)", out)
    training = {"datasets": [str(d) for d in datasets], "seed": seed, "limited": limited}
    if model in NN_KINDS:
        if model in ("cnn", "lstm") and out.suffix != ".onnx":
            raise InputError(f"a {model} is saved as ONNX: give --out with .onnx", out)
        spec = _grid_spec(model, features, window, window_s, steps)
        network = _network(model, seed, epochs, depth, width, dropout)
        data = _grid_set(datasets, spec, workers, limited)
        network.fit(data.X, data.labels(scheme))
        classes = [str(c) for c in network.classes_]
        training.update(sessions=len(data), epochs=getattr(network, "n_epochs_", None),
                        network=network.get_params())
        if model in ("cnn", "lstm"):
            meta = model_meta(kind=model, scheme=scheme, classes=classes,
                              fingerprint=data.fingerprint(), training=training,
                              grid=spec.as_dict())
            save_onnx_model(out, network, data.X.shape[1], data.X.shape[2], meta, overwrite)
        else:
            save_model(out, network, classes=classes, kind=model, scheme=scheme,
                       fingerprint=data.fingerprint(), training=training,
                       overwrite=overwrite, grid=spec.as_dict())
    else:
        extractor = _extractor(features, scalars, window, window_s)
        data = _feature_set(datasets, extractor, workers, limited)
        estimator = make_model(model, data.names, seed, c).fit(data.X, data.labels(scheme))
        classes = [str(c) for c in estimator.classes_]
        training.update(sessions=len(data), C=c)
        save_model(out, estimator, extractor=extractor, feature_names=data.names,
                   classes=classes, kind=model, scheme=scheme, fingerprint=data.fingerprint(),
                   training=training, overwrite=overwrite)
    err_console.print(f"trained {model} on {len(data)} sessions, classes {', '.join(classes)}")
    print(out)


@app.command("evaluate")
def evaluate_command(
    datasets: DatasetsArg,
    protocol: Annotated[str, typer.Option(help="thesis: 25 random 80/20 splits; group: "
                                               "no group on both sides of a split.")] = "group",
    group: Annotated[str, typer.Option(help=f"Grouping for the group protocol: "
                                            f"{', '.join(GROUP_KEYS)}.")] = "pose",
    model: ModelOpt = "svm",
    features: FeaturesOpt = None,
    scalars: ScalarsOpt = "range",
    window: WindowOpt = None,
    window_s: WindowSOpt = 0.5,
    scheme: SchemeOpt = "full",
    limited: LimitedOpt = False,
    c: COpt = 1.0,
    seed: SeedOpt = 0,
    workers: WorkersOpt = DEFAULT_WORKERS,
    json_out: Annotated[Path | None, typer.Option("--json", help="Also write the report "
                                                                 "as JSON.")] = None,
    epochs: EpochsOpt = 100,
    steps: StepsOpt = 300,
    depth: DepthOpt = None,
    width: WidthOpt = 2.0,
    dropout: DropoutOpt = 0.02,
) -> None:
    """Evaluate a classifier honestly and print accuracy, balanced accuracy, macro-F1,
    per-class recall with 95 % confidence intervals, and the confusion matrix."""
    check_scheme(scheme)
    if protocol not in PROTOCOLS:
        raise InputError(f"unknown protocol {protocol!r} (expected thesis or group)")
    if model in NN_KINDS:
        spec = _grid_spec(model, features, window, window_s, steps)
        network = _network(model, seed, epochs, depth, width, dropout)
        data = _grid_set(datasets, spec, workers, limited)

        def factory():
            return network
    else:
        extractor = _extractor(features, scalars, window, window_s)
        data = _feature_set(datasets, extractor, workers, limited)

        def factory():
            return make_model(model, data.names, seed, c)
    y = data.labels(scheme)
    groups = data.groups(group) if protocol == "group" else None
    with progress_bar(f"{protocol} protocol") as bar:
        task = bar.add_task("splits", total=None)
        report = evaluate(data.X, y, factory, protocol=protocol, groups=groups, group_by=group,
                          model=model, scheme=scheme, classes=scheme_classes(scheme),
                          seed=seed, workers=workers if model in NN_KINDS else 1,
                          progress=lambda d, t: bar.update(task, completed=d, total=t))
    print(report_markdown(report))
    if json_out is not None:
        json_out.write_text(json.dumps(report.as_dict(), indent=2))


@app.command("calibrate")
def calibrate_command(
    sessions: Annotated[list[Path], typer.Argument(
        help="No-contact sessions (action none, or with a contact column), files or "
             "directories.")],
    out: Annotated[Path, typer.Option(help="Calibration file to write (JSON).")],
    margin: Annotated[float, typer.Option(
        help="Factor on the fitted thresholds.")] = 1.5,
    workers: Annotated[int, typer.Option(help="Parallel worker processes.")] = 1,
) -> None:
    """Calibrate the contact detector on a robot's no-contact sessions: record a minute
    of free motion and holds, calibrate, then pass --calibration robot.json to replay
    and predict."""
    if margin < 1:
        raise InputError(f"--margin must be at least 1, got {margin}")
    paths = [p for source in sessions for p in _inputs(source)]
    with progress_bar("calibrating") as bar:
        task = bar.add_task("sessions", total=len(paths))
        config = calibrate_sessions(paths, margin=margin, workers=workers,
                                    progress=lambda done, total: bar.update(task,
                                                                            completed=done))
    save_calibration(out, config)
    print(f"{out}: thresholds at rest {[round(v, 2) for v in config.noise]} Nm, "
          f"per rad/s {[round(v, 2) for v in config.speed]}, "
          f"per rad/s^2 {[round(v, 3) for v in config.accel]}")


def _print_events(model, source: Path, detector, decide_after: float | None,
                  as_json: bool) -> None:
    events_model = model.event_model()
    for path in _inputs(source):
        session = read_session(path)
        for event in session_events(session, detector, events_model, decide_after):
            if as_json:
                print(json.dumps({"session": str(path), "event": event.to_dict()}))
            else:
                release = "open" if event.release_s is None else f"{event.release_s:.2f} s"
                print(f"{path}: contact {event.label} onset {event.onset_s:.2f} s, "
                      f"release {release}")


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
        help="Seconds after onset at which an event's intent is decided.")] = None,
) -> None:
    """Predict the contact class of sessions with a trained model."""
    model = load_model(model_path)
    if events or calibration is not None:
        detector = (load_calibration(calibration) if calibration is not None
                    else model.detector_config())
        if detector is None:
            raise InputError("model carries no contact detector; give --calibration", model_path)
        for source in sessions:
            _print_events(model, source, detector, decide_after, as_json)
        return
    rows = []
    for source in sessions:
        if model.input == "grid":
            X, labels, truth = [], [], []
            for path in _inputs(source):
                try:
                    session = read_session(path)
                    X.append(session_grid(session, model.grid_spec()))
                except InputError as err:
                    err_console.print(f"[yellow]skipped[/] {err}")
                    continue
                labels.append(str(path))
                truth.append(session.meta.action)
            if not X:
                continue
        elif source.is_file() and _is_feature_table(source):
            extractor = model.extractor()
            data = load_features([source], extractor)
            model.check_features(data.names, source)
            X, labels, truth = data.X, data.info["file"], data.info["action"]
        else:
            extractor = model.extractor()
            X, labels, truth = [], [], []
            for path in _inputs(source):
                try:
                    session = read_session(path)
                    values, names, _ = extractor.session_row(session)
                except InputError as err:
                    err_console.print(f"[yellow]skipped[/] {err}")
                    continue
                model.check_features(names, path)
                X.append(values)
                labels.append(str(path))
                truth.append(session.meta.action)
            if not X:
                continue
        proba = model.estimator.predict_proba(np.asarray(X))
        for label, p, true in zip(labels, proba, truth, strict=True):
            rows.append((label, model.classes[int(np.argmax(p))], p, true))
    if not rows:
        raise InputError("nothing to predict")
    for label, predicted, p, true in rows:
        if as_json:
            print(json.dumps({"session": label, "predicted": predicted, "true": true,
                              "probabilities": dict(zip(model.classes, p.round(4).tolist(),
                                                        strict=True))}))
        else:
            probs = " ".join(f"{c}={v:.2f}" for c, v in zip(model.classes, p, strict=True))
            print(f"{label}: {predicted} ({probs}; recorded action {true})")


@app.command("experiment")
def experiment_command(
    name: Annotated[str, typer.Argument(
        help=f"One of {', '.join(EXPERIMENTS)}, augmentation.")],
    datasets: DatasetsArg,
    out: Annotated[Path, typer.Option(help="Directory for the .md, .json and .png.")],
    protocol: Annotated[str, typer.Option(help="thesis or group.")] = "group",
    group: Annotated[str, typer.Option(help=f"Grouping: {', '.join(GROUP_KEYS)}.")] = "pose",
    scheme: SchemeOpt = "full",
    c: COpt = 10.0,
    seed: SeedOpt = 0,
    workers: WorkersOpt = DEFAULT_WORKERS,
    model: Annotated[str, typer.Option(
        help="augmentation: the network, cnn, lstm or minirocket (the thesis used its "
             "CNN, hours per training on a CPU).")] = "lstm",
    repeats: Annotated[int, typer.Option(
        help="augmentation: repetitions, each with its own real test split.")] = 3,
    epochs: EpochsOpt = 60,
    steps: StepsOpt = 300,
    noise_file: Annotated[Path | None, typer.Option(
        help="augmentation: noise baseline from `recorder stats --deep` (default: "
             "measured on the real set's no-contact sessions).")] = None,
) -> None:
    """Regenerate a thesis table on any dataset: features (Appendix B), rfe, speed
    (Figure 6.5), window (accuracy against window length), or augmentation REAL SIM
    (Algorithm 3: less real data, added simulated data and noise augmentation)."""
    check_scheme(scheme)
    if protocol not in PROTOCOLS:
        raise InputError(f"unknown protocol {protocol!r} (expected thesis or group)")
    if name == "augmentation" and len(datasets) != 2:
        raise InputError("augmentation takes two datasets: REAL_DIR SIM_DIR")
    if name == "augmentation" and repeats < 1:
        raise InputError(f"--repeats must be at least 1, got {repeats}")
    setting = Setting(protocol=protocol, group_by=group, scheme=scheme, seed=seed,
                      workers=workers, c=c)
    with progress_bar(f"experiment {name}") as bar:
        progress = labelled_progress(bar)
        if name == "augmentation":
            spec = _grid_spec(model, None, None, 0.5, steps)
            paths = run_augmentation(datasets[0], datasets[1], out, model=model, spec=spec,
                                     repeats=repeats, epochs=epochs, seed=seed,
                                     workers=workers, noise_file=noise_file,
                                     progress=progress)
        else:
            paths = run_experiment(name, datasets, out, setting, progress)
    for path in paths:
        print(path)


def _is_feature_table(path: Path) -> bool:
    try:
        metadata = pq.read_schema(path).metadata or {}
    except (pa.ArrowInvalid, OSError):
        return False
    return FEATURES_KEY in metadata


def main() -> None:
    """Entry point of the ``classify`` console script."""
    sys.exit(run_app(app, "classify"))
