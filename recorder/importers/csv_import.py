"""CSV exports of a robot's joint streams turned into sessions, column by column per a map.

Rows that repeat the previous row's measured values (q, dq, tau) are dropped and
counted when the map says so: a log written faster than the robot's state updates
(the MindLab files log at 200 Hz a state that changes at about 100 Hz) holds each
state twice with two time stamps, and keeping both would halve the apparent time
step and put zero-velocity steps into every difference.

Long files import in bounded memory: the file is parsed once in blocks of
:data:`BLOCK_ROWS` lines (each by ``pl.read_csv``, the header before each; Polars'
own streaming reader memory-maps the file and its RSS grew with it) into temporary files
(:class:`contactkit.recorder.importers.spill.RowSpill`), because the row counts (metadata) and
the first problem in column order are known only at its end; the session is then
written from them a row group at a time.
"""

from __future__ import annotations

import io
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from contactkit.recorder.importers.base import Importer
from contactkit.recorder.importers.csv_map import CsvMap, load_csv_map
from contactkit.recorder.importers.spill import RowSpill, spilled_session_chunks, spilled_times
from contactkit.recorder.metadata import session_filename
from contactkit.schemas import InputError, SessionMeta
from contactkit.util.safe_open import open_input

BLOCK_ROWS = 16_384
"""CSV rows parsed (and session rows written) at a time."""


