"""The ``recorder catalog``, ``recorder query`` and ``recorder browse`` commands: a
dataset as a Rerun catalog.

A thin layer over :mod:`contactkit.replay.catalog` (build), :mod:`contactkit.replay.query`
(read-only SQL) and :mod:`contactkit.replay.browse` (the catalog server and a viewer):
options, the default model, progress and messages. The libraries are imported when a
command runs, so that ``recorder --help`` loads none of them.
"""

from __future__ import annotations

import json
import signal
import threading
from pathlib import Path
from typing import Annotated, Literal, cast

import typer

from contactkit.cli.common import (
    DynamicsOpt,
    RobotOpt,
    load_dynamics_option,
    print_problems,
    scheduler_of,
)
from contactkit.errors import InputError
from contactkit.util.parallel import available_cpus
from contactkit.util.paths import catalog_beside
from contactkit.util.progress import bar_callback, err_console, labelled_progress, progress_bar
from contactkit.util.text import console_text, printable

DEFAULT_WORKERS = available_cpus()
ViewerChoice = Literal["auto", "native", "web", "none"]


def build(dataset: Path, out: Path, model: Path | None, workers: int, overwrite: bool,
          robot: str | None, scheduler: str | None, dynamics: Path | None = None):
    """Build or update the catalog of ``dataset`` in ``out`` with a progress bar and a line
    per failed session; return the :class:`~contactkit.replay.catalog.CatalogResult`."""
    from contactkit.cli.default_model import build_default_model, default_model_missing
    from contactkit.cli.replay import pyarrow_without_pandas
    from contactkit.replay.catalog import (
        CatalogIdentity,
        build_catalog,
        check_inputs,
        model_identity,
    )
    from contactkit.robots.dynamics import arm_override

    pyarrow_without_pandas()  # as the replay command: a catalog converts nothing to pandas
    if not Path(dataset).is_dir():
        raise InputError("is not a dataset directory", dataset)
    if model is None and default_model_missing():
        err_console.print("No --model given: building the default model once (simulated "
                          "data, then an SVM); it is cached for next time.")
    if model is None:
        with progress_bar() as bar:
            model_path = build_default_model(progress=labelled_progress(bar))
        identity = model_identity(model_path, "default")
    else:
        if not model.is_file():
            raise InputError("model file not found", model)
        model_path, identity = model, model_identity(model)
    identified = load_dynamics_option(dynamics)
    arm = arm_override(robot, identified)
    # a catalog built with other dynamics is refused without --overwrite
    catalog = CatalogIdentity(identity, None if identified is None else
                              {"name": Path(cast(Path, dynamics)).name,  # given with identified
                               "checksum": identified.checksum})
    check_inputs(dataset, out, catalog, overwrite=overwrite)  # before the progress bar
    with progress_bar("replaying") as bar:
        result = build_catalog(dataset, out, model_path, catalog,
                               workers=workers, overwrite=overwrite, robot=arm,
                               scheduler=scheduler, progress=bar_callback(bar, "sessions"))
    err_console.print(f"{len(result.replayed)} replayed, {len(result.kept)} unchanged, "
                      f"{len(result.removed)} removed"
                      + (f", {len(result.failed)} failed" if result.failed else "")
                      + f"; catalog {out}")
    print_problems(result.failed, "failed")
    if result.replayed and identified is None:
        _hint_self_identification(dataset)
    return result


def _hint_self_identification(dataset: Path) -> None:
    """Say on stderr how to score ``dataset`` with its own arm when it is a moving arm's
    dataset that carries no identified dynamics (its catalog then holds the nominal
    model's events, where ``classify predict --events`` identifies the arm first)."""
    from contactkit.features.self_identification import moving_dataset, survey
    from contactkit.schemas.dataset import session_files

    if moving_dataset(survey(session_files(dataset))) is None:
        err_console.print(
            "These sessions are a moving arm's, replayed with its nominal model; classify "
            "predict --events identifies the arm from them first and finds more contacts. "
            f"`recorder identify {console_text(dataset)} --cross-fitted` stores those arms "
            "in the sessions; a re-run of this command then replays them with them.")


