"""Long sessions streamed in chunks: the chunked chain equals the whole-session chain,
replay and features read a session row group by row group."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contactkit.features.timeseries import ALL_TIMESERIES, ChunkedChain, TimeseriesChain
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
