"""The ``recorder`` command: capture sessions, build datasets, recover, inspect."""

from __future__ import annotations

import json
import os
import secrets
import sys
import tempfile
from pathlib import Path
from typing import Annotated

import rerun as rr
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from contactkit.recorder.can_map import load_map
from contactkit.recorder.can_tools import bridge_session, import_can_log
from contactkit.recorder.capture import (
    OperatorCue,
    capture,
    protocol_meta,
    session_filename,
    sim_session_meta,
)
from contactkit.recorder.dataset import PRESETS, simulate_dataset
from contactkit.recorder.importer import import_arrays
from contactkit.recorder.info import session_info
from contactkit.recorder.journal import recover_directory
from contactkit.recorder.live_view import CaptureViewer
from contactkit.recorder.noise import SensorNoise, default_noise
from contactkit.recorder.sim import SimConfig, plan_session
from contactkit.recorder.sources import SOURCES, source_class
from contactkit.recorder.sources.can import BusConfig, CanSource, Cue
from contactkit.recorder.stats import build_report, write_noise_file
from contactkit.recorder.stats_report import FORMATS, print_summary, write_report
from contactkit.schemas import ACTIONS, InputError, SessionMeta, read_session, validate_session
from contactkit.schemas.dataset import rebuild_index
from contactkit.schemas.rerun_layout import capture_blueprint
from contactkit.util.cli import run_app
from contactkit.util.viewer import has_display, start_web_viewer

app = typer.Typer(
    name="recorder",
    help="Record Panda joint streams while a person touches the arm on cue, and manage the "
         "resulting sessions. Without a robot, sessions come from a physics simulation.",
    no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False)
err_console = Console(stderr=True)
DEFAULT_WORKERS = max(os.cpu_count() or 1, 1)


