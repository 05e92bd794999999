"""The ``replay`` command: sessions through the feature chain and classifier, into Rerun.

A thin layer over :mod:`contactkit.replay.session_replay`: options, viewer start-up,
progress and messages.
"""

from __future__ import annotations

import sys
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from contactkit.cli.common import (
    DynamicsOpt,
    QuietOpt,
    RobotOpt,
    VerboseOpt,
    load_dynamics_option,
    new_app,
    run_app,
    set_verbosity,
)
from contactkit.replay.hop import DEFAULT_HOP_S
from contactkit.schemas import InputError
from contactkit.util.atomic import check_target
from contactkit.util.progress import err_console, labelled_progress, progress_bar
from contactkit.util.text import console_text, printable
from contactkit.viewer.web import has_display, start_web_viewer

# The command imports the classifier, the chain and rerun when it runs, not at start-up
# (tests/cli/test_startup.py checks what `replay --help` imports).

DEFAULT_SAVE = Path("replay.rrd")


class Viewer(StrEnum):
    """Where a replay is shown."""

    rerun = "rerun"
    web = "web"
    none = "none"


def _parse_rate(rate: str) -> float | None:
    if rate == "max":
        return None
    try:
        value = float(rate)
    except ValueError as err:
        raise InputError(f"--rate must be 'max' or a positive number, got {rate!r}") from err
    if not value > 0:
        raise InputError(f"--rate must be positive, got {value}")
    return value


