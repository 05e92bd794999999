"""CAN log import and the session-to-bus bridge.

:class:`CanLogImporter` (format ``can`` of ``recorder import``) reads any log python-can
reads (ASC, BLF, TRC, CSV, candump ``.log``, MF4 with asammdf installed, SQLite ``.db``)
frame by frame, in bounded memory. ``bridge_session`` publishes a session onto a bus
(paced by ``rate``, 1 = real time) or writes the same frames, time-stamped as on the
bus, to a log file with python-can's writers.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from contactkit.errors import DependencyMissing
from contactkit.recorder.importers.base import Importer
from contactkit.recorder.importers.can_codec import (
    COLUMNS,
    SampleAssembler,
    session_frames,
    session_values,
)
from contactkit.recorder.importers.can_map import FrameMap, load_map
from contactkit.recorder.importers.spill import RowSpill
from contactkit.recorder.sources.can import BusConfig
from contactkit.schemas import InputError, Session
from contactkit.util.atomic import atomic_write
from contactkit.util.pacing import paced

LOG_SUFFIXES = (".asc", ".blf", ".trc", ".csv", ".log", ".mf4", ".db")
BLOCK_ROWS = 16_384
"""Decoded samples gathered before they are spilled, and rows written at a time."""


class CanLogImporter(Importer):
    """A CAN log python-can reads, decoded per a frame map into samples (a SYNC frame
    closes each, :class:`~contactkit.recorder.importers.can_codec.SampleAssembler`).

    The frames are read once, and the decoded samples go to a temporary file a block
    at a time (:data:`BLOCK_ROWS` of them), so memory holds one block however long the
    log; the session is then written from that file.
    """

    name = "can"
    source = "can-log"
    suffixes = tuple(s for s in LOG_SUFFIXES if s != ".csv")  # .csv: a CSV export
    description = ("CAN logs python-can reads: ASC, BLF, TRC, CSV (with --format can), "
                   "candump .log, SQLite .db, MF4 with asammdf.")

    @dataclass(frozen=True)
    class Config:
        """The CAN log format's option."""

        map_file: Path | None = field(default=None, metadata={
            "name": "map", "help": "Frame map TOML (default: CANopen CiA 402)."})

    def __init__(self, path: Path, fmap: FrameMap, rows: RowSpill,
                 stats: dict[str, int]) -> None:
        self.path, self.fmap, self.rows, self.stats = path, fmap, rows, stats

    @classmethod
    def open(cls, path: Path, config: Config) -> CanLogImporter:
        """Decode the log at ``path`` with the frame map ``config.map_file`` (None:
        CANopen CiA 402); see :meth:`read`."""
        return cls.read(path, load_map(config.map_file))

    @classmethod
    def read(cls, path: Path, fmap: FrameMap) -> CanLogImporter:
        """Decode the log at ``path`` per ``fmap`` into a temporary file of samples (t
        [s] from the first SYNC, then q [rad], dq [rad/s], tau [Nm] per joint).

        Raises InputError naming the file for an unknown format, an unreadable log or
        one without a complete sample (the counts of what was decoded say why).
        """
        if not path.is_file():
            raise InputError("no such log file", path)
        if path.suffix.lower() not in LOG_SUFFIXES:
            raise InputError(f"unknown log format {path.suffix!r} (python-can reads "
                             f"{', '.join(LOG_SUFFIXES)})", path)
        assembler = SampleAssembler(fmap)
        spill = RowSpill(len(COLUMNS))
        pending: list[np.ndarray] = []
        complete = False

        def flush() -> bool:
            block = np.array(pending).reshape(-1, len(COLUMNS))
            pending.clear()
            spill.append(block)
            return bool(np.isfinite(block[:, 1:]).all(axis=1).any())

        try:
            for msg in _messages(path):
                pending += assembler.feed(msg)
                if len(pending) >= BLOCK_ROWS:
                    complete = flush() or complete
            pending += assembler.finish()
            complete = flush() or complete
            stats = assembler.stats.as_dict()
            if not spill.rows:
                raise InputError("no complete sample in this log (no SYNC frame of the "
                                 "map?)", path)
            if not complete:
                raise InputError(f"no complete sample in this log "
                                 f"({decoding_summary(stats)}): do the CAN ids and SYNC of "
                                 "the map match the log?", path)
        except BaseException:
            spill.close()
            raise
        return cls(path, fmap, spill, stats)

    def times(self) -> Iterator[np.ndarray]:
        """Yield the samples' times [s] from the first SYNC, a block at a time."""
        return (rows[:, 0] for rows in self.rows.chunks(BLOCK_ROWS))

    def chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield the session columns (``t``, ``q_1`` .. ``tau_7``), a block at a time; a
        value no frame delivered is NaN."""
        for rows in self.rows.chunks(BLOCK_ROWS):
            yield {name: np.ascontiguousarray(rows[:, i]) for i, name in enumerate(COLUMNS)}

    def source_info(self) -> dict[str, Any]:
        """Return the log, the map and the decoding counts (:class:`BusStatistics`)."""
        return {"log": str(self.path), "map": self.fmap.describe(), **self.stats}

    def defaults(self) -> dict[str, Any]:
        """Return the robot the map names, if it names one."""
        return {} if self.fmap.robot is None else {"robot": self.fmap.robot}

    def summary(self) -> str:
        """Return the decoding counts in one line."""
        return decoding_summary(self.stats)

    def close(self) -> None:
        """Remove the temporary file of samples."""
        self.rows.close()


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
    assert bus is not None  # either a bus or a log
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