class CsvSpill:
    """One CSV file parsed per a map into temporary files, in session units (t [s], q
    [rad], dq [rad/s], torques [Nm], contact bool), repeated rows dropped; ``counts``
    holds the ``rows`` read, ``repeated_rows`` dropped and ``samples`` kept. Use it as a
    context manager: the files go when it closes."""

    def __init__(self, cmap: CsvMap) -> None:
        self.time = RowSpill(1)
        self.joints = {prefix: RowSpill(len(spec.names)) for prefix, spec in
                       cmap.joints.items()}
        self.contact = RowSpill(1, np.bool_) if cmap.contact is not None else None
        self.counts: dict[str, int] = {}

    def __enter__(self) -> CsvSpill:
        return self

    def __exit__(self, *exc: object) -> None:
        for spill in self._spills().values():
            spill.close()

    def _spills(self) -> dict[str, RowSpill]:
        spills = {"t": self.time, **self.joints}
        if self.contact is not None:
            spills["contact"] = self.contact
        return spills

    def times(self) -> Iterator[np.ndarray]:
        """Yield the kept samples' times [s], a block at a time."""
        return spilled_times(self.time, BLOCK_ROWS)

    def chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield the session columns of the kept samples, a block at a time."""
        return spilled_session_chunks(self._spills(), BLOCK_ROWS)


def spill_csv(path: Path, cmap: CsvMap) -> CsvSpill:
    """Parse one CSV file per the map into a :class:`CsvSpill`, in bounded memory.

    Raises InputError naming the file and, as for the whole file read at once, the first
    problem in the order time, joints (map order), contact label: a missing or repeated
    column, a value that is not a number, an empty value; then a label other than 0/1,
    then time that goes back (the first data row that has each).
    """
    if not path.is_file():
        raise InputError("no such CSV file", path)
    names = [cmap.time_column, *[n for spec in cmap.joints.values() for n in spec.names],
             *([cmap.contact] if cmap.contact is not None else [])]
    spill = CsvSpill(cmap)
    try:
        _parse(path, cmap, names, spill)
    except BaseException:
        spill.__exit__()
        raise
    return spill


def _blocks(path: Path, separator: str) -> Iterator[pl.DataFrame]:
    """Yield the file's header as an empty frame, then its data rows in frames of about
    :data:`BLOCK_ROWS` rows, every value a string, parsed by Polars as ``pl.read_csv``
    parses the whole file (lines are gathered until their double quotes pair up, so a
    quoted field may span lines)."""
    with open_input(path, "CSV file", "csv") as fh:
        header = _record(fh, fh.readline())
        yield _frame(header, [], separator)
        lines: list[bytes] = []
        for line in fh:
            lines.append(_record(fh, line))
            if len(lines) >= BLOCK_ROWS:
                yield _frame(header, lines, separator)
                lines = []
        if lines:
            yield _frame(header, lines, separator)


def _record(fh, line: bytes) -> bytes:
    """Return ``line`` with the lines that follow while a quoted field is open."""
    while line.count(b'"') % 2:
        more = fh.readline()
        if not more:
            break
        line += more
    return line


def _frame(header: bytes, lines: list[bytes], separator: str) -> pl.DataFrame:
    return pl.read_csv(io.BytesIO(header + b"".join(lines)), separator=separator,
                       infer_schema=False)


def _what(cmap: CsvMap) -> dict[str, str]:
    """Return what each mapped column is, for messages ("time", "q joint 1", ...)."""
    what = {cmap.time_column: "time"}
    for prefix, spec in cmap.joints.items():
        what.update({name: f"{prefix} joint {j}" for j, name in enumerate(spec.names, 1)})
    if cmap.contact is not None:
        what[cmap.contact] = "contact label"
    return what


def _parse(path: Path, cmap: CsvMap, names: list[str], spill: CsvSpill) -> None:
    what = _what(cmap)
    problems: dict[str, str] = {}
    label_problem = back_problem = None
    rows = kept = 0
    last_measured = last_t = None
    try:
        blocks = _blocks(path, cmap.delimiter)
        header = next(blocks).columns
        for name in names:
            if name not in header:
                problems[name] = f"no column {name!r} ({what[name]} in the map)"
            elif f"{name}_duplicated_0" in header:
                problems[name] = (f"column {name!r} ({what[name]}) appears more than once "
                                  "in the header")
        present = [n for n in dict.fromkeys(names) if n not in problems]
        for frame in blocks:
            values = {}
            for name in present:
                values[name], problem = _numeric(frame, name, rows, what[name])
                if problem is not None:
                    problems.setdefault(name, problem)
            if not problems:
                label_problem = label_problem or _label_problem(cmap, values, rows)
                block_kept, last_measured = _not_repeated(cmap, values, last_measured)
                t = values[cmap.time_column][block_kept] * cmap.time_factor
                if back_problem is None:
                    steps = np.diff(t, prepend=last_t) if last_t is not None else np.diff(t)
                    going_back = np.flatnonzero(steps <= 0)
                    if going_back.size:
                        index = going_back[0] + (1 if last_t is None else 0)
                        row = rows + int(np.flatnonzero(block_kept)[index]) + 1
                        back_problem = (f"column {cmap.time_column!r} (time) does not "
                                        f"increase at data row {row}")
                last_t = t[-1] if t.size else last_t
                _spill_block(spill, cmap, values, block_kept, t)
                kept += int(block_kept.sum())
            rows += frame.height
    except (pl.exceptions.PolarsError, OSError, UnicodeDecodeError) as err:
        raise InputError(f"cannot read this CSV ({type(err).__name__}: "
                         f"{str(err).splitlines()[0]})", path) from err
    if rows == 0:
        raise InputError("no data rows", path)
    for problem in (*(problems[n] for n in names if n in problems), label_problem,
                    back_problem):
        if problem is not None:
            raise InputError(problem, path)
    spill.counts = {"rows": rows, "repeated_rows": rows - kept, "samples": kept}


def _numeric(frame: pl.DataFrame, column: str, offset: int, what: str
             ) -> tuple[np.ndarray, str | None]:
    """Return one block of a CSV column as float64 and the problem of its first value
    that is not a number (data rows counted from the file's first, ``offset`` before
    this block), or None."""
    text = frame.get_column(column).str.strip_chars()
    values = text.cast(pl.Float64, strict=False).fill_nan(None)
    bad = (values.is_null() | values.is_infinite()).arg_true()
    if bad.len():
        row = int(bad[0])
        return np.zeros(0), (f"column {column!r} ({what}) holds {text[row]!r} at data row "
                             f"{offset + row + 1}, not a number")
    return values.to_numpy(), None


def _label_problem(cmap: CsvMap, values: dict[str, np.ndarray], offset: int) -> str | None:
    """Return the problem of the block's first contact label other than 0 or 1, or None."""
    if cmap.contact is None:
        return None
    label = values[cmap.contact]
    bad = np.flatnonzero((label != 0) & (label != 1))
    if not bad.size:
        return None
    return (f"column {cmap.contact!r} (contact label) holds {label[bad[0]]:g} at data row "
            f"{offset + bad[0] + 1}, expected 0 or 1")