def replay_command(
    sessions: Annotated[list[Path] | None, typer.Argument(
        help="Session files, or directories of sessions (each replays as its own "
             "recording).")] = None,
    viewer: Annotated[Viewer, typer.Option(
        help="rerun: spawn the native viewer (falls back to --save without a display); "
             "web: serve the web viewer on 127.0.0.1; none: only save and summarise.")
                      ] = Viewer.rerun,
    save: Annotated[Path | None, typer.Option(
        help="Write the recording to this .rrd file (several sessions: one file each, "
             "named after the session).")] = None,
    model: Annotated[Path | None, typer.Option(
        help="Model file from `classify train` (default: the built-in model, built and "
             "cached on first use).")] = None,
    rate: Annotated[str, typer.Option(
        help="'max' as fast as possible, or a multiple of wall-clock speed (1 = real "
             "time) with the viewer updating live.")] = "max",
    log_rate: Annotated[float | None, typer.Option(
        help="Send at most this many samples per second of session time to Rerun "
             "(e.g. 200) [Hz]; the feature chain, the events and the predictions still "
             "run on every sample, and every prediction is logged. Default: every "
             "sample. Thins the .rrd of a long session.")] = None,
    hop: Annotated[float, typer.Option(
        help="Time between classifier runs on the sliding window [s].")] = DEFAULT_HOP_S,
    connect: Annotated[str | None, typer.Option(
        help="Send to a running viewer at this gRPC URL instead "
             "(e.g. rerun+http://127.0.0.1:9876/proxy).")] = None,
    calibration: Annotated[Path | None, typer.Option(
        help="Contact detector calibration from `classify calibrate` (overrides the "
             "model's detector settings).")] = None,
    decide_after: Annotated[float | None, typer.Option(
        help="Time after a contact's onset at which its intent is decided [s] (default: "
             "the model's); a weak contact waits for the model's later delay.")] = None,
    robot: RobotOpt = None,
    dynamics: DynamicsOpt = None,
    overwrite: Annotated[bool, typer.Option(
        help="Replace existing --save files (the default replay.rrd is replaced only "
             "when it is a recording); with --build-default-model, rebuild a cached "
             "model.")] = False,
    build_default_model_: Annotated[bool, typer.Option(
        "--build-default-model", help="Build the default model from its recipe "
                                      "(see contactkit/cli/default_model.py) unless it is "
                                      "cached (--overwrite rebuilds it), print its "
                                      "path and exit. With --dynamics, the recipe "
                                      "simulates that identified arm: a model for your "
                                      "arm, cached apart; pass it with --model.")] = False,
    verbose: VerboseOpt = 0,
    quiet: QuietOpt = False,
) -> None:
    """Replay sessions through the streaming feature chain and a classifier, and show
    torques, residuals, wrench, class probabilities and the robot, time-aligned, in
    Rerun.

    Example: replay session.parquet --viewer rerun
    """
    set_verbosity(verbose, quiet)
    from contactkit.cli.default_model import (
        build_default_model,
        default_model_missing,
        model_or_default,
    )
    from contactkit.features.detector import load_calibration
    from contactkit.replay.recording import owned_recording, save_paths_for
    from contactkit.replay.session_replay import ReplaySummary, replay_sessions, session_inputs
    from contactkit.robots import RobotSetup
    from contactkit.robots.dynamics import arm_override, check_arm

    if build_default_model_:
        identified = load_dynamics_option(dynamics)
        if identified is not None and robot is not None:
            check_arm(identified, RobotSetup(robot, identified.with_hand), dynamics)
        with progress_bar() as bar:
            print(build_default_model(progress=labelled_progress(bar), rebuild=overwrite,
                                      dynamics=identified))
        return
    if not sessions:
        raise InputError("give at least one session file or directory (see replay --help)")
    speed = _parse_rate(rate)
    if log_rate is not None and not log_rate > 0:
        raise InputError(f"--log-rate must be positive, got {log_rate} Hz")
    if not hop > 0:
        raise InputError(f"--hop must be positive, got {hop} s")
    paths = session_inputs(sessions)
    detector = None if calibration is None else load_calibration(calibration)
    arm = arm_override(robot, load_dynamics_option(dynamics))
    viewer = Viewer(viewer)
    owned = None if save is not None else owned_recording
    if viewer is Viewer.rerun and connect is None and not has_display():
        save = save or DEFAULT_SAVE
        err_console.print(f"no display: saving to {console_text(save)} instead; open it with "
                          f"`rerun {console_text(save)}` where a display is available")
        viewer = Viewer.none
    if viewer is Viewer.none and save is None and connect is None:
        save = DEFAULT_SAVE
    if save is not None:
        for target in save_paths_for(save, paths):
            check_target(target, overwrite=overwrite, owned=owned)
    if model is None and default_model_missing():
        err_console.print("No --model given: building the default model once (simulated "
                          "data, then an SVM); it is cached for next time.")
    with progress_bar() as bar:
        classifier = model_or_default(model, labelled_progress(bar))
    web = None
    if viewer is Viewer.web and connect is None:
        web, connect, page = start_web_viewer()
        err_console.print(f"web viewer: {page}")
    with progress_bar() as bar:
        task = bar.add_task("replaying", total=len(paths))

        def report(result: ReplaySummary | InputError) -> None:
            if isinstance(result, InputError):
                print(f"replay: error: {printable(result)}", file=sys.stderr)
            else:
                bar.console.print(console_text(result.line()))
            bar.advance(task)

        summaries, problems = replay_sessions(
            paths, classifier, save=save, connect=connect, spawn=viewer is Viewer.rerun,
            rate=speed, hop_s=hop, detector=detector, decide_after_s=decide_after,
            log_rate_hz=log_rate, robot=arm, overwrite=overwrite, owned=owned,
            on_done=report)
    written = [s.saved for s in summaries if s.saved is not None]
    if len(written) == 1:
        err_console.print(f"saved {console_text(written[0])}; open it with "
                          f"`rerun {console_text(written[0])}`")
    elif written and save is not None:  # several recordings are saved with --save only
        err_console.print(f"saved {len(written)} recordings as {console_text(save.parent)}/"
                          f"{console_text(save.stem)}_"
                          f"<session>.rrd; open them together with "
                          f"`rerun {console_text(save.parent)}/{console_text(save.stem)}_*.rrd`")
    if web is not None:
        err_console.print("serving the web viewer; press Ctrl-C to stop")
        try:
            web.wait()
        except KeyboardInterrupt:
            web.terminate()
    if problems:
        raise typer.Exit(2)


app = new_app(no_args_is_help=False)
app.command(name="replay")(replay_command)


def pyarrow_without_pandas() -> None:
    """Have pyarrow record, once per process, that pandas is absent, unless it is loaded.

    pyarrow imports pandas the first time ``pa.array`` gets a Python list (to ask whether
    it is a pandas object), and Rerun's SDK passes lists; that is 0.7 s and 40 MB of a
    replay that converts nothing to pandas. With pandas marked missing for that one
    call, pyarrow takes every later list as a list, and still imports pandas if asked
    to convert to it (``to_pandas``). Only the console script calls this: a notebook's
    pyarrow is left as it is."""
    if "pandas" in sys.modules:
        return
    import pyarrow as pa

    sys.meta_path.insert(0, _NO_PANDAS)
    try:
        pa.array([0])
    finally:
        sys.meta_path.remove(_NO_PANDAS)


class _NoPandas:
    """An import finder under which importing pandas fails."""

    @staticmethod
    def find_spec(name: str, path: object = None, target: object = None) -> None:
        """Raise ModuleNotFoundError for pandas; leave any other module to the next
        finder (return None)."""
        if name == "pandas":
            raise ModuleNotFoundError("pandas is left out here", name="pandas")


_NO_PANDAS = _NoPandas()


def main() -> None:
    """Entry point of the ``replay`` console script."""
    pyarrow_without_pandas()
    sys.exit(run_app(app, "replay"))
