"""Every timeseries feature of every sample of many sessions, in one Parquet table.

Each session is read, computed and written batch by batch (one row group per batch),
so a long session never sits in memory whole.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.features import chain_cache
from contactkit.features.chain_cache import iter_chain_batches
from contactkit.features.timeseries import ALL_TIMESERIES, ChainConfig, columns_of
from contactkit.schemas import InputError
from contactkit.schemas.session import (
    iter_sample_batches,
    iter_session_batches,
    read_session_meta,
)
from contactkit.util.atomic import atomic_write
from contactkit.util.progress import ProgressCallback


def per_sample_tables(path: str | Path, config: ChainConfig | None = None
                      ) -> Iterator[pa.Table]:
    """Yield one session's per-sample table batch by batch: ``session_id``, ``t``, then
    the columns of every timeseries feature (``q_1``.., ``r_1``.., ``f_x``..,
    ``m_norm``; see :mod:`contactkit.features.timeseries`). The whole file is
    validated before the first batch (raises :class:`InputError` naming it)."""
    path = Path(path)
    meta, _ = read_session_meta(path)
    for _ in iter_session_batches(path, chain_cache.BATCH_ROWS):
        pass
    config = config or ChainConfig()
    for batch, series in iter_chain_batches(iter_sample_batches(path, chain_cache.BATCH_ROWS),
                                            config.robot_setup(meta, path), config,
                                            ALL_TIMESERIES):
        columns = {"session_id": pa.array([meta.session_id] * len(batch)),
                   "t": pa.array(batch.t)}
        for name, values in series.items():
            for label, column in zip(columns_of(name), values.T, strict=True):
                columns[label] = pa.array(column.copy())
        yield pa.table(columns)


def write_per_sample_table(files: Sequence[Path], out: Path,
                           progress: ProgressCallback | None = None,
                           config: ChainConfig | None = None, *,
                           overwrite: bool = False) -> tuple[int, list[InputError]]:
    """Write one row per sample of every readable session (``session_id`` and the
    columns of :func:`contactkit.features.extract.timeseries_columns`, computed with
    ``config``) to ``out`` atomically, one row group per batch of a session; return the
    number of sessions written and the ones refused. An existing ``out`` is replaced
    only with ``overwrite``."""
    out = Path(out)
    writer = None
    written, problems = 0, []
    with atomic_write(out, overwrite=overwrite) as tmp:
        try:
            for i, path in enumerate(files):
                try:
                    rows = 0
                    for table in per_sample_tables(path, config):
                        if writer is None:
                            writer = pq.ParquetWriter(tmp.file, table.schema,
                                                      compression="zstd")
                        writer.write_table(table)
                        rows += table.num_rows
                    if rows == 0:
                        raise InputError("no complete sample: every sample lacks a joint "
                                         "value", path)
                    written += 1
                except InputError as err:
                    problems.append(err)
                finally:
                    if progress:
                        progress(i + 1, len(files))
            if writer is None:
                raise InputError("no session could be processed", Path(files[0]).parent)
        finally:
            if writer is not None:
                writer.close()
    return written, problems