def _not_repeated(cmap: CsvMap, values: dict[str, np.ndarray], last: np.ndarray | None
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """Return which rows of the block to keep (with ``drop_repeated_rows``, those whose
    measured values differ from the previous row's, across blocks) and the block's last
    measured row."""
    rows = len(values[cmap.time_column])
    if not cmap.drop_repeated_rows:
        return np.ones(rows, dtype=bool), None
    measured = np.column_stack([values[name] * cmap.joints[prefix].factor
                                for prefix in ("q", "dq", "tau")
                                for name in cmap.joints[prefix].names])
    with_last = measured if last is None else np.vstack([last, measured])
    keep = np.ones(rows, dtype=bool)
    changed = (np.diff(with_last, axis=0) != 0).any(axis=1)
    keep[1 if last is None else 0:] = changed
    return keep, measured[-1:]


def _spill_block(spill: CsvSpill, cmap: CsvMap, values: dict[str, np.ndarray],
                 keep: np.ndarray, t: np.ndarray) -> None:
    spill.time.append(t)
    for prefix, spec in cmap.joints.items():
        block = np.column_stack([values[name] for name in spec.names]) * spec.factor
        spill.joints[prefix].append(block[keep])
    if spill.contact is not None:
        assert cmap.contact is not None  # the spill has a contact column when the map has
        spill.contact.append(values[cmap.contact][keep] == 1)


def read_csv_columns(path: Path, cmap: CsvMap) -> tuple[dict[str, np.ndarray], dict]:
    """Read one CSV file per the map; return session columns and import counts, the
    whole file in memory (:func:`spill_csv` streams it).

    Columns are in session units (t [s], q [rad], dq [rad/s], torques [Nm], contact
    bool). The counts are ``rows`` read, ``repeated_rows`` dropped and ``samples`` kept.
    Raises InputError as :func:`spill_csv` does.
    """
    with spill_csv(path, cmap) as spill:
        chunks = list(spill.chunks())
        columns = {name: np.concatenate([c[name] for c in chunks]) for name in chunks[0]}
        return columns, spill.counts


class CsvImporter(Importer):
    """A CSV export of the joint streams, read per a column map (:class:`CsvSpill`)."""

    name = "csv"
    source = "csv"
    suffixes = (".csv",)
    description = "CSV exports, read per a column map (--map)."

    @dataclass(frozen=True)
    class Config:
        """The CSV format's option."""

        map_file: Path = field(metadata={
            "name": "map",
            "help": "Column map TOML (e.g. recorder/data/mindlab_csv_map.toml)."})

    def __init__(self, path: Path, cmap: CsvMap, spill: CsvSpill) -> None:
        self.path, self.cmap, self.spill = path, cmap, spill

    @classmethod
    def open(cls, path: Path, config: Config) -> CsvImporter:
        """Read the CSV file at ``path`` per the column map ``config.map_file``."""
        return cls.read(path, load_csv_map(config.map_file))

    @classmethod
    def read(cls, path: Path, cmap: CsvMap) -> CsvImporter:
        """Read the CSV file at ``path`` per ``cmap`` into temporary files
        (:func:`spill_csv`, which raises InputError naming the file and the problem)."""
        return cls(path, cmap, spill_csv(path, cmap))

    def times(self) -> Iterator[np.ndarray]:
        """Yield the kept samples' times [s], a block at a time."""
        return self.spill.times()

    def chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield the session columns of the kept samples, a block at a time."""
        return self.spill.chunks()

    def source_info(self) -> dict[str, Any]:
        """Return the CSV path, the map and the row counts (rows, repeated_rows,
        samples)."""
        return {"csv": str(self.path), "map": self.cmap.describe(), **self.spill.counts}

    def defaults(self) -> dict[str, Any]:
        """Return the robot the map names, if it names one."""
        return {} if self.cmap.robot is None else {"robot": self.cmap.robot}

    def file_name(self, meta: SessionMeta) -> str:
        """Return ``<csv stem>_<session file name>``."""
        return f"{self.path.stem}_{session_filename(meta)}"

    def summary(self) -> str:
        """Return the row counts in one line."""
        counts = self.spill.counts
        return (f"{counts['samples']} samples from {counts['rows']} rows, "
                f"{counts['repeated_rows']} repeated rows dropped")

    def close(self) -> None:
        """Remove the temporary files."""
        self.spill.__exit__()
