"""Read-only SQL over a catalog's ``sessions`` and ``events`` tables, with DataFusion.

DataFusion is the engine Rerun's catalog client itself queries with (the ``catalog``
extra of rerun-sdk installs it), so one SQL dialect serves both this module and the
client's ``segment_table()`` / ``ctx``; nothing else (DuckDB) has to be installed. The
tables are the Parquet files :mod:`contactkit.replay.catalog` writes beside the
recordings: querying them needs no running server, and they hold one row per event,
which the server's segment table (one row per recording) cannot.

A query is checked by DataFusion itself, not by pattern matching: it is planned with
DDL, DML (``COPY``, ``INSERT``) and statements (``SET``) disallowed and a single
statement only; the plan may only scan ``sessions`` and ``events`` (no other table,
file, URL or table function: none is registered, and URL tables are off), and must be a
query (no ``EXPLAIN`` or ``DESCRIBE``). The first keyword must be ``SELECT`` or ``WITH``.
Anything else is one :class:`~contactkit.errors.InputError` line.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import Any

import pyarrow as pa

from contactkit.errors import InputError
from contactkit.replay.catalog import catalog_tables

TABLE_NAMES = ("sessions", "events")
_COMMENT = re.compile(r"--[^\n]*|/\*.*?\*/", re.S)
_SCAN = re.compile(r"^\s*TableScan: (\S+)", re.M)
_NOT_QUERIES = ("Explain", "Analyze", "DescribeTable", "Ddl", "Dml", "Copy", "Statement",
                "Extension")


def _first_word(sql: str) -> str:
    words = _COMMENT.sub(" ", sql).split(None, 1)
    return words[0].upper().strip("(") if words else ""


def query_catalog(out: Path, sql: str) -> pa.Table:
    """Run the read-only query ``sql`` over the catalog in ``out``; return its rows.

    Raises InputError (one line) for a folder that is not a catalog, and for a query
    that is not one SELECT or WITH over ``sessions`` and ``events`` or does not plan
    (a syntax error, an unknown column)."""
    from datafusion import SessionConfig, SessionContext, SQLOptions

    tables = catalog_tables(out)
    if _first_word(sql) not in ("SELECT", "WITH"):
        raise InputError("only a SELECT or WITH query over the tables sessions and events "
                         f"is allowed, got {_first_word(sql) or 'nothing'!r}")
    ctx = SessionContext(SessionConfig().with_information_schema(False))
    for name, path in tables.items():
        ctx.register_parquet(name, str(path))
    options = (SQLOptions().with_allow_ddl(False).with_allow_dml(False)
               .with_allow_statements(False))
    try:
        frame = ctx.sql_with_options(sql, options)
        plan = frame.logical_plan()
    except Exception as err:  # DataFusion raises its own Exception types
        raise InputError(f"query refused: {_one_line(err)}") from err
    kind = type(plan.to_variant()).__name__
    if kind in _NOT_QUERIES:
        raise InputError(f"only a SELECT or WITH query is allowed, got {kind}")
    scanned = set(_SCAN.findall(plan.display_indent()))
    others = scanned - set(TABLE_NAMES)
    if others:
        raise InputError(f"only the tables sessions and events may be queried, not "
                         f"{', '.join(sorted(others))}")
    try:
        return frame.to_arrow_table()
    except Exception as err:
        raise InputError(f"query failed: {_one_line(err)}") from err


def _one_line(err: Exception) -> str:
    return " ".join(str(err).split())[:300]


def open_command(out: Path, row: dict[str, Any]) -> str | None:
    """Return the command that opens a result row in the viewer at its time: the row's
    ``session_id`` at its ``onset_s`` (else ``decision_s``, ``planned_at_s``) where it has
    one; None for a row without a session id."""
    session = row.get("session_id")
    if not isinstance(session, str):
        return None
    at = next((row[k] for k in ("onset_s", "decision_s", "planned_at_s")
               if isinstance(row.get(k), float | int)), None)
    command = f"recorder browse {shlex.quote(str(out))} --session {shlex.quote(session)}"
    return command + (f" --at {at:.3f}" if at is not None else "")
