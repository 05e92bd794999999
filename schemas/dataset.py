"""A dataset: a directory of session files plus ``index.parquet``.

The index holds one row of metadata per session. It is always rebuildable from the
session files (their Parquet footers only, so building it is fast), and is written
atomically. Files that fail to open are listed in the result, never silently
skipped.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.errors import InputError
from contactkit.robots import canonical_robot_name
from contactkit.schemas.columns import check_time_range
from contactkit.schemas.metadata import SessionMeta
from contactkit.schemas.session import (
    METADATA_KEY,
    atomic_write_parquet,
    read_session_meta,
)

INDEX_NAME = "index.parquet"
SESSION_GLOB = "*.parquet"

INDEX_SCHEMA = pa.schema([
    pa.field("file", pa.string()),
    pa.field("session_id", pa.string()),
    pa.field("source", pa.string()),
    pa.field("condition", pa.string()),
    pa.field("pose", pa.string()),
    pa.field("target_pose", pa.string()),
    pa.field("action", pa.string()),
    pa.field("link", pa.int8()),
    pa.field("speed_rad_s", pa.float64()),
    pa.field("planned_at_s", pa.float64()),
    pa.field("nominal_rate_hz", pa.float64()),
    pa.field("n_samples", pa.int64()),
    pa.field("t_start_s", pa.float64()),
    pa.field("t_end_s", pa.float64()),
    pa.field("duration_s", pa.float64()),
    pa.field("operator", pa.string()),
    pa.field("robot", pa.string()),
    pa.field("with_hand", pa.bool_()),
    pa.field("recovered", pa.bool_()),
    pa.field("created_utc", pa.string()),
    pa.field("schema_version", pa.int16()),
    pa.field("file_bytes", pa.int64()),
    pa.field("metadata_json", pa.string()),
], metadata={b"contactkit.index": b"1"})


@dataclass
class IndexResult:
    """The rebuilt index and the files that could not be indexed (path, problem)."""

    table: pa.Table
    problems: list[tuple[str, str]] = field(default_factory=list)


def session_files(directory: str | Path) -> list[Path]:
    """Return the session files of a dataset directory, sorted, without the index."""
    directory = Path(directory)
    return sorted(p for p in directory.glob(SESSION_GLOB)
                  if p.name != INDEX_NAME and not p.name.startswith("."))


def source_sessions(sources: Sequence[str | Path]) -> list[Path]:
    """Return the session files of ``sources``, in order: a directory's
    (:func:`session_files`), a file as given. InputError naming a missing path or a
    directory without sessions."""
    paths: list[Path] = []
    for source in map(Path, sources):
        if source.is_dir():
            files = session_files(source)
            if not files:
                raise InputError("no session files (*.parquet) in this directory", source)
            paths += files
        elif source.exists():
            paths.append(source)
        else:
            raise InputError("no such file or directory", source)
    return paths


def _time_range(footer: pq.FileMetaData) -> tuple[float, float]:
    """Return (first, last) time stamp [s] from the Parquet column statistics of ``t``."""
    t_index = footer.schema.to_arrow_schema().get_field_index("t")
    lo, hi = float("nan"), float("nan")
    for rg in range(footer.num_row_groups):
        stats = footer.row_group(rg).column(t_index).statistics
        if stats is None or not stats.has_min_max:
            continue
        lo = stats.min if lo != lo else min(lo, stats.min)
        hi = stats.max if hi != hi else max(hi, stats.max)
    return lo, hi


def index_row(path: Path, meta: SessionMeta, footer: pq.FileMetaData) -> dict[str, Any]:
    """Return the index row of one session from its metadata and Parquet footer."""
    t0, t1 = _time_range(footer)
    if t0 == t0 and t1 == t1:  # row groups without statistics leave NaN
        check_time_range(t0, t1, path)
    return {
        "file": path.name,
        "session_id": meta.session_id,
        "source": meta.source,
        "condition": meta.condition,
        "pose": meta.pose,
        "target_pose": meta.target_pose,
        "action": meta.action,
        "link": meta.link,
        "speed_rad_s": meta.speed_rad_s,
        "planned_at_s": meta.planned_at_s,
        "nominal_rate_hz": meta.nominal_rate_hz,
        "n_samples": footer.num_rows,
        "t_start_s": t0,
        "t_end_s": t1,
        "duration_s": t1 - t0,
        "operator": meta.operator,
        "robot": canonical_robot_name(meta.robot),
        "with_hand": meta.with_hand,
        "recovered": meta.recovered,
        "created_utc": meta.created_utc,
        "schema_version": meta.schema_version,
        "file_bytes": path.stat().st_size,
        "metadata_json": meta.to_json(),
    }


def build_index(directory: str | Path, files: Iterable[Path] | None = None) -> IndexResult:
    """Read the footer of every session file in ``directory`` and return the index.

    Files that are not valid sessions are reported in ``problems`` and left out.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError("not a directory", directory)
    rows, problems = [], []
    for path in (session_files(directory) if files is None else files):
        try:
            meta, footer = read_session_meta(path)
            rows.append(index_row(path, meta, footer))
        except InputError as err:
            problems.append((path.name, err.problem))
    table = pa.Table.from_pylist(rows, schema=INDEX_SCHEMA)
    return IndexResult(table=table, problems=problems)


def is_index_file(path: Path) -> bool:
    """Return whether ``path`` (a regular file named ``index.parquet``) may be replaced
    by a rebuilt index: an index contactkit wrote, or a damaged file under the name the
    tool reserves for its index; never a session (``import-arrays --name
    index.parquet`` is refused, but an older version accepted it)."""
    try:
        metadata = pq.read_schema(path).metadata or {}
    except (OSError, ValueError, pa.ArrowException):
        return True
    return b"contactkit.index" in metadata or METADATA_KEY not in metadata


def write_index(directory: str | Path, table: pa.Table) -> Path:
    """Write ``index.parquet`` into ``directory`` atomically; return its path. An old
    index is replaced; any other file of that name (a session, a link) is refused."""
    path = Path(directory) / INDEX_NAME
    atomic_write_parquet(table, path, overwrite=False, owned=is_index_file)
    return path


def rebuild_index(directory: str | Path) -> IndexResult:
    """Rebuild and write the index of a dataset directory; return it with any problems."""
    result = build_index(directory)
    write_index(directory, result.table)
    return result

