"""The ``recorder`` command: capture sessions, build datasets, recover, inspect."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, cast

import typer

from contactkit.cli.capture_protocol import (
    CAPTURE_SUMMARY,
    SOURCES_SUMMARY,
    Action,
    CaptureExtension,
    Condition,
    Pose,
)
from contactkit.cli.catalog import register as register_catalog
from contactkit.cli.common import (
    CommandsBuilder,
    DynamicsOpt,
    RobotOpt,
    beyond_range_text,
    deferred_commands,
    exit_if_failed,
    load_dynamics_option,
    new_app,
    print_problems,
    run_app,
    scheduler_of,
)
from contactkit.errors import DATA_ERRORS, problem_text
from contactkit.recorder.metadata import set_session_robot
from contactkit.recorder.sim.presets import PRESETS
from contactkit.robots import URDF_PREFIX, get_robot, robot_names
from contactkit.schemas import InputError, SessionMeta, read_session
from contactkit.util.atomic import check_target, output_directory
from contactkit.util.parallel import available_cpus
from contactkit.util.params import Param
from contactkit.util.paths import catalog_beside
from contactkit.util.progress import (
    bar_callback,
    err_console,
    labelled_progress,
    progress_bar,
)
from contactkit.util.text import console_text, printable

if TYPE_CHECKING:
    from contactkit.features.detector import DetectorConfig
    from contactkit.features.identification import Identified
    from contactkit.recorder.importers.jobs import Imported

# The commands import the libraries they run (simulator, importers, statistics, plots)
# inside their functions, so that `recorder --help` and `recorder info` load none of them:
# tests/cli/test_startup.py checks which modules they import.

DEFAULT_WORKERS = available_cpus()
if TYPE_CHECKING:  # the presets are known at run time: a name for the type checker
    Preset = str
else:
    Preset = Literal[tuple(PRESETS)]
ReportFormat = Literal["html", "md", "json"]


def _start_events(values: dict[str, Any], meta: SessionMeta, source: Any) -> Any:
    """Store the --dynamics given in ``meta``; return the capture's listener: the live
    event pipeline with --events (behind
    :class:`~contactkit.recorder.capture.live_dynamics.LiveDynamics` with --dynamics),
    else None. The classifier side is imported here, when asked for: it takes
    seconds."""
    identified = load_dynamics_option(values["dynamics"])
    if identified is not None:  # stored with the session, and the live model below
        meta.dynamics = meta.with_dynamics(identified, values["dynamics"]).dynamics
    elif values["robot_load"]:
        raise InputError("--robot-load needs --dynamics")
    if not values["events"]:
        given = [flag for flag, key in (("--model", "model"), ("--calibration", "calibration"),
                                        ("--decide-after", "decide_after"))
                 if values[key] is not None]
        if given:
            raise InputError(f"{given[0]} needs --events")
        start = None
    else:
        start = _live_events(values)
    if identified is None:
        return None if start is None else start(meta)
    from contactkit.recorder.capture.live_dynamics import LiveDynamics

    return LiveDynamics(meta, source, identified, start or (lambda _: None),
                        values["robot_load"])


def _live_events(values: dict[str, Any]) -> Any:
    """Load the event model and detector of --events; return what starts the live event
    pipeline for the session metadata it is given (its arm, and the identified dynamics
    it carries: the chain, the detector's thresholds unless --calibration, isolation)."""
    from contactkit.classify.events.listener import LiveEvents, describe
    from contactkit.cli.default_model import default_model_missing, model_or_default
    from contactkit.features.detector import dynamics_detector, load_calibration
    from contactkit.features.isolation import robot_isolator

    calibration = None if values["calibration"] is None else load_calibration(
        values["calibration"])
    if values["model"] is None and default_model_missing():
        err_console.print("No --model given: building the default model once (simulated "
                          "data, then an SVM); it is cached for next time.")
    with progress_bar() as bar:
        model = model_or_default(values["model"], labelled_progress(bar))
    if calibration is None and model.detector_config() is None:
        raise InputError("model carries no contact detector; give --calibration",
                         values["model"])
    chain = model.online_transformer().chain_config()

    def report(kind: str, event: Any) -> None:
        err_console.print(f"  [bold]event[/] {describe(kind, event)}")

    def start(meta: SessionMeta) -> Any:
        robot = chain.robot_setup(meta)  # with the identified dynamics the session carries
        detector = calibration or dynamics_detector(robot.dynamics) or model.detector_config()
        return LiveEvents(chain, robot, detector, model.event_model(), values["decide_after"],
                          report, robot_isolator(robot))

    return start


EVENTS = CaptureExtension((
    Param("events", bool, False, "Run the contact-event pipeline on every sample as it "
          "arrives: print each onset, decision and release, and store the events in the "
          "session metadata (recorder info shows them)."),
    Param("model", Path, None, "Events: model file from `classify train` (default: the "
          "built-in model, built and cached on first use)."),
    Param("calibration", Path, None, "Events: contact detector calibration from `classify "
          "calibrate` (overrides the model's detector settings)."),
    Param("decide_after", float, None, "Events: time after a contact's onset at which its "
          "intent is decided (default: the model's); a weak contact waits for the "
          "model's later delay.", unit="s"),
    Param("dynamics", Path, None, "The arm's identified dynamics (`recorder identify`), "
          "stored with the session as values; --source sim simulates that arm (its "
          "links, friction and armature, unperturbed); with --events, the observer, the "
          "detector (the file's thresholds, unless --calibration) and isolation use them "
          "live. "
          "Refused for another arm or hand: with --source franka, name the arm (--robot)."),
    Param("robot_load", bool, False, "With --dynamics: the load the robot reports once "
          "connected (--source franka: m_load at F_x_Cload, stored as payload_kg) is the "
          "identification's payload, in place of the identified one (link 7: the nominal "
          "one plus that load)."),
), _start_events)


def deferred_capture(extensions: tuple[CaptureExtension, ...] = ()
                     ) -> dict[str, tuple[str, CommandsBuilder]]:
    """Return ``capture`` and ``sources`` as deferred commands of an app
    (:func:`~contactkit.cli.common.deferred_commands`): their one-line help, and one
    builder that loads every source (plugins included) and makes both, called only when
    one of them runs or shows its own help."""

    def build() -> dict[str, Any]:
        from contactkit.cli.capture import register_capture  # loads every source

        commands = new_app("recorder")
        register_capture(commands, extensions)
        return dict(typer.main.get_group(commands).commands)

    return {"capture": (CAPTURE_SUMMARY, build), "sources": (SOURCES_SUMMARY, build)}


# capture's flags come from every installed source: capture and sources are built only
# when one of them runs, so the other commands and `recorder --help` load no source (nor
# the capture's writer).
app = new_app("recorder", help="Record Panda joint streams while a person touches the arm on "
              "cue, and manage the resulting sessions. Without a robot, sessions come from a "
              "physics simulation.", root_options=True,
              cls=deferred_commands(deferred_capture((EVENTS,))))


@app.command("simulate")
def simulate_command(
    ctx: typer.Context,
    out_dir: Annotated[Path, typer.Argument(help="Dataset directory (created if needed).")],
    preset: Annotated[Preset, typer.Option(help="Which sessions to draw.")] = "smoke",
    sessions: Annotated[int | None, typer.Option(
        help="How many sessions (default: the preset's size).")] = None,
    seed: Annotated[int, typer.Option(help="Dataset seed.")] = 0,
    workers: Annotated[int, typer.Option(help="Parallel processes.")] = DEFAULT_WORKERS,
    rate: Annotated[float | None, typer.Option(
        help="Sample rate [Hz] (default: the preset's, 600 for the thesis presets).")] = None,
    robot_seed: Annotated[int | None, typer.Option(
        help="Simulated robot instance (default: the preset's).")] = None,
    noise_scale: Annotated[float, typer.Option(help="Multiply the sensor noise.")] = 1.0,
    variability: Annotated[float | None, typer.Option(
        help="Spread of strength and tempo between simulated people (default: the "
             "preset's, 1 for most).")] = None,
    robot: Annotated[str, typer.Option(
        help="The simulated arm: panda, fr3 or another registered robot (`recorder "
             "robots`). Not --robot-seed, which picks an instance of it.")] = "panda",
    write_dynamics: Annotated[Path | None, typer.Option(
        metavar="FILE",
        help="Also write the simulated robot instance's true parameters (its perturbed "
             "link inertias and friction) as a dynamics file, the format of `recorder "
             "identify`: `--dynamics FILE` then gives the observer the plant's own model, "
             "the floor an identification can reach. An existing file is kept when it "
             "holds the same parameters, else refused.")] = None,
    dynamics: Annotated[Path | None, typer.Option(
        "--dynamics", metavar="FILE",
        help="Simulate this identified arm (`recorder identify`, or --write-dynamics of "
             "another run) instead of a random instance of the nominal one: its link "
             "inertias, friction and armature are the plant's, unperturbed; the training "
             "data of your own arm. Checked against --robot. Not with --robot-seed.")
                        ] = None,
) -> None:
    """Write many simulated sessions in parallel (existing ones are skipped) and index them.

    A session that fails is reported and the others are still written (exit code 2).
    """
    from contactkit.recorder.sim.dataset import simulate_dataset
    from contactkit.recorder.sim.simulator import ArmSimulator, SimConfig, load_simulated_arm
    from contactkit.robots import RobotSetup

    chosen = PRESETS[preset]
    identified = None if dynamics is None else load_simulated_arm(
        dynamics, RobotSetup(robot), robot_seed)
    config = SimConfig(rate_hz=rate or chosen.rate_hz, noise_scale=noise_scale, robot=robot,
                       robot_seed=chosen.robot_seed if robot_seed is None else robot_seed,
                       dynamics=identified)
    if write_dynamics is not None:
        _write_true_dynamics(write_dynamics, ArmSimulator(config).true_dynamics(
            {"preset": preset}))
    with progress_bar("simulating") as bar:
        result = simulate_dataset(output_directory(out_dir), preset, sessions, seed, workers,
                                  config, bar_callback(bar, "sessions"), variability,
                                  scheduler=scheduler_of(ctx))
    err_console.print(f"{result.written} written, {result.skipped} already there"
                      + (f", {len(result.failed)} failed" if result.failed else "")
                      + f"; index has {result.index.table.num_rows} sessions")
    print_problems(result.failed, "failed")
    print_problems(result.index.problems)
    print(printable(out_dir / "index.parquet"))
    if result.failed:
        raise typer.Exit(2)


register_catalog(app)


def _write_true_dynamics(path: Path, dynamics: Any) -> None:
    """Write a simulated instance's true dynamics to ``path``; an existing file with the
    same checksum is left as it is, another is refused."""
    from contactkit.robots.dynamics import load_dynamics, save_dynamics

    if path.exists():
        if load_dynamics(path).checksum != dynamics.checksum:
            raise InputError("exists and holds other parameters (another robot instance): "
                             "remove it or write elsewhere", path)
        return
    save_dynamics(path, dynamics)


@app.command("identify")
def identify_command(
    sessions: Annotated[list[Path], typer.Argument(
        help="Free-motion sessions (action none, or a contact column that is all false), "
             "files or directories; with --around-contacts or --cross-fitted, any "
             "sessions.")],
    out: Annotated[Path | None, typer.Option(
        help="Dynamics file to write (JSON); required unless --cross-fitted.")] = None,
    robot: RobotOpt = None,
    around_contacts: Annotated[bool, typer.Option(
        help="Use every session, with contact or not, outside the contacts the detector "
             "of --model finds with the nominal model (0.5 s before each to 1 s after "
             "it); what stands out of the held-out residuals (a touch it missed) is left "
             "out of the detector's calibration. For a dataset without free-motion "
             "recordings: identify its arm from the dataset itself.")] = False,
    cross_fitted: Annotated[bool, typer.Option(
        help="Identify a dataset's arm from the dataset itself, cross-fitted, and store "
             "it in the sessions: the poses are dealt into two halves, the arm is "
             "identified from each (around the contacts, as --around-contacts) and every "
             "session's metadata gets the arm (and detector) identified from the other "
             "half, as recorder set-robot --dynamics stores it. replay, classify and the "
             "catalog then use it; classify predict --events gives the events it gives "
             "when it identifies by itself. Rewrites the sessions' metadata (the samples "
             "are unchanged); no --out. Run again to redo it: stored dynamics are never "
             "read.")] = False,
    model: Annotated[Path | None, typer.Option(
        help="With --around-contacts or --cross-fitted: the model file whose detector "
             "finds the contacts (default: the default model, built once when "
             "missing).")] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing --out file.")] = False,
    workers: Annotated[int, typer.Option(
        help="With --cross-fitted: identify both halves at once, in two processes (any "
             "value over 1).")] = DEFAULT_WORKERS,
) -> None:
    """Identify the arm's own dynamics from free motion with nobody touching it: each
    link's mass, centre of mass and inertia, the payload at the flange, the joints'
    friction (Gaz et al.'s sigmoid, viscous and constant) and armature; then calibrate
    the contact detector on motion the fit did not see: with two sessions or more,
    each session's residual with the model identified from the others (the final fit
    uses them all); with one, its last quarter, held out. With --around-contacts, the
    free motion is what lies outside the contacts a detector finds in any session;
    --cross-fitted does so for each half of a dataset's poses and stores each half's
    arm in the other half's sessions.

    Only t, q, dq, tau and the arm's name are read (never a session's labels or contact
    column with --around-contacts). What the motion does not determine
    stays at the robot's nominal model; the output lists which parameters the data
    determine (exit 0). Exit 2, nothing written, when the motion determines nothing
    (too short, no joint moving), no session is free motion (none is usable with
    --around-contacts), or the sessions are of different arms. Sessions with contact
    (without --around-contacts), index.parquet and files that are not sessions are
    skipped, each with a line. Pass the file with --dynamics to replay,
    classify and recorder commands, or store it with sessions (recorder set-robot
    --dynamics).
    """
    from contactkit.features.identification import identify_sessions
    from contactkit.robots.dynamics import save_dynamics
    from contactkit.schemas.dataset import source_sessions

    if cross_fitted and out is not None:
        raise InputError("--cross-fitted stores each half's arm in the other half's "
                         "sessions: it writes no --out file")
    if out is None and not cross_fitted:
        raise InputError("give --out (the dynamics file to write), or --cross-fitted to "
                         "store the arm in the sessions")
    if out is not None:
        check_target(out, overwrite=overwrite)
    if model is not None and not (around_contacts or cross_fitted):
        raise InputError("--model is for --around-contacts or --cross-fitted: without "
                         "them, identification uses free-motion sessions only and finds no "
                         "contact")
    paths = source_sessions(sessions)
    problems: list[tuple[str, str]] = []
    finder = None  # the detector that finds the contacts to cut out
    if around_contacts or cross_fitted:
        from contactkit.cli.default_model import default_model_missing, model_or_default

        if model is None and default_model_missing():
            err_console.print("No --model given: building the default model once (its "
                              "detector finds the contacts); it is cached for next time.")
        with progress_bar() as bar:
            finder = model_or_default(model, labelled_progress(bar)).detector_config()
        if finder is None:
            raise InputError("the model carries no contact detector to find the contacts "
                             "with (train it with events)", model)
    if cross_fitted and finder is not None:
        _identify_cross_fitted(paths, finder, robot, problems, workers)
    elif out is not None:
        with progress_bar("identifying") as bar:
            result = identify_sessions(paths, robot, around_contacts=finder,
                                       problems=problems,
                                       progress=bar_callback(bar, "steps (read, fit, held out)"))
        print_problems(problems)
        save_dynamics(out, result.dynamics, overwrite=overwrite)
        _print_identified(str(out), result)
    exit_if_failed(problems)


def _identify_cross_fitted(paths: list[Path], finder: DetectorConfig, robot: str | None,
                           problems: list[tuple[str, str]], workers: int) -> None:
    """Identify the arm of the sessions ``paths`` from each half of their poses around
    the contacts ``finder`` finds (both at once with ``workers`` > 1), store each half's
    arm in the other half's sessions, print what each half determined; files that
    could not be read or rewritten are appended to ``problems``."""
    from contactkit.features.self_identification import cross_fitted_dynamics, survey

    surveyed = survey(paths, problems)
    print_problems(problems)
    with progress_bar() as bar:
        folds = cross_fitted_dynamics(surveyed, finder, robot, labelled_progress(bar),
                                      workers=workers)
    stored = len(problems)
    with progress_bar("storing the arms") as bar:
        callback = bar_callback(bar, "sessions")
        done, total = 0, sum(len(fold.scored) for fold in folds)
        for fold in folds:
            for path in fold.scored:
                try:
                    set_session_robot(path, robot, dynamics=fold.identified.dynamics)
                except DATA_ERRORS as err:
                    problems.append((str(path), problem_text(err)))
                done += 1
                callback(done, total)
    print_problems(problems[stored:])
    for k, fold in enumerate(folds, 1):
        _print_identified(f"half {k} of the poses ({len(fold.scored)} sessions, the arm "
                          f"identified from the other {len(fold.fitted)})", fold.identified)


def _print_identified(name: str, result: Identified) -> None:
    """Print what an identification determined (``name`` first: its file or its
    sessions): samples, parameters, residuals, payload and detector."""
    from contactkit.features.detector import dynamics_detector

    report, dynamics = result.excitation, result.dynamics
    print(f"{name}: {dynamics.robot} {'with' if dynamics.with_hand else 'without'} hand, "
          f"{report.samples} samples fitted (joints moving: {report.moving})")
    print(f"  determined: {len(report.determined)} of "
          f"{len(report.determined) + len(report.undetermined)} parameters, "
          f"{report.directions} directions, condition number {report.condition:.3g}")
    print(f"  left at the nominal model: {_short_list(report.undetermined)}")
    if report.projected:
        print(f"  links projected to be physically consistent: {report.projected}")
    print(f"  residual RMS [Nm] nominal {[round(v, 3) for v in report.rms_before_nm]}, "
          f"identified {[round(v, 3) for v in report.rms_after_nm]}")
    mass, hand = dynamics.payload.mass_kg, " and hand" if dynamics.with_hand else ""
    print(f"  payload at the flange (identified minus nominal link 7{hand}): {mass:+.3f} kg"
          + (" (lighter than its model)" if mass < 0 else ""))
    detector = dynamics_detector(dynamics)
    if detector is not None:
        held = detector.source.get("held_out", "?")
        dropped = detector.source.get("outliers", {}).get("dropped_share")
        if dropped is not None:
            held += f", {100 * dropped:.1f} % of its samples left out as outliers"
        print(f"  detector ({held}): at rest {[round(v, 2) for v in detector.noise]} Nm, per rad/s "
              f"{[round(v, 2) for v in detector.speed]}, per Nm of dynamic torque "
              f"{[round(v, 2) for v in detector.dynamic]}" + beyond_range_text(detector))


def _short_list(names: list[str], most: int = 12) -> str:
    """Return ``names`` joined, the first ``most`` and a count of the rest."""
    if not names:
        return "none"
    shown = ", ".join(names[:most])
    return shown if len(names) <= most else f"{shown} and {len(names) - most} more"


@app.command("excite")
def excite_command(
    robot: Annotated[str, typer.Option(
        help="The arm: panda, fr3, a plugin's name or urdf:PATH (`recorder robots` lists "
             "them and their limits).")],
    out: Annotated[Path, typer.Option(help="Trajectory file to write (CSV).")],
    pose: Annotated[Pose | None, typer.Option(
        help="Start and end pose (thesis Table 3.1; default A).")] = None,
    q0: Annotated[str | None, typer.Option(
        help="Start and end pose as 7 comma-separated joint angles [rad], instead of "
             "--pose.")] = None,
    duration: Annotated[float, typer.Option(
        help="Length [s], rounded to a whole number of periods.")] = 20.0,
    harmonics: Annotated[int, typer.Option(
        help="Sine and cosine terms per joint (3-12).")] = 5,
    base_frequency: Annotated[float, typer.Option(
        help="Base frequency [Hz]: the motion repeats at this rate, its terms at 1..K "
             "times it.")] = 0.1,
    seed: Annotated[int, typer.Option(help="Seed of the optimisation's random start.")] = 0,
    hand: Annotated[bool, typer.Option(
        "--hand/--no-hand", help="The arm carries its hand (its surface is kept clear).")
                    ] = True,
    preview: Annotated[Path | None, typer.Option(
        help="Also write a Rerun recording (.rrd): the arm's motion in 3-D and the joint "
             "curves against their limits.")] = None,
    overwrite: Annotated[bool, typer.Option(
        help="Replace an existing --out (and --preview) file.")] = False,
) -> None:
    """Write an exciting trajectory to identify the arm's dynamics from (`recorder
    identify`), and print the file's path.

    Each joint follows a finite Fourier series (Swevers et al. 1997) that starts and ends
    at rest (q, dq, ddq) at the pose. It stays within the arm's position, velocity,
    acceleration and jerk limits with a margin (10 % of the rates, 0.1 rad from the
    position limits, at every instant), 5 cm above the table and between links three
    or more joints apart (the arm's collision surfaces, the hand's included). Its
    coefficients minimise the condition number of the identification's base-parameter
    regressor (pinocchio's joint-torque regressor with viscous, Coulomb and offset
    friction columns), in a bounded time (about 10-20 s on one core).

    The file is CSV at 1 kHz: t [s], q_1..q_7 [rad], dq_1..dq_7 [rad/s], ddq_1..ddq_7
    [rad/s^2]. Run it with your own controller, which records the robot's states as it
    plays it (FCI admits one client, so `recorder capture --source franka` cannot
    connect meanwhile), then `recorder import` them (docs/howto/excite.md: franky and
    pylibfranka); or in simulation: `recorder capture --source sim --trajectory FILE
    --pose A --action none`. Hand-guided motion cannot replace it: the hand on the arm
    is an external force, which the identification would take for the arm's own
    dynamics.
    """
    from contactkit.recorder.excitation import (
        ExcitationSettings,
        excite,
        pose_from,
        write_preview,
    )
    from contactkit.recorder.trajectory import write_trajectory
    from contactkit.robots import RobotSetup, canonical_robot_name

    settings = ExcitationSettings(duration_s=duration, harmonics=harmonics,
                                  base_hz=base_frequency, seed=seed)
    start = pose_from(pose, q0)
    setup = RobotSetup(canonical_robot_name(robot), hand)
    check_target(out, overwrite=overwrite)
    if preview is not None:
        check_target(preview, overwrite=overwrite)
    with progress_bar("optimising") as bar:
        result = excite(setup, start, settings, bar_callback(bar, "iterations"))
    sampled = result.trajectory.sampled(setup.robot)
    err_console.print(
        f"condition number {result.condition_start:.0f} at the random start, "
        f"{result.condition:.0f} optimised ({result.base_parameters} base parameters, "
        f"{result.iterations} iterations, {result.seconds:.1f} s); "
        f"{settings.periods} periods of {settings.duration_s / settings.periods:.2f} s"
        + (f"; shrunk to {result.shrunk:.2f} of its amplitude to keep clear"
           if result.shrunk < 1.0 else ""),
        highlight=False)
    written = write_trajectory(out, sampled, overwrite=overwrite)
    if preview is not None:
        err_console.print(f"preview: {write_preview(preview, sampled, setup, overwrite=overwrite)}",
                          highlight=False)
    print(written)


@app.command("robots")
def robots_command() -> None:
    """List the robot models a session can name: built-in, installed plugins (the
    contactkit.robots entry-point group) and the urdf:PATH form, with their limits."""
    import numpy as np

    for name in robot_names():
        try:
            spec = get_robot(name)
        except InputError as err:
            print(f"{name}: cannot be loaded ({err.problem})")
            continue
        limits = spec.limits
        print(f"{name}: {spec.description}")
        print(f"  joints {', '.join(spec.joint_names)}")
        print(f"  q [rad] {np.round(limits.q_min, 4).tolist()} .. "
              f"{np.round(limits.q_max, 4).tolist()}")
        print(f"  dq max [rad/s] {np.round(limits.dq_max, 4).tolist()}; tau max [Nm] "
              f"{np.round(limits.tau_max, 1).tolist()}")
        print(f"  ddq max [rad/s^2] {np.round(limits.ddq_max, 2).tolist()}; jerk max "
              f"[rad/s^3] {np.round(limits.jerk_max, 0).tolist()}")
        print(f"  hand: {'yes' if spec.has_hand else 'no'}; friction model: "
              f"{'identified' if spec.friction else 'none'}; aliases: "
              f"{', '.join(spec.aliases) or '-'}")
    print(f"{URDF_PREFIX}PATH: any 7-joint serial arm from its URDF file (the session stores "
          "the file's SHA-256)")


@app.command("set-robot")
def set_robot_command(
    sessions: Annotated[list[Path], typer.Argument(help="Session files to correct.")],
    robot: Annotated[str | None, typer.Option(
        help="The arm they were recorded on: panda, fr3, a plugin's name or urdf:PATH "
             "(default: the arm each names).")] = None,
    dynamics: Annotated[Path | None, typer.Option(
        "--dynamics", metavar="FILE",
        help="Store the arm's identified dynamics (`recorder identify`) in each session's "
             "metadata, as values (not the file's path): every command then uses them "
             "unless its own --dynamics overrides them. Checked as the file is, and "
             "refused for another arm or hand.")] = None,
    clear_dynamics: Annotated[bool, typer.Option(
        "--clear-dynamics", help="Remove the stored dynamics: the nominal model again.")
                              ] = False,
) -> None:
    """Correct the robot a session names (for example FR3 sessions recorded with --source
    franka before sessions named their arm, which say franka_panda), or store the arm's
    identified dynamics with it. Each file's metadata is rewritten atomically (a
    symbolic link's target, keeping its permissions); its samples are unchanged. Naming
    another arm drops the dynamics stored for the old one."""
    if robot is None and dynamics is None and not clear_dynamics:
        raise InputError("give --robot, --dynamics or --clear-dynamics")
    if dynamics is not None and clear_dynamics:
        raise InputError("--dynamics and --clear-dynamics exclude each other")
    identified = load_dynamics_option(dynamics)
    for path in sessions:
        meta = set_session_robot(path, robot, dynamics=identified,
                                 clear_dynamics=clear_dynamics)
        err_console.print(f"{console_text(path)}: robot {console_text(meta.robot)}, "
                          f"{'identified dynamics' if meta.dynamics else 'nominal model'}")


@app.command("index")
def index_command(
    directory: Annotated[Path, typer.Argument(help="Dataset directory.")],
) -> None:
    """Rebuild DIR/index.parquet (one metadata row per session) from the session files."""
    from contactkit.schemas.dataset import rebuild_index

    result = rebuild_index(directory)
    err_console.print(f"{result.table.num_rows} sessions indexed")
    print_problems(result.problems)
    print(printable(directory / "index.parquet"))


@app.command("recover")
def recover_command(
    directory: Annotated[Path, typer.Argument(help="Directory with leftover journals.")],
) -> None:
    """Turn every leftover capture journal in DIR into a valid session marked as recovered.

    Each journal is handled and reported on its own; a journal is removed only after its
    session was read back and verified. Exit code 2 when some journal was left in place
    because it could not be recovered."""
    from contactkit.recorder.capture.journal import recover_directory

    recoveries = recover_directory(directory)
    if not recoveries:
        err_console.print("no journals to recover")
    for rec in recoveries:
        print(printable(f"{rec.session or rec.journal}: {rec.note}"))
    exit_if_failed([rec for rec in recoveries if rec.failed])


# The import command: its options, declared once. Protocol choices left out (None) come
# from the file where it states them, else from the metadata's defaults.
ImportFiles = Annotated[list[Path] | None, typer.Argument(
    metavar="FILE", show_default=False,
    help="Recordings, one session each; a directory imports every recording of --format "
         "in it (a ROS 2 bag folder is one recording).")]
FormatOption = Annotated[str | None, typer.Option(
    "--format", help="The files' format: csv, can, bag, arrays or a plugin's (`recorder "
                     "importers` lists them; default: from each file's suffix).")]
PoseOption = Annotated[Pose | None, typer.Option(help="Pose of the session (thesis Table "
                                                      "3.1), if the robot held one.")]
ActionOption = Annotated[Action | None, typer.Option(
    help="What the person did (default: none; a log with several touches keeps them in "
         "its contact column).")]
ConditionOption = Annotated[Condition | None, typer.Option(
    help="Protocol condition (default: static).")]
TargetPoseOption = Annotated[Pose | None, typer.Option(help="Dynamic: target pose.")]
PlannedAtOption = Annotated[float | None, typer.Option(
    help="Planned interaction time [s from the first sample] (a bag's label topic gives "
         "one).")]
LinkOption = Annotated[int | None, typer.Option(help="Touched link 1-7.")]
OperatorOption = Annotated[str | None, typer.Option(help="Who touched the robot.")]
HandOption = Annotated[bool | None, typer.Option(
    "--hand/--no-hand", help="The robot carried its hand (default: yes).")]
RobotOption = Annotated[str | None, typer.Option(
    help="The arm: panda, fr3, a plugin's name or urdf:PATH (`recorder robots` lists "
         "them; default: the map's, else panda).")]
NotesOption = Annotated[str | None, typer.Option(help="Free text stored in the metadata.")]
MetaOption = Annotated[list[str] | None, typer.Option(
    help="Any other metadata field KEY=VALUE (repeatable), e.g. speed_rad_s=0.5, "
         "pose_q=[...], session_id=...; values read as JSON where they can be.")]
MapOption = Annotated[Path | None, typer.Option(
    "--map", help="csv: column map TOML (required; example for the MindLab ZHAW files: "
                  "recorder/data/mindlab_csv_map.toml). can: frame map TOML (default: "
                  "CANopen CiA 402).")]
TopicOption = Annotated[str | None, typer.Option(
    help="bag: joint-state topic (FrankaState, FrankaRobotState or JointState; default: "
         "the usual franka_ros/franka_ros2 topics).")]
LabelTopicOption = Annotated[str | None, typer.Option(
    help="bag: std_msgs/String or Bool topic of labels or cue events: String events are "
         "stored with their times (the first is the planned time), Bool is the "
         "ground-truth contact.")]
ArraysTOption = Annotated[Path | None, typer.Option(
    "--t", help="arrays: time stamps [s], one per line (the FILE of --format arrays).")]
ArraysQOption = Annotated[Path | None, typer.Option(
    "--q", help="arrays: joint positions [rad], 7 values a line or one per line.")]
ArraysDqOption = Annotated[Path | None, typer.Option(
    "--dq", help="arrays: joint velocities [rad/s].")]
ArraysTauOption = Annotated[Path | None, typer.Option(
    "--tau", help="arrays: measured joint torques [Nm].")]
FormatOptionPairs = Annotated[list[str] | None, typer.Option(
    "--option", help="A format's own option NAME=VALUE (repeatable), for plugins "
                     "(`recorder importers` lists each format's options).")]
NameOption = Annotated[str | None, typer.Option(
    help="Output file name (one FILE only; default: from the metadata).")]
OutOption = Annotated[Path, typer.Option(help="Output directory.")]
OverwriteOption = Annotated[bool, typer.Option(help="Replace an existing session file.")]
WorkersOption = Annotated[int, typer.Option(help="Parallel processes for several files.")]
IMPORT_ALIASES = {"import-csv": "csv", "import-can": "can", "import-bag": "bag",
                  "import-arrays": "arrays"}
"""The import verbs of earlier versions: each is `recorder import --format FORMAT`."""
NAMED_FORMAT_OPTIONS = ("map", "topic", "label_topic", "q", "dq", "tau")
"""The format options `recorder import` offers as flags of their own."""


def import_command(
    ctx: typer.Context,
    files: ImportFiles = None,
    fmt: FormatOption = None,
    pose: PoseOption = None,
    action: ActionOption = None,
    condition: ConditionOption = None,
    target_pose: TargetPoseOption = None,
    planned_at: PlannedAtOption = None,
    link: LinkOption = None,
    operator: OperatorOption = None,
    hand: HandOption = None,
    robot: RobotOption = None,
    notes: NotesOption = None,
    meta: MetaOption = None,
    column_or_frame_map: MapOption = None,
    topic: TopicOption = None,
    label_topic: LabelTopicOption = None,
    t: ArraysTOption = None,
    q: ArraysQOption = None,
    dq: ArraysDqOption = None,
    tau: ArraysTauOption = None,
    option: FormatOptionPairs = None,
    name: NameOption = None,
    out: OutOption = Path("sessions"),
    overwrite: OverwriteOption = False,
    workers: WorkersOption = DEFAULT_WORKERS,
) -> None:
    """Turn recordings of other tools into validated sessions, one per file, and print
    their paths.

    The format comes from each file's suffix (.csv; .asc, .blf, .trc, .log, .mf4, .db;
    .bag, .mcap, .db3 or a ROS 2 bag folder) or from --format; `recorder importers`
    lists the formats, plugins included, and their options. Every format streams
    through one writer in bounded memory. Several files import in parallel; one that
    fails is reported and the others are still written (exit code 2).
    """
    from contactkit.recorder.importers.jobs import (
        checked_meta,
        format_options,
        import_file,
        import_files,
        import_jobs,
        protocol_from,
    )

    alias = IMPORT_ALIASES.get(ctx.info_name or "")
    if alias is not None and fmt not in (None, alias):
        raise InputError(f"{ctx.info_name} reads format {alias}; for {fmt} use "
                         f"`recorder import --format {fmt}`")
    fmt = fmt or alias or ("arrays" if t is not None else None)
    paths = [*(files or []), *([] if t is None else [t])]
    if not paths:
        raise InputError("give the files to import" + (" (--t for arrays)" if fmt == "arrays"
                                                       else ""))
    protocol = protocol_from({
        "pose": pose, "action": action, "condition": condition, "target_pose": target_pose,
        "planned_at_s": planned_at, "link": link, "operator": operator, "with_hand": hand,
        "robot": robot, "notes": notes}, meta or [])
    checked_meta({"action": "none", "source": "import", **protocol})
    options = format_options({"map": column_or_frame_map, "topic": topic,
                              "label_topic": label_topic, "q": q, "dq": dq, "tau": tau},
                             option or [])
    jobs = import_jobs(paths, fmt, output_directory(out), protocol=protocol,
                       options=options, name=name, overwrite=overwrite)
    if len(jobs) == 1:
        _report_import(import_file(jobs[0]))
        return
    with progress_bar("importing") as bar:
        imported, problems = import_files(jobs, workers, bar_callback(bar, "files"),
                                          scheduler=scheduler_of(ctx))
    for result in imported:
        _report_import(result)
    err_console.print(f"{len(imported)} of {len(jobs)} files imported")
    print_problems(problems)
    exit_if_failed(problems)


def _report_import(result: Imported) -> None:
    err_console.print(f"{result.recording}: {result.summary}", markup=False, highlight=False)
    print(printable(result.session))


app.command("import")(import_command)
for _alias, _format in IMPORT_ALIASES.items():
    app.command(_alias, help=f"Alias of `recorder import --format {_format}` (the verb of "
                             "earlier versions; same options).")(import_command)


@app.command("importers")
def importers_command() -> None:
    """List the import formats: built-in, installed plugins (the contactkit.importers
    entry-point group), with the suffixes each claims and its options."""
    from contactkit.recorder.importers.registry import load_importers, registered_importers
    from contactkit.util.params import dataclass_params

    classes, problems = load_importers()
    for fmt in registered_importers():
        if fmt in problems:
            print(f"{fmt}: unusable ({problems[fmt]})")
            continue
        cls = classes[fmt]
        suffixes = f" ({', '.join(cls.suffixes)})" if cls.suffixes else ""
        print(f"{fmt}: {cls.description or cls.__doc__}{suffixes}")
        for param in dataclass_params(cls.Config):
            key = param.option.removeprefix("--").replace("-", "_")
            flag = param.option if key in NAMED_FORMAT_OPTIONS else f"--option {key}=VALUE"
            print(f"  {flag}  {param.describe()}")


@app.command("stats")
def stats_command(
    ctx: typer.Context,
    directory: Annotated[Path, typer.Argument(help="Dataset directory.")],
    out: Annotated[Path | None, typer.Option(
        help="Report file (default: report.html, report.md or report.json here).")] = None,
    fmt: Annotated[ReportFormat, typer.Option(
        "--format", help="html (one self-contained file), md (with PNGs beside it) or "
                         "json.")] = "html",
    deep: Annotated[bool, typer.Option(
        help="Read every session (parallel): sampling, noise baseline, peaks, force "
             "profiles, windows, joint limits, and a fingerprint over file contents.")
                    ] = False,
    workers: Annotated[int, typer.Option(help="Parallel processes for --deep.")
                       ] = DEFAULT_WORKERS,
    overwrite: Annotated[bool, typer.Option(
        help="Replace an existing --out report (the default report is replaced only "
             "when stats wrote it).")] = False,
    catalog: Annotated[Path | None, typer.Option(
        help="The dataset's Rerun catalog (recorder catalog): the report links each "
             "session to its recording there. Default: DATASET-catalog beside the "
             "dataset, where it exists.")] = None,
    dynamics: DynamicsOpt = None,
) -> None:
    """Summarise a dataset on the terminal and write a report of what it holds and of
    its problems (bad files, duplicates, sessions too short)."""
    from contactkit.recorder.stats.report import (
        OWNED_REPORT,
        print_summary,
        report_path,
        write_report,
    )
    from contactkit.recorder.stats.summary import build_report, write_noise_file

    identified = load_dynamics_option(dynamics)
    if identified is not None and not deep:
        raise InputError("--dynamics needs --deep (only the deep report computes residuals)")
    default = out is None
    out = report_path(out or Path(f"report.{fmt}"), fmt)
    check_target(out, overwrite=overwrite, owned=OWNED_REPORT if default else None)
    with progress_bar("reading", disable=not deep) as bar:
        report = build_report(directory, deep, workers, bar_callback(bar, "sessions"),
                              scheduler=scheduler_of(ctx), dynamics=identified)
    print_summary(report, err_console)
    noise = report["deep"] and report["deep"]["noise_baseline"]
    if noise:
        noise_path = write_noise_file(out.with_name(f"{out.stem}_noise.json"), noise,
                                      directory, overwrite=overwrite, default=default)
        err_console.print(f"noise baseline for the simulator: {noise_path} "
                          "(recorder capture --noise-file)")
    if catalog is None and catalog_beside(directory).is_dir():
        catalog = catalog_beside(directory)
    elif catalog is not None and not catalog.is_dir():
        raise InputError("catalog folder not found", catalog)
    print(write_report(report, out, fmt, overwrite=overwrite, default=default,
                       catalog=catalog))


@app.command("export-mcap")
def export_mcap_command(
    session: Annotated[Path, typer.Argument(help="Session file (.parquet).")],
    out: Annotated[Path | None, typer.Option(
        help="Where to write: a name ending in .mcap is one MCAP file; any other name is a "
             "ROS 2 bag directory (rosbag2's convention: metadata.yaml and NAME.mcap "
             "inside; default: the session's name without suffix, beside it).")] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing file or bag directory.")
                         ] = False,
    dynamics: DynamicsOpt = None,
) -> None:
    """Write a session as MCAP (JointState, WrenchStamped) for Foxglove, PlotJuggler or
    the Rerun viewer; print the .mcap file's path. `recorder import` reads it back. The
    metadata it carries holds the session's identified dynamics, or --dynamics' in
    their place."""
    from contactkit.recorder.importers.mcap_export import export_mcap

    print(printable(export_mcap(session, out or session.with_suffix(""),
                                overwrite=overwrite,
                                dynamics=load_dynamics_option(dynamics))))


