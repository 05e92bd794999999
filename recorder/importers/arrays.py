"""Plain numeric arrays as labs export them: text, CSV or .npy.

Text files hold one number per line (7 consecutive lines per sample for joint
arrays) or 7 numbers per line separated by spaces, tabs or commas. ``.npy`` files
hold an (N,) or (N, 7) array.

:func:`spill_array` reads a file a block at a time into a temporary file, so an
hour-long recording takes one block of memory; :func:`load_array` returns it whole.
A ``.npy`` file that is not a plain C-order array of numbers (Fortran order, object
or text values, format 3.0, a truncated file) is read whole with ``np.load``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from contactkit.recorder.importers.base import Importer
from contactkit.recorder.importers.spill import RowSpill, spilled_session_chunks, spilled_times
from contactkit.schemas import N_JOINTS, InputError

BLOCK_LINES = 65_536
"""Text lines (or .npy rows) read at a time."""
BLOCK_ROWS = 16_384
"""Samples handed to the writer at a time."""


def spill_array(path: str | Path, width: int) -> RowSpill:
    """Read ``path`` into a :class:`RowSpill` of rows of ``width`` values (float64), in
    bounded memory; close it when done.

    Raises InputError naming the file when it cannot be read, holds non-numbers or
    has a length that is not a multiple of ``width``.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    try:
        raw, ndim = _npy(path) if path.suffix == ".npy" else _text(path)
    except InputError:
        raise
    except (ValueError, TypeError, OSError, EOFError) as err:
        raise InputError(f"not a numeric array ({type(err).__name__}: {str(err)[:80]})",
                         path) from err
    try:
        return _shaped(raw, ndim, width, path)
    except InputError:
        raw.close()
        raise


def _shaped(raw: RowSpill, ndim: int, width: int, path: Path) -> RowSpill:
    """Check a read array's shape against ``width`` and return it as rows of ``width``."""
    if ndim not in (1, 2):
        raise InputError(f"expected a table of numbers, found {ndim} dimensions", path)
    if ndim == 2 and raw.width == 1:
        ndim = 1
    if width == 1:
        if ndim != 1:
            raise InputError(f"expected one value per line, found {raw.width}", path)
        return raw
    if ndim == 1:
        if raw.rows % width:
            raise InputError(f"{raw.rows} values is not a multiple of {width} joints", path)
        raw.regroup(width)
        return raw
    if raw.width != width:
        raise InputError(f"wrong joint count: {raw.width} values per line, expected "
                         f"{width}", path)
    return raw


def _text(path: Path) -> tuple[RowSpill, int]:
    """Read a text array: rows of numbers, the same count on every line (comments and
    blank lines skipped); return them spilled and their dimensions (1 when empty)."""
    lengths: set[int] = set()
    spill: RowSpill | None = None
    problem: Exception | None = None
    block: list[list[str]] = []

    def flush() -> None:
        nonlocal spill, problem
        rows, block[:] = list(block), []
        if not rows or problem is not None or len(lengths) > 1:
            return
        try:
            values = np.array(rows, dtype=float)
        except (ValueError, TypeError) as err:
            problem = err
            return
        spill = spill or RowSpill(values.shape[1])
        spill.append(values)

    try:
        with open(path) as fh:
            for line in _lines(fh):
                if line.strip() and not line.lstrip().startswith("#"):
                    block.append(line.split())
                    lengths.add(len(block[-1]))
                    if len(block) >= BLOCK_LINES:
                        flush()
            flush()
        if len(lengths) > 1:
            raise InputError(f"lines have different numbers of values {sorted(lengths)}",
                             path)
        if problem is not None:
            raise problem
    except BaseException:
        if spill is not None:
            spill.close()
        raise
    return (spill, 2) if spill is not None else (RowSpill(1), 1)


def _lines(fh) -> Iterator[str]:
    """Yield the lines of a text file as ``str.splitlines`` splits the whole text, with
    commas and semicolons read as spaces."""
    for line in fh:
        yield from line.replace(",", " ").replace(";", " ").splitlines()


def _npy(path: Path) -> tuple[RowSpill, int]:
    """Read a .npy array a block of rows at a time (whole, with ``np.load``, when it is
    not a plain C-order array of numbers); return it spilled and its dimensions."""
    with open(path, "rb") as fh:
        try:
            version = np.lib.format.read_magic(fh)
            header = {(1, 0): np.lib.format.read_array_header_1_0,
                      (2, 0): np.lib.format.read_array_header_2_0}[version]
            shape, fortran, dtype = header(fh)
        except (ValueError, KeyError, OSError, EOFError):
            return _whole_npy(path)  # np.load names the problem
        row_values = int(np.prod(shape[1:], dtype=np.int64))
        size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if (fortran or dtype.kind not in "biuf" or len(shape) not in (1, 2) or row_values == 0
                or path.stat().st_size - fh.tell() < size):
            return _whole_npy(path)
        spill = RowSpill(row_values)
        for start in range(0, shape[0], BLOCK_LINES):
            rows = min(BLOCK_LINES, shape[0] - start)
            data = fh.read(rows * row_values * dtype.itemsize)
            spill.append(np.frombuffer(data, dtype=dtype).astype(np.float64)
                         .reshape(rows, row_values))
    return spill, len(shape)


