"""Crash-safe session writing: an append-only journal, then an atomic Parquet file.

While a capture runs, samples go to ``<session>.parquet.journal`` beside the
output: an Arrow IPC stream whose schema carries the session metadata. Pending
rows are written as a record batch, flushed and fsync'ed whenever they cover half
the flush interval (default interval 0.1 s of data), so a capture killed at any
moment loses at most the last 0.1 s. On a clean finish the Parquet file is written
from the journal one row group at a time (memory stays bounded however long the
capture) through a temporary file and a link, and only then is the journal removed.

``recover`` turns every leftover journal in a directory into a valid session whose
metadata says it was recovered and how many samples it holds. A torn final record
batch (the process died mid-write) is dropped; every complete batch is kept.

A live capture holds an exclusive lock on its journal (``flock``), so ``recover``
leaves the journal of a capture that is still running alone, and two recovers never
write the same session. When the disk fills up (or any write fails), the capture
stops with an :class:`InputError` that says how many samples are safe in the journal.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from contactkit.errors import DATA_ERRORS, ContactkitError, problem_text, write_error
from contactkit.schemas import InputError, SessionMeta
from contactkit.schemas.session import (
    METADATA_KEY,
    iter_session_batches,
    read_session_meta,
    session_schema,
    write_session_batches,
)
from contactkit.util.atomic import check_target, remove_stale_temporaries
from contactkit.util.paths import inside
from contactkit.util.safe_open import parse_json

JOURNAL_SUFFIX = ".journal"


def journal_path(out_path: Path) -> Path:
    """Return the journal path of a session output path."""
    return out_path.with_name(out_path.name + JOURNAL_SUFFIX)


def journal_in_use(path: Path) -> bool:
    """Return whether a live capture (or a running recover) holds the journal's lock."""
    try:
        with open(path, "rb") as handle:
            try:
                fcntl.flock(handle, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
    except FileNotFoundError:
        return False
    return False


class SessionWriter:
    """Append samples to a journal while capturing; write the session on :meth:`close`.

    ``columns`` names the session columns that will be appended (a subset of the
    schema). Use as a context manager: leaving the block by an exception keeps the
    journal for ``recorder recover``.
    """

    def __init__(self, out_path: str | Path, meta: SessionMeta, columns: list[str],
                 flush_interval_s: float = 0.1, overwrite: bool = False) -> None:
        self.out_path = Path(out_path)
        self.overwrite = overwrite
        self.meta = meta
        self.flush_interval_s = flush_interval_s
        self.journal = journal_path(self.out_path)
        check_target(self.out_path, overwrite=overwrite)
        if self.journal.exists():
            if journal_in_use(self.journal):
                raise InputError("another capture is writing this session", self.journal)
            raise InputError("an unrecovered journal of this session exists; run "
                             "`recorder recover` first", self.journal)
        self.schema = session_schema(columns, meta)
        try:
            self._file = open(self.journal, "xb")  # noqa: SIM115 (closed in close/abort)
        except FileNotFoundError as err:
            raise InputError("output directory does not exist", self.out_path.parent) from err
        except FileExistsError as err:
            raise InputError("another capture is writing this session", self.journal) from err
        except OSError as err:
            raise InputError(f"cannot write here ({err.strerror})", self.out_path.parent
                             ) from err
        fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        self._pending: list[dict[str, np.ndarray]] = []
        self._pending_t0: float | None = None
        self.samples_written = 0
        self._failed = False
        with self._writing():
            self._stream = pa.ipc.new_stream(self._file, self.schema)
            self._sync()

    def append(self, columns: dict[str, np.ndarray]) -> None:
        """Add rows (arrays of equal length, ``t`` in s); flush when enough are pending."""
        if len(columns["t"]) == 0:
            return
        self._pending.append(columns)
        if self._pending_t0 is None:
            self._pending_t0 = float(columns["t"][0])
        if float(columns["t"][-1]) - self._pending_t0 >= self.flush_interval_s / 2:
            self.flush()

    def flush(self) -> None:
        """Write pending rows as one record batch and force them to disk."""
        if not self._pending:
            return
        arrays = [pa.array(np.concatenate([c[f.name] for c in self._pending]), type=f.type)
                  for f in self.schema]
        batch = pa.RecordBatch.from_arrays(arrays, schema=self.schema)
        with self._writing():
            self._stream.write_batch(batch)
            self._sync()
        self.samples_written += batch.num_rows
        self._pending.clear()
        self._pending_t0 = None

    @contextlib.contextmanager
    def _writing(self):
        """Turn a failed journal write (disk full: a ResourceError, I/O error: an
        InputError) into one line that says what is safe; later flushes are refused."""
        if self._failed:
            raise InputError("the journal is no longer writable", self.journal)
        try:
            yield
        except OSError as err:
            self._failed = True
            raise write_error(f"cannot write the journal ({err.strerror or err}); the "
                              f"capture stopped and its {self.samples_written} samples "
                              "already flushed are kept for `recorder recover`", err,
                              self.journal) from err

    def _sync(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> Path:
        """Flush, write the Parquet session atomically, remove the journal; return the path.

        The journal stays locked until it is removed, so a concurrent ``recover`` never
        races the finishing capture. If writing the session fails, the journal is kept.
        """
        try:
            self.flush()
            with self._writing():
                self._stream.close()
                self._sync()
            if self.samples_written == 0:
                self.journal.unlink()
                raise InputError("no samples were recorded; nothing written", self.out_path)
            write_session_batches(self.out_path, journal_batches(self.journal), self.meta,
                                  overwrite=self.overwrite)
            self.journal.unlink()
            return self.out_path
        finally:
            with contextlib.suppress(OSError):
                self._file.close()

    def abort(self) -> None:
        """Flush what is pending and close the journal, keeping it for recovery (after a
        failed write, only close it: the samples flushed before are what counts)."""
        try:
            if not self._failed:
                self.flush()
                self._stream.close()
        except ContactkitError:
            pass
        finally:
            with contextlib.suppress(OSError):
                self._file.close()

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None and not self._file.closed:
            self.abort()


@dataclass
class JournalContents:
    """What a journal holds: metadata, the complete batches as a table, and whether a
    torn batch was dropped at its end."""

    meta: SessionMeta
    table: pa.Table
    torn: bool


def _open_journal(path: Path) -> tuple[pa.ipc.RecordBatchStreamReader, SessionMeta]:
    try:
        reader = pa.ipc.open_stream(pa.OSFile(str(path)))
    except (pa.ArrowInvalid, OSError) as err:
        raise InputError(f"not a readable journal ({err})", path) from err
    try:
        meta = SessionMeta.from_dict(parse_json(reader.schema.metadata[METADATA_KEY],
                                                "session metadata", path), path)
    except (KeyError, TypeError, ValueError, RecursionError) as err:
        raise InputError("journal has no session metadata", path) from err
    return reader, meta


def _complete_batches(reader: pa.ipc.RecordBatchStreamReader, torn: list[bool]
                      ) -> Iterator[pa.RecordBatch]:
    """Yield the complete batches of an open journal; set ``torn[0]`` if one was cut."""
    while True:
        try:
            yield reader.read_next_batch()
        except StopIteration:
            return
        except (pa.ArrowInvalid, OSError):
            torn[0] = True
            return


def journal_batches(path: str | Path) -> Iterator[pa.RecordBatch]:
    """Yield every complete record batch of a journal, one at a time (a torn last batch
    is dropped), so a long journal is never held in memory at once."""
    reader, _ = _open_journal(Path(path))
    yield from _complete_batches(reader, [False])


def journal_progress(directory: str | Path) -> tuple[int, float]:
    """Return how far the capture journalling into ``directory`` has come: its complete
    samples and the time [s] of the last one ((0, 0.0) when there is no journal yet,
    or its header is still being written). Reads one batch at a time."""
    for journal in Path(directory).glob("*" + JOURNAL_SUFFIX):
        samples, last_t = 0, 0.0
        try:
            for batch in journal_batches(journal):
                if batch.num_rows:
                    samples += batch.num_rows
                    last_t = float(batch.column("t")[-1].as_py())
        except InputError:
            return 0, 0.0
        return samples, last_t
    return 0, 0.0


def read_journal(path: str | Path) -> JournalContents:
    """Read every complete record batch of a journal (a torn last batch is dropped)."""
    reader, meta = _open_journal(Path(path))
    torn = [False]
    table = pa.Table.from_batches(list(_complete_batches(reader, torn)), schema=reader.schema)
    return JournalContents(meta=meta, table=table, torn=torn[0])


@dataclass
class Recovery:
    """Outcome of recovering one journal: the session written (or None) and a note."""

    journal: Path
    session: Path | None
    samples: int
    note: str
    failed: bool = False
    """True when the journal could not be recovered (it is left in place)."""


def recover_journal(journal: Path) -> Recovery:
    """Turn one journal into a session marked as recovered; remove the journal after.

    The journal is removed only once the session it wrote has been read back and
    verified (valid, the journal's session id, at least the journal's samples). If the
    session file already exists (the capture died after writing it but before removing
    its journal), the journal is removed only when that file passes the same check; any
    other file there is left alone, and so is the journal.
    """
    out_path = inside(journal.parent, journal.name[: -len(JOURNAL_SUFFIX)])
    try:
        fd = os.open(journal, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        return Recovery(journal, None, 0, "journal already gone (recovered by another run)")
    except OSError as err:
        if err.errno != errno.ELOOP:
            raise
        return Recovery(journal, None, 0, "left in place: a symbolic link, not a journal "
                                          "(a journal is never followed)", failed=True)
    handle = os.fdopen(fd, "rb")
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        handle.close()
        return Recovery(journal, None, 0, "left in place: not a regular file, not a journal",
                        failed=True)
    with handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return Recovery(journal, None, 0, "left in place: a live capture (or another "
                                              "recover) is writing it")
        if not journal.exists():
            return Recovery(journal, None, 0, "journal already gone (recovered by another run)")
        return _recover_locked(journal, out_path)


def _verified(session: Path, session_id: str | None, samples: int) -> str | None:
    """Return why ``session`` is not the verified session of a journal (its id, unless
    None, and at least ``samples`` valid rows), or None when it is."""
    try:
        meta, _ = read_session_meta(session)
        if session_id is not None and meta.session_id != session_id:
            return f"{session.name} holds another session ({meta.session_id[:40]!r})"
        rows = sum(batch.num_rows for batch in iter_session_batches(session))
    except InputError as err:
        return f"{session.name} is not a valid session ({err.problem[:200]})"
    if rows < samples:
        return f"{session.name} holds {rows} samples, the journal {samples}"
    return None


def _recover_locked(journal: Path, out_path: Path) -> Recovery:
    """Recover a journal whose lock this process holds."""
    try:
        reader, meta = _open_journal(journal)
    except InputError as err:
        if not os.path.lexists(out_path):
            return Recovery(journal, None, 0, f"left in place: {err.problem}", failed=True)
        reader = meta = None  # an unreadable journal beside a valid session: stale
    if os.path.lexists(out_path):
        samples = 0 if reader is None else sum(
            b.num_rows for b in _complete_batches(reader, [False]))
        problem = _verified(out_path, None if meta is None else meta.session_id, samples)
        if problem is not None:
            return Recovery(journal, None, 0, f"left in place: {problem}; move that file "
                                              "away and run recover again", failed=True)
        journal.unlink()
        return Recovery(journal, out_path, 0, "session already complete; stale journal removed")
    assert reader is not None and meta is not None  # read: no session beside it
    n = gaps = 0
    torn = [False]
    for batch in _complete_batches(reader, torn):  # first pass: count, one batch at a time
        n += batch.num_rows
        gaps += _incomplete_samples(batch)
    if n == 0:
        return Recovery(journal, None, 0, "journal holds no complete sample; left in place",
                        failed=True)
    if gaps:
        meta.source_info = {**meta.source_info, "incomplete_samples": gaps}
    meta.recovered = True
    meta.recovered_samples = n
    note = f"recovered {n} samples" + (" (torn last batch dropped)" if torn[0] else "")
    meta.notes = (meta.notes + "; " if meta.notes else "") + note
    write_session_batches(out_path, journal_batches(journal), meta)
    problem = _verified(out_path, meta.session_id, n)
    if problem is not None:
        return Recovery(journal, out_path, n, f"journal left in place: written session "
                                              f"failed its check ({problem})", failed=True)
    journal.unlink()
    return Recovery(journal, out_path, n, note)


def _incomplete_samples(batch: pa.RecordBatch) -> int:
    """Return how many rows of a batch lack a q, dq or tau value (NaN)."""
    measured = np.column_stack([batch.column(c).to_numpy() for c in batch.schema.names
                                if c.split("_")[0] in ("q", "dq", "tau") and c[-1].isdigit()])
    return int((~np.isfinite(measured)).any(axis=1).sum())


def recover_directory(directory: str | Path) -> list[Recovery]:
    """Recover every journal in ``directory``; return one :class:`Recovery` per journal.
    Temporary files of writers that were killed are removed."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError("not a directory", directory)
    remove_stale_temporaries(directory)
    return [_recover_one(p) for p in sorted(directory.glob("*" + JOURNAL_SUFFIX))]


def _recover_one(journal: Path) -> Recovery:
    """Recover one journal of a directory; a failure is its Recovery, not the end."""
    try:
        return recover_journal(journal)
    except (*DATA_ERRORS, OSError) as err:  # type: ignore[misc]  # mypy: a starred tuple
        return Recovery(journal, None, 0, f"left in place: {problem_text(err)}", failed=True)
