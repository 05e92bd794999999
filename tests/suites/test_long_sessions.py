"""Sessions in bounded memory: written from record batches row group by row group,
read back batch by batch, validated across the chunk boundaries."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from contactkit.schemas import InputError, SessionMeta, read_session, write_session
from contactkit.schemas.columns import REQUIRED_COLUMNS
from contactkit.schemas.session import iter_session_batches, session_schema, write_session_batches


def _meta() -> SessionMeta:
    return SessionMeta(session_id="long", source="sim", action="none")


def _batches(n: int = 1000, size: int = 50, bad_row: int | None = None,
             t_back_at: int | None = None) -> list[pa.RecordBatch]:
    t = np.arange(n) / 1000.0
    if t_back_at is not None:
        t[t_back_at] = t[t_back_at - 1]
    columns = {c: t if c == "t" else np.sin(t + i) for i, c in enumerate(REQUIRED_COLUMNS)}
    if bad_row is not None:
        columns["tau_3"][bad_row] = np.nan
    schema = session_schema(columns, _meta())
    return [pa.RecordBatch.from_arrays([pa.array(columns[f.name][s:s + size]) for f in schema],
                                       schema=schema) for s in range(0, n, size)]


def test_written_in_row_groups_read_in_batches(tmp_path: Path) -> None:
    chunked, whole = tmp_path / "chunked.parquet", tmp_path / "whole.parquet"
    assert write_session_batches(chunked, _batches(), _meta(), row_group_rows=300) == 1000
    write_session(whole, pa.Table.from_batches(_batches()), _meta())
    assert pq.ParquetFile(chunked).metadata.num_row_groups == 4
    assert read_session(chunked).table.equals(read_session(whole).table)
    assert read_session(chunked).meta == read_session(whole).meta
    batches = list(iter_session_batches(chunked, batch_rows=256))
    assert [b.num_rows for b in batches][:3] == [256, 256, 256]
    assert pa.Table.from_batches(batches).equals(read_session(whole).table)
    assert not list(tmp_path.glob(".*.tmp"))


@pytest.mark.parametrize(("kwargs", "problem"), [
    ({"bad_row": 700}, "NaN in column 'tau_3' at row 100 (counted from row 600)"),
    ({"t_back_at": 600}, "t is not strictly increasing at row 600"),
])
def test_a_bad_chunk_is_named_and_nothing_written(tmp_path: Path, kwargs, problem) -> None:
    path = tmp_path / "bad.parquet"
    with pytest.raises(InputError, match=problem.replace("(", r"\(").replace(")", r"\)")):
        write_session_batches(path, _batches(**kwargs), _meta(), row_group_rows=300)
    assert not list(tmp_path.iterdir())


def test_chunked_reader_checks_each_batch(tmp_path: Path) -> None:
    path = tmp_path / "s.parquet"
    write_session_batches(path, _batches(), _meta(), row_group_rows=300)
    table = pq.read_table(path)
    t = table.column("t").to_numpy().copy()
    t[500] = t[499]
    broken = table.set_column(0, "t", pa.array(t))
    pq.write_table(broken, tmp_path / "broken.parquet", row_group_size=300)
    with pytest.raises(InputError, match="not strictly increasing at row 500"):
        list(iter_session_batches(tmp_path / "broken.parquet", batch_rows=250))