def catalog_command(
    ctx: typer.Context,
    dataset: Annotated[Path, typer.Argument(help="Dataset directory.")],
    out: Annotated[Path, typer.Option(
        help="Catalog folder: one .rrd per session at its top level, the tables and the "
             "manifest in tables/ (created if needed).")],
    model: Annotated[Path | None, typer.Option(
        help="Model file from `classify train` (default: the built-in model).")] = None,
    workers: Annotated[int, typer.Option(help="Parallel processes.")] = DEFAULT_WORKERS,
    robot: RobotOpt = None,
    dynamics: DynamicsOpt = None,
    overwrite: Annotated[bool, typer.Option(
        help="Rebuild a catalog built with another model or dynamics.")] = False,
) -> None:
    """Replay every session of a dataset into a Rerun catalog: one recording per session
    (recording id = session id) with its metadata, contact events, predictions and
    agreement as recording properties, and the tables sessions and events for `recorder
    query`. A re-run replays only new or changed sessions.

    Serve it with `recorder browse DIR` or `rerun server -d DIR`. A session that fails is
    listed and the others are written (exit code 2)."""
    result = build(dataset, out, model, workers, overwrite, robot, scheduler_of(ctx),
                   dynamics)
    print(out)
    if result.failed:
        raise typer.Exit(2)


def query_command(
    catalog: Annotated[Path, typer.Argument(help="Catalog folder (recorder catalog).")],
    sql: Annotated[str, typer.Argument(
        help="One SELECT or WITH query over the tables sessions and events.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON lines.")] = False,
) -> None:
    """Query a catalog with SQL (DataFusion): the tables sessions (one row per session)
    and events (one row per contact event, with its session_id). Each row with a
    session_id is followed by the command that opens it in the viewer at its time.

    Example: recorder query cat "SELECT s.action, e.label, count(*) AS n FROM events e
    JOIN sessions s USING (session_id) WHERE NOT e.correct GROUP BY 1, 2"
    """
    from contactkit.replay.query import open_command, query_catalog

    table = query_catalog(catalog, sql)
    for row in table.to_pylist():
        command = open_command(catalog, row)
        if as_json:
            print(json.dumps(row | ({"open": command} if command else {}), default=str))
        else:
            line = "  ".join(f"{k}={v}" for k, v in row.items())
            print(printable(line) + (f"\n  open: {printable(command)}" if command else ""))
    if not as_json:
        err_console.print(f"{table.num_rows} rows")


def browse_command(
    ctx: typer.Context,
    source: Annotated[Path, typer.Argument(
        help="A catalog folder, or a dataset (its catalog is built or updated first, in "
             "--out).")],
    out: Annotated[Path | None, typer.Option(
        help="With a dataset: its catalog folder (default: DATASET-catalog beside it, "
             "where `recorder stats` links to it).")] = None,
    host: Annotated[str, typer.Option(
        help="Address the catalog server binds (Rerun's own default is 0.0.0.0: every "
             "interface).")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="The server's port (0: a free one).")] = 0,
    session: Annotated[str | None, typer.Option(
        help="Open this session (its id) instead of the dataset's table.")] = None,
    at: Annotated[float | None, typer.Option(
        help="With --session: the time to open it at [s].")] = None,
    viewer: Annotated[ViewerChoice, typer.Option(
        help="auto (native with a display, else web), native, web or none (only serve).")
                      ] = "auto",
    model: Annotated[Path | None, typer.Option(
        help="With a dataset: the model file (default: the built-in model).")] = None,
    workers: Annotated[int, typer.Option(help="With a dataset: parallel processes.")
                       ] = DEFAULT_WORKERS,
) -> None:
    """Serve a catalog with Rerun's catalog server and open a viewer on it: the dataset's
    table of sessions with their properties, each session's recording a click away.
    Prints the URL to connect to; Ctrl-C stops it."""
    from contactkit.replay.browse import (
        dataset_url,
        open_viewer,
        segment_url,
        start_catalog_server,
    )
    from contactkit.replay.catalog import is_catalog

    if at is not None and session is None:
        raise InputError("--at needs --session")
    if not (0 <= port < 65536):
        raise InputError(f"--port must be 0..65535, got {port}")
    folder = source
    if not is_catalog(source):
        folder = out or catalog_beside(source)
        result = build(source, folder, model, workers, False, None, scheduler_of(ctx))
        if not (result.replayed or result.kept):
            raise InputError("no session could be replayed", source)
    server = start_catalog_server(folder, host, port)
    process = None
    try:
        target = dataset_url(server) if session is None else segment_url(server, session, at)
        print(target, flush=True)
        if viewer != "none":
            process, page = open_viewer(target, web=None if viewer == "auto"
                                        else viewer == "web")
            if page is not None:
                print(page, flush=True)
        err_console.print("serving the catalog; press Ctrl-C to stop")
        _wait_for_interrupt()
    finally:
        if process is not None:
            process.terminate()
            process.wait()
        server.shutdown()


def _wait_for_interrupt() -> None:
    """Block until Ctrl-C or SIGTERM (both end the command cleanly)."""
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)


def register(app: typer.Typer) -> None:
    """Add the catalog commands to the ``recorder`` app."""
    app.command("catalog")(catalog_command)
    app.command("query")(query_command)
    app.command("browse")(browse_command)