@app.command("can-bridge")
def can_bridge_command(
    session: Annotated[Path, typer.Argument(help="Session file to publish.")],
    interface: Annotated[str, typer.Option(help="python-can interface.")] = "socketcan",
    channel: Annotated[str | None, typer.Option(help="Bus channel.")] = None,
    can_map: Annotated[Path | None, typer.Option(
        "--map", help="Frame map TOML (default: CANopen CiA 402).")] = None,
    rate: Annotated[float | None, typer.Option(
        help="Pace at this multiple of real time (bus default 1; log default: as fast as "
             "possible).")] = None,
    log: Annotated[Path | None, typer.Option(
        help="Write the frames to this log (.asc, .blf, .trc, .csv, .log, .db) instead "
             "of a bus.")] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing --log file.")] = False,
) -> None:
    """Publish a recorded or simulated session onto a CAN bus per the frame map (or into
    a CAN log), to test a CAN setup end to end without a robot."""
    from contactkit.recorder.importers.can_map import load_map
    from contactkit.recorder.importers.can_tools import bridge_session
    from contactkit.recorder.sources.can import BusConfig

    if log is None and not channel:
        raise InputError("give --channel (and --interface) for a bus, or --log FILE")
    if log is not None:
        check_target(log, overwrite=overwrite)
    recorded = read_session(session)
    # without a log, the channel was given (checked above)
    bus = None if log is not None else BusConfig(interface, cast(str, channel))
    sent = bridge_session(recorded, load_map(can_map), bus=bus, log=log, rate=rate,
                          overwrite=overwrite)
    err_console.print(f"{sent} frames ({recorded.n_samples} samples) sent"
                      + (f" to {log}" if log else f" on {interface}:{channel}"))


@app.command("info")
def info_command(
    session: Annotated[Path, typer.Argument(help="Session file (.parquet).")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead.")] = False,
) -> None:
    """Show a session's metadata, duration, measured rate, gaps and ground truth."""
    from rich.console import Console

    from contactkit.recorder.info import print_info, session_info

    info = session_info(session)
    if as_json:
        print(json.dumps(info, indent=2, default=str))
    else:
        print_info(info, Console())


def main() -> None:
    """Entry point of the ``recorder`` console script."""
    sys.exit(run_app(app, "recorder"))
