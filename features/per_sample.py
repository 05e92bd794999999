"""Every timeseries feature of every sample of many sessions, in one Parquet table."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.features.extract import timeseries_columns
from contactkit.schemas import InputError, read_session
from contactkit.util.progress import ProgressCallback


def write_per_sample_table(files: Sequence[Path], out: Path,
                           progress: ProgressCallback | None = None
                           ) -> tuple[int, list[InputError]]:
    """Write one row per sample of every readable session (``session_id`` and the
    columns of :func:`contactkit.features.extract.timeseries_columns`) to ``out``
    atomically; return the number of sessions written and the ones refused."""
    out = Path(out)
    tmp = out.with_name(f".{out.name}.tmp")
    writer = None
    written, problems = 0, []
    try:
        for i, path in enumerate(files):
            try:
                session = read_session(path)
            except InputError as err:
                problems.append(err)
                continue
            finally:
                if progress:
                    progress(i + 1, len(files))
            table = pa.table({"session_id": [session.meta.session_id] * session.n_samples,
                              **timeseries_columns(session)})
            if writer is None:
                writer = pq.ParquetWriter(tmp, table.schema, compression="zstd")
            writer.write_table(table)
            written += 1
        if writer is None:
            raise InputError("no session could be processed", Path(files[0]).parent)
        writer.close()
        tmp.replace(out)
    finally:
        if writer is not None:
            writer.close()
        tmp.unlink(missing_ok=True)
    return written, problems
