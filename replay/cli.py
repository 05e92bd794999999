"""The ``replay`` command: sessions through the feature chain and classifier, into Rerun."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from contactkit.classify.cli import labelled_progress
from contactkit.classify.modelfile import ModelFile, load_model
from contactkit.features.detector import DetectorConfig, load_calibration
from contactkit.replay.default_model import build_default_model, default_model_path
from contactkit.replay.engine import DEFAULT_HOP_S, Block, ReplayStream
from contactkit.replay.recording import (
    log_block,
    log_offline,
    log_static,
    new_recording,
    save_path_for,
)
from contactkit.schemas import InputError, read_session
from contactkit.schemas import rerun_layout as layout
from contactkit.schemas.dataset import session_files
from contactkit.util.cli import run_app
from contactkit.util.viewer import has_display, start_web_viewer

err_console = Console(stderr=True)
VIEWERS = ("rerun", "web", "none")


def _progress() -> Progress:
    return Progress(TextColumn("[bold]{task.description}[/]"), BarColumn(),
                    MofNCompleteColumn(), TimeRemainingColumn(), console=err_console)


def _model(path: Path | None) -> ModelFile:
    if path is not None:
        return load_model(path)
    if not default_model_path().exists():
        err_console.print("No --model given: building the default model once (simulated "
                          "data, then an SVM); it is cached for next time.")
    with _progress() as bar:
        return load_model(build_default_model(progress=labelled_progress(bar)))


def _sessions(inputs: list[Path]) -> list[Path]:
    paths: list[Path] = []
    for source in inputs:
        if source.is_dir():
            paths += session_files(source)
        else:
            paths.append(source)
    if not paths:
        raise InputError("no session files given")
    return paths


def _parse_rate(rate: str) -> float | None:
    if rate == "max":
        return None
    try:
        value = float(rate)
    except ValueError as err:
        raise InputError(f"--rate must be 'max' or a positive number, got {rate!r}") from err
    if value <= 0:
        raise InputError(f"--rate must be positive, got {value}")
    return value


def replay_one(path: Path, model: ModelFile, *, viewer: str, save: Path | None,
               connect: str | None, rate: float | None, hop_s: float, many: bool,
               detector: DetectorConfig | None = None,
               decide_after_s: float | None = None) -> str:
    """Replay one session into its own recording; return a one-line summary."""
    session = read_session(path)
    stream = ReplayStream(session, model, hop_s, detector, decide_after_s)
    rec = new_recording(path.stem, session.meta.session_id)
    blueprint = layout.replay_blueprint()
    if save is not None:
        rec.save(save_path_for(save, path, many), default_blueprint=blueprint)
    if connect is not None:
        rec.connect_grpc(connect, default_blueprint=blueprint)
    elif viewer == "rerun":
        rec.spawn(default_blueprint=blueprint)
    tree = log_static(rec, stream)
    started = time.monotonic()
    for block in stream.blocks():
        if rate is not None:
            log_block(rec, tree, stream, block)
            due = started + (session.t[block.stop - 1] - session.t[0]) / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    if rate is None:
        log_block(rec, tree, stream, _whole(stream))
    answer = stream.offline()
    if answer is not None:
        log_offline(rec, stream, answer)
    rec.flush()
    rec.disconnect()
    contact = [(t, label) for t, label in zip(stream.pred_t, stream.pred_label, strict=True)
               if label != "none"]
    online = (f"first online contact: {contact[0][1]} at {contact[0][0]:.2f} s" if contact
              else "online: none throughout")
    events = ("" if stream.pipeline is None else
              f"; {len(stream.events)} contact events"
              + "".join(f", {e.label} at {e.onset_s:.2f} s" for e in stream.events[:5]))
    if answer is None:
        offline = "no planned time (no offline answer)"
    else:
        found = "detected" if answer.window.found else "planned"
        offline = (f"predicted {answer.label} (offline, {found} window "
                   f"{answer.window.start_s:.2f}-{answer.window.end_s:.2f} s)")
    return (f"{path.name}: recorded {session.meta.action}, {offline}; {online}; "
            f"{len(stream.pred_t)} online predictions{events}")


def _whole(stream: ReplayStream) -> Block:
    return Block(0, stream.session.n_samples, range(len(stream.pred_t)))


def replay_command(
    sessions: Annotated[list[Path] | None, typer.Argument(
        help="Session files, or directories of sessions (each replays as its own "
             "recording).")] = None,
    viewer: Annotated[str, typer.Option(
        help="rerun: spawn the native viewer (falls back to --save without a display); "
             "web: serve the web viewer on 127.0.0.1; none: only save and summarise.")
                      ] = "rerun",
    save: Annotated[Path | None, typer.Option(
        help="Write the recording to this .rrd file (several sessions: one file each, "
             "named after the session).")] = None,
    model: Annotated[Path | None, typer.Option(
        help="Model file from `classify train` (default: the built-in model, built and "
             "cached on first use).")] = None,
    rate: Annotated[str, typer.Option(
        help="'max' as fast as possible, or a multiple of wall-clock speed (1 = real "
             "time) with the viewer updating live.")] = "max",
    hop: Annotated[float, typer.Option(
        help="Seconds between classifier runs on the sliding window.")] = DEFAULT_HOP_S,
    connect: Annotated[str | None, typer.Option(
        help="Send to a running viewer at this gRPC URL instead "
             "(e.g. rerun+http://127.0.0.1:9876/proxy).")] = None,
    calibration: Annotated[Path | None, typer.Option(
        help="Contact detector calibration from `classify calibrate` (overrides the "
             "model's detector settings).")] = None,
    decide_after: Annotated[float | None, typer.Option(
        help="Seconds after a contact's onset at which its intent is decided (default: "
             "the model's).")] = None,
    build_default_model_: Annotated[bool, typer.Option(
        "--build-default-model", help="(Re)build the default model from its recipe "
                                      "(see replay/default_model.py) and exit.")] = False,
) -> None:
    """Replay sessions through the streaming feature chain and a classifier, and show
    torques, residuals, wrench, class probabilities and the robot, time-aligned, in
    Rerun.

    Example: replay session.parquet --viewer rerun
    """
    if build_default_model_:
        with _progress() as bar:
            print(build_default_model(progress=labelled_progress(bar), rebuild=True))
        return
    if not sessions:
        raise InputError("give at least one session file or directory (see replay --help)")
    if viewer not in VIEWERS:
        raise InputError(f"unknown viewer {viewer!r} (expected rerun, web or none)")
    speed = _parse_rate(rate)
    if hop <= 0:
        raise InputError(f"--hop must be positive, got {hop} s")
    paths = _sessions(sessions)
    if viewer == "rerun" and connect is None and not has_display():
        save = save or Path("replay.rrd")
        err_console.print(f"no display: saving to {save} instead; open it with "
                          f"`rerun {save}` where a display is available")
        viewer = "none"
    if viewer == "none" and save is None and connect is None:
        save = Path("replay.rrd")
    detector = None if calibration is None else load_calibration(calibration)
    classifier = _model(model)
    web = None
    if viewer == "web" and connect is None:
        web, connect, page = start_web_viewer()
        err_console.print(f"web viewer: {page}")
    failures = 0
    many = len(paths) > 1
    with _progress() as bar:
        task = bar.add_task("replaying", total=len(paths))
        for path in paths:
            try:
                summary = replay_one(path, classifier, viewer=viewer, save=save,
                                     connect=connect, rate=speed, hop_s=hop, many=many,
                                     detector=detector, decide_after_s=decide_after)
                bar.console.print(summary)
            except InputError as err:
                failures += 1
                print(f"replay: error: {err}", file=sys.stderr)
            bar.advance(task)
    if save is not None:
        where = save_path_for(save, paths[0], many)
        if many:
            err_console.print(f"saved one recording per session as {save.parent}/"
                              f"{save.stem}_<session>.rrd; open them together with "
                              f"`rerun {save.parent}/{save.stem}_*.rrd`")
        else:
            err_console.print(f"saved {where}; open it with `rerun {where}`")
    if web is not None:
        err_console.print("serving the web viewer; press Ctrl-C to stop")
        try:
            web.wait()
        except KeyboardInterrupt:
            web.terminate()
    if failures:
        raise typer.Exit(2)


def main() -> None:
    """Entry point of the ``replay`` console script."""
    app = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
    app.command(name="replay")(replay_command)
    sys.exit(run_app(app, "replay"))

