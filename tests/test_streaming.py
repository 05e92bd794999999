"""Long sessions streamed in chunks: the chunked chain equals the whole-session chain,
replay and features read a session row group by row group."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from contactkit.features import chain_cache
from contactkit.features.extract import timeseries_columns
from contactkit.features.per_sample import write_per_sample_table
from contactkit.features.timeseries import (
    ALL_TIMESERIES,
    ChainConfig,
    ChunkedChain,
    TimeseriesChain,
)
from contactkit.schemas import read_session
from tests.conftest import make_session


@pytest.fixture(scope="module")
def shove(tmp_path_factory) -> Path:
    return make_session(tmp_path_factory.mktemp("shove"), seed=5, action="shove", link=6,
                        duration_s=4.0, planned_at_s=2.0, rate_hz=500.0)


@pytest.mark.parametrize("size", [1, 7, 333, 1000, 1999, 5000])
def test_chunked_chain_equals_the_whole_session_chain(shove, size) -> None:
    s = read_session(shove)
    whole = TimeseriesChain(with_hand=True).compute(s.t, s.q, s.dq, s.tau)
    chain = ChunkedChain(with_hand=True)
    parts = [chain.compute(s.t[i:i + size], s.q[i:i + size], s.dq[i:i + size],
                           s.tau[i:i + size]) for i in range(0, s.n_samples, size)]
    for name in ALL_TIMESERIES:
        chunked = np.concatenate([part[name] for part in parts])
        assert chunked.shape == whole[name].shape
        assert np.abs(chunked - whole[name]).max() <= 1e-9, name


def test_an_empty_chunk_changes_nothing(shove) -> None:
    s = read_session(shove)
    chain = ChunkedChain(with_hand=True, names=["r"])
    first = chain.compute(s.t[:10], s.q[:10], s.dq[:10], s.tau[:10])["r"]
    assert chain.compute(s.t[:0], s.q[:0], s.dq[:0], s.tau[:0])["r"].shape == (0, 7)
    rest = chain.compute(s.t[10:], s.q[10:], s.dq[10:], s.tau[10:])["r"]
    whole = TimeseriesChain(with_hand=True).compute(s.t, s.q, s.dq, s.tau, ["r"])["r"]
    assert np.abs(np.vstack([first, rest]) - whole).max() <= 1e-9


def test_chain_cache_written_in_row_groups_equals_the_chain(shove, tmp_path,
                                                            monkeypatch) -> None:
    monkeypatch.setenv("CONTACTKIT_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(chain_cache, "BATCH_ROWS", 333)
    s = read_session(shove)
    cached = chain_cache.chain_series(s, ChainConfig(), ["tau", "r", "f"])
    whole = TimeseriesChain(with_hand=True).compute(s.t, s.q, s.dq, s.tau, ["tau", "r", "f"])
    for name, values in whole.items():
        assert np.abs(cached[name] - values).max() <= 1e-9, name
    (stored,) = (tmp_path / "cache" / "chain").glob("*/r.parquet")
    assert pq.ParquetFile(stored).metadata.num_row_groups == -(-s.n_samples // 333)


def test_per_sample_table_streams_and_equals_the_chain(shove, tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(chain_cache, "BATCH_ROWS", 500)
    out = tmp_path / "samples.parquet"
    assert write_per_sample_table([shove], out) == (1, [])
    table = pq.read_table(out)
    s = read_session(shove)
    expected = timeseries_columns(s)
    assert table.column_names == ["session_id", *expected]
    assert pq.ParquetFile(out).metadata.num_row_groups == -(-s.n_samples // 500)
    for name, values in expected.items():
        assert np.abs(table.column(name).to_numpy() - values).max() <= 1e-9, name
