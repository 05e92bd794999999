"""The per-session chain cache: same numbers, computed once per session and settings."""

from __future__ import annotations

import numpy as np

from contactkit.features import chain_cache
from contactkit.features.chain_cache import chain_series
from contactkit.features.extract import SessionFeatures
from contactkit.features.observer import ObserverConfig
from contactkit.features.timeseries import ChainConfig, TimeseriesChain
from contactkit.schemas import read_session


def test_cached_chain_equals_the_chain_and_is_computed_once(session_path, tmp_path,
                                                            monkeypatch) -> None:
    monkeypatch.setenv("CONTACTKIT_CACHE", str(tmp_path / "cache"))
    session = read_session(session_path)
    names = ["dq", "tau", "r", "f"]
    direct = TimeseriesChain.for_session(session.meta).compute(
        session.t, session.q, session.dq, session.tau, names)
    first = chain_series(session, ChainConfig(), names)
    assert len(list((tmp_path / "cache" / "chain").glob("*/r.parquet"))) == 1
    computed = []
    original = TimeseriesChain._chunk

    def counting(self, t, q, dq, tau, wanted, before):
        computed.append(list(wanted))
        return original(self, t, q, dq, tau, wanted, before)

    monkeypatch.setattr(TimeseriesChain, "_chunk", counting)
    again = chain_series(session, ChainConfig(), names)
    assert computed == [["dq", "tau"]]  # r and f came from the cache
    for name in names:
        assert np.array_equal(first[name], direct[name]) and np.array_equal(again[name],
                                                                            direct[name])
    other = chain_series(session, ChainConfig(ObserverConfig(gain=20.0)), ["r"])
    assert computed[-1] == ["r"] and not np.array_equal(other["r"], direct["r"])


def test_windows_of_different_lengths_share_one_chain(session_path, tmp_path,
                                                      monkeypatch) -> None:
    monkeypatch.setenv("CONTACTKIT_CACHE", str(tmp_path / "cache"))
    rows = {w: SessionFeatures(window="planned", window_s=w).session_row(session_path)[0]
            for w in (0.2, 0.5)}
    monkeypatch.setenv(chain_cache.CACHE_ENV, "0")
    for w, row in rows.items():
        fresh = SessionFeatures(window="planned", window_s=w).session_row(session_path)[0]
        assert np.array_equal(row, fresh)
    assert len(list((tmp_path / "cache" / "chain").glob("*/r.parquet"))) == 1