def _whole_npy(path: Path) -> tuple[RowSpill, int]:
    raw = np.asarray(np.load(path, allow_pickle=False), dtype=float)
    spill = RowSpill(raw.shape[1] if raw.ndim == 2 else 1)
    if raw.ndim in (1, 2):
        spill.append(raw)
    return spill, raw.ndim


def load_array(path: str | Path, width: int) -> np.ndarray:
    """Load ``path`` as an (N, width) float64 array (``width`` 1 gives shape (N,)).

    Raises InputError naming the file when it cannot be read, holds non-numbers or
    has a length that is not a multiple of ``width``.
    """
    spill = spill_array(path, width)
    try:
        values = spill.read(0, spill.rows).copy()
    finally:
        spill.close()
    return values[:, 0] if width == 1 else values


def spill_joint_arrays(t_path: str | Path, q_path: str | Path, dq_path: str | Path,
                       tau_path: str | Path) -> dict[str, RowSpill]:
    """Read time [s], q [rad], dq [rad/s] and tau [Nm] files into temporary files (see
    :func:`spill_array`; the caller closes them); check their lengths agree.

    Returns a dict with ``t`` (rows of 1) and ``q``, ``dq``, ``tau`` (rows of 7).
    """
    paths = {"t": t_path, "q": q_path, "dq": dq_path, "tau": tau_path}
    spills: dict[str, RowSpill] = {}
    try:
        for name, path in paths.items():
            spills[name] = spill_array(path, 1 if name == "t" else N_JOINTS)
        n = spills["t"].rows
        for name, spill in spills.items():
            if spill.rows != n:
                raise InputError(f"{spill.rows} samples, but the time file has {n}",
                                 paths[name])
    except BaseException:
        for spill in spills.values():
            spill.close()
        raise
    return spills


def load_joint_arrays(t_path: str | Path, q_path: str | Path, dq_path: str | Path,
                      tau_path: str | Path) -> dict[str, np.ndarray]:
    """Load time [s], q [rad], dq [rad/s] and tau [Nm] files; check their lengths agree.

    Returns a dict with ``t`` (N,) and ``q``, ``dq``, ``tau`` (N, 7).
    """
    spills = spill_joint_arrays(t_path, q_path, dq_path, tau_path)
    try:
        arrays = {name: spill.read(0, spill.rows).copy() for name, spill in spills.items()}
    finally:
        for spill in spills.values():
            spill.close()
    arrays["t"] = arrays["t"][:, 0]
    return arrays


class ArraysImporter(Importer):
    """Plain arrays: the time file [s] is the file imported, and the q [rad], dq [rad/s]
    and tau [Nm] files are its options (:func:`spill_joint_arrays`). Read a block at a
    time into temporary files, so memory stays bounded however long the recording."""

    name = "arrays"
    source = "arrays"
    description = ("Plain arrays (text, CSV or .npy): FILE holds the time stamps, --q, --dq "
                   "and --tau the joints.")

    @dataclass(frozen=True)
    class Config:
        """The joint files beside the time file."""

        q: Path = field(metadata={"help": "Joint positions, 7 values a line or one per line.",
                                  "unit": "rad"})
        dq: Path = field(metadata={"help": "Joint velocities, 7 values a line.",
                                   "unit": "rad/s"})
        tau: Path = field(metadata={"help": "Measured joint torques, 7 values a line.",
                                    "unit": "Nm"})

    def __init__(self, paths: list[Path], spills: dict[str, RowSpill]) -> None:
        self.paths, self.spills = paths, spills

    @classmethod
    def open(cls, path: Path, config: Config) -> ArraysImporter:
        """Read the time file ``path`` and the joint files ``config.q``, ``.dq`` and
        ``.tau``; InputError naming a file that cannot be used."""
        paths = [Path(p) for p in (path, config.q, config.dq, config.tau)]
        return cls(paths, spill_joint_arrays(*paths))

    def times(self) -> Iterator[np.ndarray]:
        """Yield the time stamps [s], a block at a time."""
        return spilled_times(self.spills["t"], BLOCK_ROWS)

    def chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield the session columns ``t``, ``q_*``, ``dq_*``, ``tau_*``, a block at a
        time."""
        return spilled_session_chunks(self.spills, BLOCK_ROWS)

    def source_info(self) -> dict[str, Any]:
        """Return the files imported (time, q, dq, tau)."""
        return {"imported_from": [str(p) for p in self.paths]}

    def summary(self) -> str:
        """Return the number of samples."""
        return f"{self.spills['t'].rows} samples"

    def close(self) -> None:
        """Remove the temporary files."""
        for spill in self.spills.values():
            spill.close()
