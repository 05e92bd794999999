"""Session files (format v1): one Parquet file per recording, read, validated and
written whole (:func:`read_session`, :func:`validate_session`, :func:`write_session`) or
in row-group batches (:func:`iter_sample_batches`, :func:`write_session_batches`).

The columns and their rules are :mod:`contactkit.schemas.columns`; the metadata, one
JSON document under the Parquet key-value metadata key ``contactkit.session``, is
:class:`contactkit.schemas.metadata.SessionMeta`.
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.errors import InputError
from contactkit.schemas.columns import (
    ALL_JOINT_PREFIXES,
    COLUMN_ORDER,
    FORCE_COLUMNS,
    REQUIRED_COLUMNS,
    WRENCH_HAT_COLUMNS,
    check_joint_count,
    check_times,
    column_array,
    column_type,
    hard_limit,
    joint_columns,
)
from contactkit.schemas.metadata import SessionMeta
from contactkit.util.atomic import Owned, atomic_write, check_target
from contactkit.util.safe_open import parse_json

METADATA_KEY = b"contactkit.session"


def session_schema(columns: Iterable[str], meta: SessionMeta | None = None) -> pa.Schema:
    """Return the Arrow schema for the given session columns, in canonical order."""
    wanted = set(columns)
    unknown = wanted - set(COLUMN_ORDER)
    if unknown:
        raise InputError(f"unexpected column {sorted(unknown)[0]!r}")
    schema = pa.schema([pa.field(c, column_type(c), nullable=False) for c in COLUMN_ORDER
                        if c in wanted])
    if meta is not None:
        schema = schema.with_metadata({METADATA_KEY: meta.to_json().encode()})
    return schema


@dataclass
class Session:
    """A validated session: its metadata and its columns as an Arrow table."""

    meta: SessionMeta
    table: pa.Table
    path: Path | None = None

    def column(self, name: str) -> np.ndarray:
        """Return one column as a numpy array (float64, or bool for ``contact``)."""
        return column_array(self.table.column(name))

    def joints(self, prefix: str) -> np.ndarray:
        """Return the 7 columns ``prefix_1..prefix_7`` as an (N, 7) float64 array."""
        return np.column_stack([self.column(c) for c in joint_columns(prefix)])

    def has(self, name: str) -> bool:
        """Return whether the session has the column (optional columns may be absent)."""
        return name in self.table.column_names

    @property
    def t(self) -> np.ndarray:
        """Time stamps [s] since session start, shape (N,)."""
        return self.column("t")

    @property
    def q(self) -> np.ndarray:
        """Joint positions [rad], shape (N, 7)."""
        return self.joints("q")

    @property
    def dq(self) -> np.ndarray:
        """Joint velocities [rad/s], shape (N, 7)."""
        return self.joints("dq")

    @property
    def tau(self) -> np.ndarray:
        """Measured joint torques [Nm], gravity included, shape (N, 7)."""
        return self.joints("tau")

    def complete(self) -> Session:
        """Return the session without samples that lack a joint value (NaN gaps left by a
        CAN source); the feature chain treats the gap as one longer time step."""
        table = complete_table(self.table)
        if table is self.table:
            return self
        if table.num_rows == 0:
            raise InputError(f"no complete sample: each of the {self.table.num_rows} samples "
                             "lacks a joint value", self.path)
        return Session(meta=self.meta, table=table, path=self.path)

    @property
    def n_samples(self) -> int:
        """Number of samples (rows)."""
        rows: int = self.table.num_rows
        return rows

    @property
    def duration_s(self) -> float:
        """Time between the first and last sample [s] (0 for fewer than two samples)."""
        t = self.t
        return float(t[-1] - t[0]) if len(t) > 1 else 0.0


def complete_table(table: pa.Table) -> pa.Table:
    """Return the rows of a session table (or of a chunk of one) that have every joint
    value (q, dq, tau); the table itself when none is missing."""
    keep = np.ones(table.num_rows, dtype=bool)
    for prefix in ("q", "dq", "tau"):
        for name in joint_columns(prefix):
            keep &= np.isfinite(column_array(table.column(name)))
    if keep.all():
        return table
    return table.filter(pa.array(keep))


def new_session_id() -> str:
    """Return a fresh random session id (32 hex digits)."""
    return uuid.uuid4().hex


def table_from_columns(columns: Mapping[str, np.ndarray], meta: SessionMeta) -> pa.Table:
    """Build a session table (canonical column order, metadata attached) from arrays."""
    schema = session_schema(columns.keys(), meta)
    arrays = [pa.array(np.asarray(columns[f.name]), type=f.type) for f in schema]
    return pa.Table.from_arrays(arrays, schema=schema)


def write_session(path: str | Path, columns: Mapping[str, np.ndarray] | pa.Table,
                  meta: SessionMeta, *, overwrite: bool = False) -> Path:
    """Validate and write a session atomically; return the written path.

    The data go to a temporary file in the same directory, are flushed to disk and
    then linked into place, so a reader never sees a half-written file. An existing
    file is left untouched (``InputError``) unless ``overwrite`` is true.
    """
    path = Path(path)
    meta.check(path)
    if isinstance(columns, pa.Table):
        table = table_from_columns({n: columns.column(n).to_numpy() for n in columns.column_names},
                                   meta)
    else:
        table = table_from_columns(columns, meta)
    validate_table(table, path, allows_gaps(meta))
    check_target(path, overwrite=overwrite)
    atomic_write_parquet(table, path, overwrite=overwrite)
    return path


def atomic_write_parquet(table: pa.Table, path: Path, *, overwrite: bool,
                         owned: Owned | None = None) -> None:
    """Write ``table`` to ``path`` with :func:`contactkit.util.atomic.atomic_write`
    (``overwrite`` and ``owned`` are its overwrite policy)."""
    with atomic_write(path, overwrite=overwrite, owned=owned) as tmp:
        pq.write_table(table, tmp.file, compression="zstd")


def read_session_meta(path: str | Path) -> tuple[SessionMeta, pq.FileMetaData]:
    """Read only the metadata of a session file (its Parquet footer).

    Returns the session metadata and the Parquet file metadata (row count, column
    statistics). Raises :class:`InputError` on a foreign or corrupt file: no or bad
    metadata (parsed with :func:`~contactkit.util.safe_open.parse_json`'s bounds), no
    time column ``t`` of doubles.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    try:
        footer = pq.read_metadata(path)
    except (pa.ArrowInvalid, OSError) as err:
        raise InputError(f"not a readable Parquet file ({_first_line(err)})", path) from err
    kv = footer.metadata or {}
    if METADATA_KEY not in kv:
        raise InputError("no contactkit session metadata (not a contactkit session file)", path)
    doc = parse_json(kv[METADATA_KEY], "session metadata", path)
    try:
        field = footer.schema.to_arrow_schema().field("t")
    except (KeyError, pa.ArrowInvalid) as err:
        raise InputError("no time column 't' (not a contactkit session file)", path) from err
    if field.type != pa.float64():
        raise InputError(f"column 't' has type {field.type}, expected double", path)
    return SessionMeta.from_dict(doc, path), footer


def validate_session(path: str | Path) -> Session:
    """Read and fully validate a session file; return it.

    Raises :class:`InputError` naming the file and the first problem found: not
    Parquet, missing metadata, unknown schema version, missing or unexpected
    column, wrong joint count, wrong type, NaN/inf, non-increasing ``t``.
    """
    path = Path(path)
    meta, _ = read_session_meta(path)
    try:
        # ParquetFile, not pq.read_table: that one goes through pyarrow.dataset, whose
        # import loads pandas (a second of start-up for `recorder info`)
        with pq.ParquetFile(path) as file:
            table = file.read()
    except (pa.ArrowInvalid, OSError) as err:
        raise InputError(f"cannot read the Parquet data ({_first_line(err)})", path) from err
    validate_table(table, path, allows_gaps(meta))
    return Session(meta=meta, table=table, path=path)


read_session = validate_session


def allows_gaps(meta: SessionMeta) -> bool:
    """Return whether a session may hold NaN joint values: only when its source
    reported incomplete samples (a CAN frame that never came)."""
    return int(meta.source_info.get("incomplete_samples", 0) or 0) > 0


def validate_table(table: pa.Table, path: str | Path | None = None,
                   gaps_allowed: bool = False) -> None:
    """Check a session table's columns, types and values; raise :class:`InputError`.

    NaN is accepted in q, dq and tau only with ``gaps_allowed``; ``t`` must always be
    finite and strictly increasing.
    """
    names = table.column_names
    check_joint_count(names, path)
    for name in REQUIRED_COLUMNS:
        if name not in names:
            raise InputError(f"missing column {name!r}", path)
    for name in names:
        if name not in COLUMN_ORDER:
            raise InputError(f"unexpected column {name!r}", path)
        expected = column_type(name)
        if table.schema.field(name).type != expected:
            raise InputError(f"column {name!r} has type {table.schema.field(name).type}, "
                             f"expected {expected}", path)
        if table.column(name).null_count:
            raise InputError(f"null values in column {name!r}", path)
    gap_columns = set(REQUIRED_COLUMNS[1:]) if gaps_allowed else set()
    for name in (n for n in names if n != "contact"):
        values = column_array(table.column(name))
        bad = np.isinf(values) if name in gap_columns else ~np.isfinite(values)
        if bad.any():
            row = int(np.argmax(bad))
            kind = "NaN" if math.isnan(values[row]) else "infinite value"
            raise InputError(f"{kind} in column {name!r} at row {row}", path)
        bound = hard_limit(name)
        if bound is not None:
            with np.errstate(invalid="ignore"):
                beyond = np.abs(values) > bound
            if beyond.any():
                row = int(np.argmax(beyond))
                raise InputError(f"impossible value {values[row]:.6g} in column {name!r} at "
                                 f"row {row} (beyond the hard limit {bound:g}: a corrupt "
                                 "file or a unit error)", path)
    t = column_array(table.column("t"))
    if len(t) == 0:
        raise InputError("session has no samples", path)
    check_times(t, path)


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__


ROW_GROUP_ROWS = 65_536
"""Rows per Parquet row group of a session written in chunks (about 65 s at 1 kHz)."""


def iter_session_batches(path: str | Path, batch_rows: int = ROW_GROUP_ROWS,
                         columns: Sequence[str] | None = None) -> Iterator[pa.RecordBatch]:
    """Yield a session file's rows as record batches of at most ``batch_rows`` rows,
    each validated as :func:`validate_session` does, ``t`` increasing across them;
    ``columns`` reads (and validates) only those columns, at least the required ones.

    Memory stays bounded by one batch however long the session is. Raises
    :class:`InputError` naming the file and the problem, on the batch that has it.
    """
    path = Path(path)
    meta, _ = read_session_meta(path)
    gaps = allows_gaps(meta)
    try:
        groups = _group_batches(pq.ParquetFile(path), batch_rows, columns)
        batches = _rebatched(groups, batch_rows)
        offset, last_t = 0, -math.inf
        for batch in batches:
            _validate_chunk(pa.Table.from_batches([batch]), path, gaps, offset, last_t)
            offset += batch.num_rows
            last_t = float(batch.column("t")[-1].as_py())
            yield batch
    except (pa.ArrowInvalid, OSError) as err:
        raise InputError(f"cannot read the Parquet data ({_first_line(err)})", path) from err
    if offset == 0:
        raise InputError("session has no samples", path)


@dataclass(frozen=True)
class SampleBatch:
    """Consecutive samples of a session, each joint quantity stacked (joints 1..7 as
    columns): times ``t`` (n,) [s]; ``q`` [rad], ``dq`` [rad/s], ``tau`` [Nm] (n, 7);
    and the session's optional columns where it has them (None where it has not):
    ``q_d`` [rad], ``dq_d`` [rad/s], ``tau_ext_hat`` [Nm] (n, 7), ``f_ext`` [N]
    (n, 3), ``f_ext_hat`` (n, 6: force [N], then moment [Nm]), ``contact`` (n,) bool,
    ``robot_mode`` (n,) int8 and ``command_success_rate`` (n,). This is what the
    feature chain, the replay, the statistics and the live listeners take."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    q_d: np.ndarray | None = None
    dq_d: np.ndarray | None = None
    tau_ext_hat: np.ndarray | None = None
    f_ext: np.ndarray | None = None
    f_ext_hat: np.ndarray | None = None
    contact: np.ndarray | None = None
    robot_mode: np.ndarray | None = None
    command_success_rate: np.ndarray | None = None

    @classmethod
    def from_columns(cls, columns: pa.Table | pa.RecordBatch | Mapping[str, np.ndarray]
                     ) -> SampleBatch:
        """Return the batch of session columns (a table, a record batch, or a mapping
        of column name to array, as a capture's chunk): ``t`` and every joint column
        of q, dq and tau are required; an optional group is taken where all its
        columns are present."""
        if isinstance(columns, (pa.Table, pa.RecordBatch)):
            names = set(columns.schema.names)

            def get(name: str) -> np.ndarray:
                values: np.ndarray = columns.column(name).to_numpy(zero_copy_only=False)
                return values
        else:
            names = set(columns)

            def get(name: str) -> np.ndarray:
                return np.asarray(columns[name])

        def stacked(group: Sequence[str]) -> np.ndarray | None:
            if not names.issuperset(group):
                return None
            return np.column_stack([get(c) for c in group]).astype(float, copy=False)

        def single(name: str) -> np.ndarray | None:
            return get(name) if name in names else None

        fields_in_order: list[Any] = [
            np.asarray(get("t"), dtype=float),
            *(stacked(joint_columns(p)) for p in ALL_JOINT_PREFIXES),
            stacked(FORCE_COLUMNS), stacked(WRENCH_HAT_COLUMNS), single("contact"),
            single("robot_mode"), single("command_success_rate")]
        return cls(*fields_in_order)

    def __len__(self) -> int:
        """Return the number of samples."""
        return len(self.t)

    def take(self, rows: np.ndarray | slice) -> SampleBatch:
        """Return the samples ``rows`` (indices, a boolean mask or a slice)."""
        taken: dict[str, Any] = {f.name: None if getattr(self, f.name) is None
                                 else getattr(self, f.name)[rows] for f in fields(self)}
        return SampleBatch(**taken)

    def complete(self) -> SampleBatch:
        """Return the samples that have a time and every joint value (q, dq, tau), as
        :func:`complete_table` keeps them; the batch itself when none is missing."""
        joints = (self.q, self.dq, self.tau)
        if np.isfinite(self.t).all() and all(np.isfinite(x).all() for x in joints):
            return self  # checked as whole arrays: a reduction along rows of 7 costs 10x
        keep = np.isfinite(self.t) & np.isfinite(self.q).all(axis=1) \
            & np.isfinite(self.dq).all(axis=1) & np.isfinite(self.tau).all(axis=1)
        return self.take(keep)


def iter_sample_batches(source: Session | str | Path, batch_rows: int = ROW_GROUP_ROWS,
                        columns: Sequence[str] | None = None) -> Iterator[SampleBatch]:
    """Yield the complete samples (:meth:`SampleBatch.complete`) of a session, a file
    read and validated by :func:`iter_session_batches` or a :class:`Session` in
    memory, as :class:`SampleBatch` of at most ``batch_rows`` rows; batches left empty
    are skipped. ``columns`` as for :func:`iter_session_batches` (files only)."""
    if isinstance(source, Session):
        batches: Iterable[pa.RecordBatch] = source.table.to_batches(max_chunksize=batch_rows)
    else:
        batches = iter_session_batches(source, batch_rows, columns)
    for batch in batches:
        samples = SampleBatch.from_columns(batch).complete()
        if len(samples):
            yield samples


def _group_batches(file: pq.ParquetFile, batch_rows: int,
                   columns: Sequence[str] | None = None) -> Iterator[pa.RecordBatch]:
    """Read one row group at a time: a single ``iter_batches`` over the whole file keeps
    buffers of the groups already read (RSS grew by about 30 MB per 65,536 rows)."""
    for group in range(file.metadata.num_row_groups):
        yield from file.iter_batches(batch_size=batch_rows, row_groups=[group],
                                     columns=None if columns is None else list(columns),
                                     use_threads=False)


def _rebatched(batches: Iterable[pa.RecordBatch], rows: int) -> Iterator[pa.RecordBatch]:
    """Yield the rows of ``batches`` in batches of exactly ``rows`` rows (the last may
    hold fewer), whatever the row groups."""
    pending: list[pa.RecordBatch] = []
    count = 0
    for batch in batches:
        pending.append(batch)
        count += batch.num_rows
        while count >= rows:
            table = pa.Table.from_batches(pending)
            yield table.slice(0, rows).combine_chunks().to_batches()[0]
            rest = table.slice(rows)
            pending, count = rest.to_batches(), rest.num_rows
    if count:
        yield pa.Table.from_batches(pending).combine_chunks().to_batches()[0]


def _validate_chunk(table: pa.Table, path: Path, gaps_allowed: bool, offset: int,
                    last_t: float) -> None:
    """Validate one chunk of a session; rows in messages count from the file's start."""
    if table.num_rows == 0:
        return
    try:
        validate_table(table, path, gaps_allowed)
    except InputError as err:
        if offset == 0:
            raise
        raise InputError(f"{err.problem} (counted from row {offset})", path) from err
    if math.isfinite(last_t):
        check_times(column_array(table.column("t"))[:1], path, offset, last_t)


def write_session_batches(path: str | Path, batches: Iterable[pa.RecordBatch],
                          meta: SessionMeta, *, overwrite: bool = False,
                          row_group_rows: int = ROW_GROUP_ROWS) -> int:
    """Validate and write a session from record batches, one Parquet row group of about
    ``row_group_rows`` rows at a time, atomically as :func:`write_session` does.

    Memory stays bounded by one row group however long the session is. Returns the
    number of rows written; raises :class:`InputError` as :func:`write_session` does.
    """
    path = Path(path)
    meta.check(path)
    check_target(path, overwrite=overwrite)
    gaps = allows_gaps(meta)
    written = 0

    with atomic_write(path, overwrite=overwrite) as tmp:
        writer, last_t = None, -math.inf
        try:
            for group in _row_groups(batches, row_group_rows):
                schema = session_schema(group.column_names, meta)
                group = group.select(schema.names).cast(schema)
                _validate_chunk(group, path, gaps, written, last_t)
                if writer is None:
                    writer = pq.ParquetWriter(tmp.file, schema, compression="zstd")
                writer.write_table(group, row_group_size=row_group_rows)
                written += group.num_rows
                last_t = float(group.column("t")[-1].as_py())
        finally:
            if writer is not None:
                writer.close()
        if written == 0:
            raise InputError("session has no samples", path)
    return written


def _row_groups(batches: Iterable[pa.RecordBatch], rows: int) -> Iterator[pa.Table]:
    """Gather record batches into tables of at least ``rows`` rows (the last may be less)."""
    pending: list[pa.RecordBatch] = []
    count = 0
    for batch in batches:
        pending.append(batch)
        count += batch.num_rows
        if count >= rows:
            yield pa.Table.from_batches(pending).combine_chunks()
            pending, count = [], 0
    if count:
        yield pa.Table.from_batches(pending).combine_chunks()
