"""The ``classify`` command: features now; training and evaluation build on them."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated

import pyarrow as pa
import pyarrow.parquet as pq
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from features.extract import SessionFeatures, feature_rows, timeseries_columns
from features.scalars import SCALARS
from features.timeseries import ALL_TIMESERIES, GROUPS
from features.windows import METHODS
from schemas import InputError, read_session
from schemas.cli import run_app
from schemas.dataset import session_files
from schemas.features import write_feature_table

app = typer.Typer(name="classify", no_args_is_help=True, add_completion=False,
                  pretty_exceptions_enable=False,
                  help="Turn sessions into features and contact predictions.")
err_console = Console(stderr=True)


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


def progress_bar(label: str) -> Progress:
    """Return a progress bar on stderr for long work."""
    return Progress(TextColumn(f"[bold]{label}[/]"), BarColumn(), MofNCompleteColumn(),
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
    workers: Annotated[int, typer.Option(help="Parallel processes.")] = max(os.cpu_count() or 1,
                                                                             1),
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


def main() -> None:
    """Entry point of the ``classify`` console script."""
    sys.exit(run_app(app, "classify"))
