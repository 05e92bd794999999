"""CAN log import and the session-to-bus bridge.

``import_can_log`` reads any log python-can reads (ASC, BLF, TRC, CSV, candump
``.log``, MF4 with asammdf installed, SQLite ``.db``) and writes a validated
session. ``bridge_session`` publishes a session onto a bus (paced by ``rate``,
1 = real time) or writes the same frames, time-stamped as on the bus, to a log
file with python-can's writers.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import can
import numpy as np

from contactkit.errors import DependencyMissing
from contactkit.recorder.importers.can_codec import (
    SampleAssembler,
    rows_to_columns,
    session_frames,
    session_values,
)
from contactkit.recorder.importers.can_map import FrameMap
from contactkit.recorder.importers.writer import write_imported_session
from contactkit.recorder.sources.can import BusConfig
from contactkit.schemas import InputError, Session, SessionMeta
from contactkit.util.atomic import atomic_write
from contactkit.util.pacing import paced

LOG_SUFFIXES = (".asc", ".blf", ".trc", ".csv", ".log", ".mf4", ".db")


def read_log(path: Path, fmap: FrameMap) -> tuple[dict[str, np.ndarray], SampleAssembler]:
    """Decode a CAN log file into session columns; return them and the assembler."""
    if not path.is_file():
        raise InputError("no such log file", path)
    if path.suffix.lower() not in LOG_SUFFIXES:
        raise InputError(f"unknown log format {path.suffix!r} (python-can reads "
                         f"{', '.join(LOG_SUFFIXES)})", path)
    assembler = SampleAssembler(fmap)
    rows = []
    for msg in _messages(path):
        rows += assembler.feed(msg)
    rows += assembler.finish()
    if not rows:
        raise InputError("no complete sample in this log (no SYNC frame of the map?)", path)
    return rows_to_columns(rows), assembler


def _messages(path: Path) -> Iterator[can.Message]:
    """Yield the frames of a log file; a malformed file is an InputError.

    python-can's readers raise many kinds of error on a damaged file (its own parse
    errors, zlib, struct, sqlite3, ...), so any error while parsing counts as a bad file.
    """
    try:
        reader = iter(can.LogReader(path))
    except ImportError as err:
        raise DependencyMissing(f"reading this format needs an extra package ({err})",
                                path) from err
    except Exception as err:  # a third-party parser of untrusted bytes
        raise InputError(f"cannot read this log ({type(err).__name__}: {str(err)[:80]})",
                         path) from err
    while True:
        try:
            msg = next(reader)
        except StopIteration:
            return
        except Exception as err:  # a third-party parser of untrusted bytes
            raise InputError(f"cannot read this log ({type(err).__name__}: "
                             f"{str(err)[:80]})", path) from err
        yield msg


def import_can_log(path: Path, fmap: FrameMap, meta: SessionMeta, out_dir: Path,
                   name: str) -> Path:
    """Write the session decoded from a CAN log; return its path."""
    columns, assembler = read_log(path, fmap)
    if not complete_rows(columns).any():
        summary = decoding_summary(assembler.stats.as_dict())
        raise InputError(f"no complete sample in this log ({summary}): do the CAN ids and "
                         "SYNC of the map match the log?", path)
    meta.source_info = {"log": str(path), "map": fmap.describe(), **assembler.stats.as_dict()}
    return write_imported_session(columns, meta, out_dir, name)


def complete_rows(columns: dict[str, np.ndarray]) -> np.ndarray:
    """Return which samples hold every joint value (q, dq and tau of all joints)."""
    names = [n for n in columns if n.split("_")[0] in ("q", "dq", "tau")
             and n.split("_")[-1].isdigit()]
    return np.all(np.isfinite(np.column_stack([columns[n] for n in names])), axis=1)


def decoding_summary(stats: dict) -> str:
    """Return one line on a decoded log: samples, frames and each kind of fault counted."""
    return (f"{stats['samples']} samples from {stats['frames']} frames; "
            f"{stats['incomplete_samples']} incomplete, {stats['lost_syncs']} lost SYNCs, "
            f"{stats['unknown_ids']} unknown ids, {stats['bad_lengths']} bad lengths, "
            f"{stats['duplicates']} duplicates")


def bridge_session(session: Session, fmap: FrameMap, *, bus: BusConfig | None = None,
                   log: Path | None = None, rate: float | None = None,
                   overwrite: bool = False) -> int:
    """Send a session's frames onto a bus, or write them to ``log``; return the count.

    On a bus the frames are paced at ``rate`` x real time (default 1). Into a log
    they are written as fast as possible unless ``rate`` is given, time-stamped as
    they would be on the bus, into a temporary file renamed into place at the end (a
    failure or kill leaves no partial log); an existing ``log`` is replaced only with
    ``overwrite``.
    """
    if (bus is None) == (log is None):
        raise InputError("publishing needs either a bus or a log file, not both")
    if rate is not None and rate <= 0:
        raise InputError(f"pacing rate must be positive, got {rate}")
    session = session.complete()
    values = session_values(session.q, session.dq, session.tau)
    if log is not None:
        if log.suffix.lower() not in LOG_SUFFIXES:
            raise InputError(f"unknown log format {log.suffix!r}", log)
        start = time.time()
        sent = 0
        with atomic_write(log, overwrite=overwrite, suffix=log.suffix.lower()) as tmp:
            writer = can.Logger(tmp.path)
            try:
                for msg in _paced(session_frames(fmap, session.t, values, start), rate):
                    writer.on_message_received(msg)
                    sent += 1
            finally:
                _drain(writer)
                writer.stop()
        return sent
    channel = bus.open(fmap.fd)
    sent = 0
    try:
        start = time.time()
        for msg in _paced(session_frames(fmap, session.t, values, start), rate or 1.0):
            channel.send(msg)
            sent += 1
    finally:
        channel.shutdown()
    return sent


def _drain(writer: can.Listener) -> None:
    """Wait until a threaded writer (python-can's SqliteWriter) has taken every queued
    frame: its stop() writes one more batch and drops the rest of its queue."""
    buffer = getattr(writer, "buffer", None)
    while buffer is not None and not buffer.empty():
        time.sleep(0.02)


def _paced(frames: Iterator[can.Message], rate: float | None) -> Iterator[can.Message]:
    """Return the frames paced at ``rate`` x real time by their time stamps [s]."""
    return paced(frames, lambda msg: msg.timestamp, rate)