def _out_dir(path: Path) -> Path:
    """Create the output directory and prove it writable (a read-only mount, missing
    permission, a full disk) before any source, robot or bus is started."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot create output directory ({err.strerror})", path) from err
    try:
        with tempfile.TemporaryFile(dir=path) as probe:
            probe.write(b"\0")
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as err:
        raise InputError(f"cannot write here ({err.strerror or err})", path) from err
    return path


def _sim_config(rate: float, with_hand: bool, robot_seed: int, noise_file: Path | None,
                noise_scale: float, jitter_ms: float, drop_prob: float) -> SimConfig:
    noise = default_noise() if noise_file is None else SensorNoise.from_file(noise_file)
    if noise_scale < 0:
        raise InputError(f"--noise-scale must be >= 0, got {noise_scale}")
    return SimConfig(rate_hz=rate, with_hand=with_hand, robot_seed=robot_seed, noise=noise,
                     noise_scale=noise_scale, jitter_s=jitter_ms / 1000.0, drop_prob=drop_prob)


@app.command("capture")
def capture_command(
    pose: Annotated[str, typer.Option(help="Start pose, A-H (thesis Table 3.1).")],
    action: Annotated[str, typer.Option(help=f"What the person does: {', '.join(ACTIONS)}.")],
    condition: Annotated[str, typer.Option(
        help="static: hold the pose; dynamic: move to --target-pose.")] = "static",
    target_pose: Annotated[str | None, typer.Option(
        help="Dynamic condition: pose to move to (default D).")] = None,
    speed: Annotated[float | None, typer.Option(
        help="Dynamic condition: average speed of the furthest-moving joint [rad/s] "
             "(default 0.2).")] = None,
    link: Annotated[int | None, typer.Option(
        help="Link 1-7 to touch (default: random for a contact).")] = None,
    planned_at: Annotated[float | None, typer.Option(
        help="Planned interaction time [s from start] (default: thesis timing, 5 s "
             "static, mid-motion dynamic).")] = None,
    duration: Annotated[float | None, typer.Option(
        help="Session length [s] (default: 3 s hold + 4 s or the motion + 5 s hold).")] = None,
    rate: Annotated[float, typer.Option(help="Sample rate [Hz] (thesis: ~600).")] = 1000.0,
    operator: Annotated[str, typer.Option(
        help="Who touches the robot; in simulation, names a person with their own "
             "strength and tempo.")] = "sim",
    seed: Annotated[int | None, typer.Option(
        help="Random seed; the same seed gives the same data (default: random, stored in "
             "the metadata).")] = None,
    out: Annotated[Path, typer.Option(help="Output directory (created if needed).")] = Path(
        "sessions"),
    source: Annotated[str, typer.Option(
        help=f"Data source: {', '.join(SOURCES)} (sim: the simulated Panda; can: a CAN bus "
             "decoded with --map).")] = "sim",
    realtime: Annotated[bool, typer.Option(
        help="Pace the capture at wall-clock speed and show the operator cue "
             "(countdown, then a bell at the planned time).")] = False,
    hand: Annotated[bool, typer.Option(help="Simulate the Panda with its hand mounted.")] = True,
    robot_seed: Annotated[int, typer.Option(
        help="Simulated robot instance (its true inertia and friction).")] = 0,
    noise_file: Annotated[Path | None, typer.Option(
        help="Sensor-noise JSON (from `recorder stats --deep`); default: measured on the "
             "real Panda reference recording.")] = None,
    noise_scale: Annotated[float, typer.Option(help="Multiply the sensor noise.")] = 1.0,
    jitter_ms: Annotated[float, typer.Option(help="Time-stamp jitter, uniform +- [ms].")] = 0.0,
    drop_prob: Annotated[float, typer.Option(help="Probability of losing a sample.")] = 0.0,
    notes: Annotated[str, typer.Option(help="Free text stored in the metadata.")] = "",
    overwrite: Annotated[bool, typer.Option(
        help="Replace an existing session file with the same name.")] = False,
    viewer: Annotated[str, typer.Option(
        help="Show the capture live: rerun (native viewer), web (browser, 127.0.0.1) or "
             "none.")] = "none",
    save_rrd: Annotated[Path | None, typer.Option(
        help="Also write the live view to this .rrd file.")] = None,
    interface: Annotated[str, typer.Option(
        help="--source can: python-can interface (virtual, socketcan, pcan, kvaser, ...).")
                         ] = "socketcan",
    channel: Annotated[str | None, typer.Option(
        help="--source can: bus channel, e.g. can0.")] = None,
    can_map: Annotated[Path | None, typer.Option(
        "--map", help="--source can: frame map TOML (default: CANopen CiA 402, "
                      "recorder/data/can_default_map.toml).")] = None,
    timeout: Annotated[float, typer.Option(
        help="--source can: end the capture when the bus is silent this long [s].")] = 1.0,
    cue_id: Annotated[str | None, typer.Option(
        help="--source can: send a cue frame with this id (e.g. 0x700) at the planned "
             "time, for a lamp or buzzer; its bus time goes into the metadata.")] = None,
    cue_data: Annotated[str, typer.Option(help="Cue frame payload, hex.")] = "01",
) -> None:
    """Record one session and print the written file's path.

    Example: recorder capture --pose B --action adjust
    """
    source_class(source)
    if source == "can":
        planned = 5.0 if planned_at is None else planned_at
        total = 12.0 if duration is None else duration
        if total <= 0 or not 0 <= planned < total:
            raise InputError(f"planned interaction time {planned} s must lie within the "
                             f"session (0 to {total} s)")
        if not channel:
            raise InputError("--source can needs --channel (and --interface)")
        fmap = load_map(can_map)
        cue_frame = None if cue_id is None else Cue(int(cue_id, 0), bytes.fromhex(cue_data),
                                                    planned)
        chosen = CanSource(BusConfig(interface, channel), fmap, total, timeout, cue_frame)
        meta = protocol_meta(source="can", action=action, condition=condition, pose=pose,
                             target_pose=target_pose, speed_rad_s=speed, link=link,
                             planned_at_s=planned, operator=operator, with_hand=hand,
                             notes=notes)
        rate_hz = rate
    else:
        seed = secrets.randbits(63) if seed is None else seed
        config = _sim_config(rate, hand, robot_seed, noise_file, noise_scale, jitter_ms,
                             drop_prob)
        spec = plan_session(seed=seed, condition=condition, action=action, pose=pose,
                            target_pose=target_pose, speed_rad_s=speed, link=link,
                            planned_at_s=planned_at, duration_s=duration, operator=operator,
                            with_hand=hand)
        chosen = source_class(source)(spec, config)
        meta = sim_session_meta(spec, config, chosen.metadata())
        meta.notes = notes
        planned, total, rate_hz = spec.planned_at_s, spec.duration_s, config.rate_hz
    out_path = _out_dir(out) / session_filename(meta)
    if out_path.exists() and overwrite:
        out_path.unlink()
    live = _live_view(viewer, save_rrd, meta, rate_hz)
    cue = None
    if realtime or live is not None or chosen.live:
        err_console.print(f"[bold]Recording[/] {meta.condition} pose {meta.pose}, "
                          f"{meta.action} at {planned:.2f} s of {total:.1f} s")
        cue = OperatorCue(planned, meta.action, meta.link,
                          echo=None if live is None else live.cue)
    result = capture(chosen, meta, out_path, realtime=realtime, cue=cue,
                     on_chunk=None if live is None else [live.on_chunk])
    if live is not None:
        live.rec.flush()
        live.rec.disconnect()
    print(result.path)


def _live_view(viewer: str, save_rrd: Path | None, meta: SessionMeta,
               rate_hz: float) -> CaptureViewer | None:
    """Return a live Rerun view of the capture (None for --viewer none without --save-rrd)."""
    if viewer not in ("rerun", "web", "none"):
        raise InputError(f"unknown viewer {viewer!r} (expected rerun, web or none)")
    if viewer == "none" and save_rrd is None:
        return None
    rec = rr.RecordingStream("contactkit-capture", recording_id=meta.session_id)
    blueprint = capture_blueprint()
    if save_rrd is not None:
        rec.save(save_rrd, default_blueprint=blueprint)
    if viewer == "rerun":
        if has_display():
            rec.spawn(default_blueprint=blueprint)
        else:
            err_console.print("no display for the native viewer; use --viewer web or "
                              "--save-rrd")
    elif viewer == "web":
        _, url, page = start_web_viewer()
        err_console.print(f"web viewer: {page}")
        rec.connect_grpc(url, default_blueprint=blueprint)
    return CaptureViewer(rec, meta, rate_hz)


@app.command("simulate")
def simulate_command(
    out_dir: Annotated[Path, typer.Argument(help="Dataset directory (created if needed).")],
    preset: Annotated[str, typer.Option(help=f"One of {', '.join(PRESETS)}.")] = "smoke",
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
) -> None:
    """Write many simulated sessions in parallel (existing ones are skipped) and index them.

    A session that fails is reported and the others are still written (exit code 2).
    """
    if preset not in PRESETS:
        raise InputError(f"unknown preset {preset!r} (available: {', '.join(PRESETS)})")
    chosen_robot = PRESETS[preset].robot_seed if robot_seed is None else robot_seed
    config = _sim_config(rate or PRESETS[preset].rate_hz, True, chosen_robot, None, noise_scale,
                         0.0, 0.0)
    with Progress(TextColumn("[bold]simulating[/]"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=err_console) as bar:
        task = bar.add_task("sessions", total=None)
        result = simulate_dataset(_out_dir(out_dir), preset, sessions, seed, workers, config,
                                  lambda done, total: bar.update(task, completed=done,
                                                                 total=total),
                                  variability)
    err_console.print(f"{result.written} written, {result.skipped} already there"
                      + (f", {len(result.failed)} failed" if result.failed else "")
                      + f"; index has {result.index.table.num_rows} sessions")
    for name, problem in result.failed:
        err_console.print(f"[red]failed[/] {name}: {problem}")
    _print_problems(result.index.problems)
    print(out_dir / "index.parquet")
    if result.failed:
        raise typer.Exit(2)


@app.command("index")
def index_command(
    directory: Annotated[Path, typer.Argument(help="Dataset directory.")],
) -> None:
    """Rebuild DIR/index.parquet (one metadata row per session) from the session files."""
    result = rebuild_index(directory)
    err_console.print(f"{result.table.num_rows} sessions indexed")
    _print_problems(result.problems)
    print(directory / "index.parquet")


@app.command("recover")
def recover_command(
    directory: Annotated[Path, typer.Argument(help="Directory with leftover journals.")],
) -> None:
    """Turn every leftover capture journal in DIR into a valid session marked as recovered."""
    recoveries = recover_directory(directory)
    if not recoveries:
        err_console.print("no journals to recover")
    for rec in recoveries:
        print(f"{rec.session or rec.journal}: {rec.note}")


@app.command("import-arrays")
def import_arrays_command(
    t: Annotated[Path, typer.Option("--t", help="Time stamps [s], one per line.")],
    q: Annotated[Path, typer.Option("--q", help="Joint positions [rad].")],
    dq: Annotated[Path, typer.Option("--dq", help="Joint velocities [rad/s].")],
    tau: Annotated[Path, typer.Option("--tau", help="Measured joint torques [Nm].")],
    out: Annotated[Path, typer.Option(help="Output directory.")],
    meta: Annotated[list[str] | None, typer.Option(
        help="Metadata KEY=VALUE (repeatable), e.g. action=none, with_hand=false, "
             "planned_at_s=10, pose=A, operator=lab1, notes=...")] = None,
    name: Annotated[str | None, typer.Option(help="Output file name (default from the "
                                                   "metadata).")] = None,
) -> None:
    """Turn plain arrays (text, CSV or .npy) into a validated session; print its path.

    Joint files hold 7 values per line, or one per line (7 lines a sample); the time
    file one value per line. Time is shifted to start at 0 s.
    """
    session_path = import_arrays(t, q, dq, tau, _out_dir(out), meta or [], name)
    print(session_path)


@app.command("stats")
def stats_command(
    directory: Annotated[Path, typer.Argument(help="Dataset directory.")],
    out: Annotated[Path | None, typer.Option(
        help="Report file (default: report.html, report.md or report.json here).")] = None,
    fmt: Annotated[str, typer.Option("--format", help="html (one self-contained file), md "
                                                      "(with PNGs beside it) or json.")
                   ] = "html",
    deep: Annotated[bool, typer.Option(
        help="Read every session (parallel): sampling, noise baseline, peaks, force "
             "profiles, windows, joint limits, and a fingerprint over file contents.")
                    ] = False,
    workers: Annotated[int, typer.Option(help="Parallel processes for --deep.")
                       ] = DEFAULT_WORKERS,
) -> None:
    """Summarise a dataset on the terminal and write a report of what it holds and of
    its problems (bad files, duplicates, sessions too short)."""
    if fmt not in FORMATS:
        raise InputError(f"unknown format {fmt!r} (expected html, md or json)")
    out = out or Path(f"report.{fmt}")
    if not out.parent.is_dir():
        raise InputError("output directory does not exist", out.parent)
    with Progress(TextColumn("[bold]reading sessions[/]"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=err_console, disable=not deep) as bar:
        task = bar.add_task("sessions", total=None)
        report = build_report(directory, deep, workers,
                              lambda done, total: bar.update(task, completed=done, total=total))
    print_summary(report, err_console)
    noise = report["deep"] and report["deep"]["noise_baseline"]
    if noise:
        noise_path = write_noise_file(out.with_name(f"{out.stem}_noise.json"), noise,
                                      directory)
        err_console.print(f"noise baseline for the simulator: {noise_path} "
                          "(recorder capture --noise-file)")
    print(write_report(report, out, fmt))


@app.command("import-can")
def import_can_command(
    log: Annotated[Path, typer.Argument(help="CAN log: .asc, .blf, .trc, .csv, .log "
                                             "(candump), .mf4 (with asammdf), .db (SQLite).")],
    pose: Annotated[str, typer.Option(help="Pose A-H of the session.")],
    action: Annotated[str, typer.Option(help=f"Action: {', '.join(ACTIONS)}.")],
    can_map: Annotated[Path | None, typer.Option(
        "--map", help="Frame map TOML (default: CANopen CiA 402).")] = None,
    planned_at: Annotated[float | None, typer.Option(
        help="Planned interaction time [s from the first sample].")] = None,
    condition: Annotated[str, typer.Option(help="static or dynamic.")] = "static",
    target_pose: Annotated[str | None, typer.Option(help="Dynamic: target pose.")] = None,
    link: Annotated[int | None, typer.Option(help="Touched link 1-7.")] = None,
    operator: Annotated[str, typer.Option(help="Who touched the robot.")] = "",
    hand: Annotated[bool, typer.Option(help="The robot carried its hand.")] = True,
    out: Annotated[Path, typer.Option(help="Output directory.")] = Path("sessions"),
) -> None:
    """Convert a CAN log into a validated session and print its path."""
    fmap = load_map(can_map)
    meta = protocol_meta(source="can-log", action=action, condition=condition, pose=pose,
                         target_pose=target_pose, speed_rad_s=None, link=link,
                         planned_at_s=planned_at, operator=operator, with_hand=hand)
    directory = _out_dir(out)
    path = import_can_log(log, fmap, meta, directory, session_filename(meta))
    info = validate_session(path).meta.source_info
    err_console.print(f"{info['samples']} samples from {info['frames']} frames; "
                      f"{info['incomplete_samples']} incomplete, {info['lost_syncs']} lost "
                      f"SYNCs, {info['unknown_ids']} unknown ids, {info['bad_lengths']} bad "
                      f"lengths, {info['duplicates']} duplicates")
    print(path)


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
) -> None:
    """Publish a recorded or simulated session onto a CAN bus per the frame map (or into
    a CAN log), to test a CAN setup end to end without a robot."""
    if rate is not None and rate <= 0:
        raise InputError(f"--rate must be positive, got {rate}")
    if log is None and not channel:
        raise InputError("give --channel (and --interface) for a bus, or --log FILE")
    fmap = load_map(can_map)
    recorded = read_session(session)
    bus = None if log is not None else BusConfig(interface, channel)
    sent = bridge_session(recorded, fmap, bus=bus, log=log, rate=rate)
    err_console.print(f"{sent} frames ({recorded.n_samples} samples) sent"
                      + (f" to {log}" if log else f" on {interface}:{channel}"))


@app.command("info")
def info_command(
    session: Annotated[Path, typer.Argument(help="Session file (.parquet).")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead.")] = False,
) -> None:
    """Show a session's metadata, duration, measured rate, gaps and ground truth."""
    info = session_info(session)
    if as_json:
        print(json.dumps(info, indent=2, default=str))
        return
    console = Console()
    meta, s = info["metadata"], info["sampling"]
    table = Table(title=str(session), show_header=False, title_justify="left")
    for key in ("session_id", "source", "condition", "pose", "target_pose", "speed_rad_s",
                "action", "link", "planned_at_s", "operator", "with_hand", "recovered",
                "recovered_samples", "created_utc", "notes"):
        if meta.get(key) not in (None, ""):
            table.add_row(key, str(meta[key]))
    table.add_row("samples", str(s["samples"]))
    table.add_row("duration", f"{s['duration_s']:.3f} s")
    table.add_row("rate", f"{s['rate_hz']:.1f} Hz (median step {s['median_step_s'] * 1e3:.3f} "
                          f"ms, min {s['min_step_s'] * 1e3:.3f}, max {s['max_step_s'] * 1e3:.3f})")
    table.add_row("gaps", f"{s['gaps']} longer than 3x median (~{s['dropped_estimate']} "
                          "samples missing)")
    if info["contact_interval_s"]:
        lo, hi = info["contact_interval_s"]
        table.add_row("contact", f"{lo:.3f} s to {hi:.3f} s, peak {info['peak_force_n']:.1f} N")
    elif info["peak_force_n"] is not None:
        table.add_row("contact", "none")
    console.print(table)


def _print_problems(problems: list[tuple[str, str]]) -> None:
    for name, problem in problems:
        err_console.print(f"[yellow]skipped[/] {name}: {problem}")


def main() -> None:
    """Entry point of the ``recorder`` console script."""
    sys.exit(run_app(app, "recorder"))
