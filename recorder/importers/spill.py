"""Rows spilled to a temporary file while a long input is read, read back by range.

An importer whose input format decides things only at its end (a bag's time source,
which optional columns every message carries) appends what it reads here and writes
the session from it afterwards, so memory holds one chunk, not the whole recording.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator, Mapping

import numpy as np

from contactkit.schemas import N_JOINTS, InputError, joint_columns


class RowSpill:
    """Rows of ``width`` values of one ``dtype`` in an anonymous temporary file (removed
    when closed or collected)."""

    def __init__(self, width: int, dtype: type = np.float64) -> None:
        self.width = width
        self.dtype = np.dtype(dtype)
        self.rows = 0
        self._file = tempfile.TemporaryFile()  # noqa: SIM115 (closed by close())

    def append(self, values: np.ndarray) -> None:
        """Append rows: ``values`` (n, width), or (n,) for width 1; InputError naming the
        temporary directory when it is full or not writable."""
        values = np.ascontiguousarray(values, dtype=self.dtype)
        values = values.reshape(len(values), self.width)
        try:
            self._file.seek(0, 2)
            self._file.write(values.tobytes())
        except OSError as err:
            raise InputError(f"cannot write a temporary file ({err.strerror or err})",
                             tempfile.gettempdir()) from err
        self.rows += len(values)

    def regroup(self, width: int) -> None:
        """Read the same values from now on as rows of ``width`` (the values in order,
        their count a multiple of ``width``)."""
        self.rows = self.rows * self.width // width
        self.width = width

    def read(self, start: int, stop: int) -> np.ndarray:
        """Return rows ``start`` up to ``stop`` as an (n, width) array."""
        row_bytes = self.width * self.dtype.itemsize
        stop = min(stop, self.rows)
        if stop <= start or row_bytes == 0:
            return np.zeros((max(stop - start, 0), self.width), self.dtype)
        self._file.seek(start * row_bytes)
        data = self._file.read((stop - start) * row_bytes)
        return np.frombuffer(data, dtype=self.dtype).reshape(-1, self.width)

    def chunks(self, rows: int) -> Iterator[np.ndarray]:
        """Yield every row in order, ``rows`` at a time."""
        for start in range(0, self.rows, rows):
            yield self.read(start, start + rows)

    def close(self) -> None:
        """Remove the file."""
        self._file.close()


def spilled_times(time: RowSpill, block_rows: int) -> Iterator[np.ndarray]:
    """Yield spilled time stamps [s] (rows of one value) as (n,) arrays, ``block_rows``
    at a time."""
    return (t[:, 0] for t in time.chunks(block_rows))


def spilled_session_chunks(spills: Mapping[str, RowSpill], block_rows: int
                           ) -> Iterator[dict[str, np.ndarray]]:
    """Yield session columns from spills holding the same samples, ``block_rows`` at a
    time, in the spills' order: a spill of rows of 7 gives the joint columns of its
    prefix (``q`` -> ``q_1`` .. ``q_7``), one of rows of one value the column of its
    name (``t``, ``contact``)."""
    rows = min(spill.rows for spill in spills.values())
    for start in range(0, rows, block_rows):
        columns: dict[str, np.ndarray] = {}
        for name, spill in spills.items():
            block = spill.read(start, start + block_rows)
            if spill.width == N_JOINTS:
                columns.update(zip(joint_columns(name), block.T, strict=True))
            else:
                columns[name] = block[:, 0]
        yield columns
