"""CSV exports of a robot's joint streams turned into sessions, column by column per a map.

Rows that repeat the previous row's measured values (q, dq, tau) are dropped and
counted when the map says so: a log written faster than the robot's state updates
(the MindLab files log at 200 Hz a state that changes at about 100 Hz) holds each
state twice with two time stamps, and keeping both would halve the apparent time
step and put zero-velocity steps into every difference.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from contactkit.recorder.csv_map import CsvMap
from contactkit.recorder.importer import write_imported_session
from contactkit.recorder.metadata import session_filename
from contactkit.schemas import InputError, SessionMeta, joint_columns


def read_csv_columns(path: Path, cmap: CsvMap) -> tuple[dict[str, np.ndarray], dict]:
    """Read one CSV file per the map; return session columns and import counts.

    Columns are in session units (t [s], q [rad], dq [rad/s], torques [Nm], contact
    bool). The counts are ``rows`` read, ``repeated_rows`` dropped and ``samples`` kept.
    Raises InputError naming the file and the column for a missing or repeated column, a
    value that is not a number, an empty value, a label other than 0/1, or time that goes
    back.
    """
    if not path.is_file():
        raise InputError("no such CSV file", path)
    try:
        frame = pl.read_csv(path, separator=cmap.delimiter, infer_schema=False)
    except (pl.exceptions.PolarsError, OSError, UnicodeDecodeError) as err:
        raise InputError(f"cannot read this CSV ({type(err).__name__}: "
                         f"{str(err).splitlines()[0]})", path) from err
    if frame.height == 0:
        raise InputError("no data rows", path)
    t = _numeric(frame, cmap.time_column, path, "time") * cmap.time_factor
    values = {}
    for prefix, spec in cmap.joints.items():
        values[prefix] = np.column_stack(
            [_numeric(frame, name, path, f"{prefix} joint {j}")
             for j, name in enumerate(spec.names, start=1)]) * spec.factor
    contact = None
    if cmap.contact is not None:
        label = _numeric(frame, cmap.contact, path, "contact label")
        bad = np.flatnonzero((label != 0) & (label != 1))
        if bad.size:
            raise InputError(f"column {cmap.contact!r} (contact label) holds {label[bad[0]]:g} "
                             f"at data row {bad[0] + 1}, expected 0 or 1", path)
        contact = label == 1
    keep = np.ones(frame.height, dtype=bool)
    if cmap.drop_repeated_rows:
        measured = np.column_stack([values[p] for p in ("q", "dq", "tau")])
        keep[1:] = (np.diff(measured, axis=0) != 0).any(axis=1)
    t = t[keep]
    going_back = np.flatnonzero(np.diff(t) <= 0)
    if going_back.size:
        row = int(np.flatnonzero(keep)[going_back[0] + 1]) + 1
        raise InputError(f"column {cmap.time_column!r} (time) does not increase at data row "
                         f"{row}", path)
    columns = {"t": t}
    for prefix, array in values.items():
        for col, series in zip(joint_columns(prefix), array[keep].T, strict=True):
            columns[col] = series
    if contact is not None:
        columns["contact"] = contact[keep]
    counts = {"rows": frame.height, "repeated_rows": int((~keep).sum()),
              "samples": int(keep.sum())}
    return columns, counts


def _numeric(frame: pl.DataFrame, column: str, path: Path, what: str) -> np.ndarray:
    """Return one CSV column as float64, or raise InputError naming the column."""
    if column not in frame.columns:
        raise InputError(f"no column {column!r} ({what} in the map)", path)
    if f"{column}_duplicated_0" in frame.columns:
        raise InputError(f"column {column!r} ({what}) appears more than once in the header",
                         path)
    text = frame.get_column(column).str.strip_chars()
    values = text.cast(pl.Float64, strict=False).fill_nan(None)
    bad = (values.is_null() | values.is_infinite()).arg_true()
    if bad.len():
        row = int(bad[0])
        raise InputError(f"column {column!r} ({what}) holds {text[row]!r} at data row "
                         f"{row + 1}, not a number", path)
    return values.to_numpy()


def import_csv(path: Path, cmap: CsvMap, meta: SessionMeta, out_dir: Path) -> Path:
    """Write the session read from one CSV file; return its path.

    The file is named after the CSV file and the session (``<stem>_<condition>_...``);
    ``source_info`` records the CSV path, the map and the row counts.
    """
    columns, counts = read_csv_columns(path, cmap)
    meta.source_info = {"csv": str(path), "map": cmap.describe(), **counts}
    return write_imported_session(columns, meta, out_dir,
                                  f"{path.stem}_{session_filename(meta)}")
