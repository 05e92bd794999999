"""Long sessions streamed in chunks: the chunked chain equals the whole-session chain,
replay and features read a session row group by row group."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import rerun.chunk as rc

from contactkit.classify.modelfile.model_file import load_model
from contactkit.features import chain_cache
from contactkit.features.extract import timeseries_columns
from contactkit.features.names import KNOWN
from contactkit.features.per_sample import write_per_sample_table
from contactkit.features.timeseries import ChainConfig, TimeseriesChain
from contactkit.replay import engine
from contactkit.replay.session_replay import replay_session
from contactkit.schemas import SessionMeta, read_session, write_session
from contactkit.schemas.columns import REQUIRED_COLUMNS
from contactkit.schemas.session import SampleBatch, iter_sample_batches
from contactkit.viewer import layout
from tests.conftest import make_session, run_command, save_quick_model
from tests.rrd_frames import assert_frames_ok


@pytest.fixture(scope="module")
def shove(tmp_path_factory) -> Path:
    return make_session(tmp_path_factory.mktemp("shove"), seed=5, action="shove", link=6,
                        duration_s=4.0, planned_at_s=2.0, rate_hz=500.0)


@pytest.mark.parametrize("size", [1, 7, 333, 1000, 1999, 5000])
def test_chunked_chain_equals_the_whole_session_chain(shove, size) -> None:
    s = read_session(shove)
    whole = TimeseriesChain(names=KNOWN).compute(s.t, s.q, s.dq, s.tau)
    chain = TimeseriesChain(names=KNOWN)
    batch = SampleBatch(s.t, s.q, s.dq, s.tau)
    parts = [chain.feed(batch.take(slice(i, i + size))) for i in range(0, s.n_samples, size)]
    for name in KNOWN:  # the thesis's features and the detector's tau_dyn
        chunked = np.concatenate([part[name] for part in parts])
        assert chunked.shape == whole[name].shape
        assert np.abs(chunked - whole[name]).max() <= 1e-9, name


def test_sample_batches_stack_the_session_columns(shove) -> None:
    s = read_session(shove)
    (batch,) = list(iter_sample_batches(s, s.n_samples))
    assert np.array_equal(batch.q, s.q) and np.array_equal(batch.tau, s.tau)
    assert batch.f_ext.shape == (s.n_samples, 3) and batch.contact.dtype == bool
    assert batch.tau_ext_hat is None
    columns = {name: s.column(name).copy() for name in s.table.column_names}
    columns["q_3"][5] = np.nan
    gappy = SampleBatch.from_columns(columns).complete()
    assert len(gappy) == s.n_samples - 1 and gappy.t[5] == s.t[6]
    assert np.array_equal(gappy.f_ext[5], batch.f_ext[6])


def test_an_empty_chunk_changes_nothing(shove) -> None:
    s = read_session(shove)
    chain = TimeseriesChain(names=["r"])
    batch = SampleBatch(s.t, s.q, s.dq, s.tau)
    first = chain.feed(batch.take(slice(10)))["r"]
    assert chain.feed(batch.take(slice(0)))["r"].shape == (0, 7)
    rest = chain.feed(batch.take(slice(10, None)))["r"]
    whole = TimeseriesChain().compute(s.t, s.q, s.dq, s.tau, ["r"])["r"]
    assert np.abs(np.vstack([first, rest]) - whole).max() <= 1e-9


def test_chain_cache_written_in_row_groups_equals_the_chain(shove, tmp_path,
                                                            monkeypatch) -> None:
    monkeypatch.setenv("CONTACTKIT_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(chain_cache, "BATCH_ROWS", 333)
    s = read_session(shove)
    cached = chain_cache.chain_series(s, ChainConfig(), ["tau", "r", "f"])
    whole = TimeseriesChain().compute(s.t, s.q, s.dq, s.tau, ["tau", "r", "f"])
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


@pytest.fixture(scope="module")
def quick_model(tmp_path_factory) -> Path:
    """An SVM on random rows of the default features: fast to build, predicts anything."""
    return save_quick_model(tmp_path_factory.mktemp("model") / "m.skops")


def _long_session(directory: Path, n: int, rate_hz: float = 1000.0) -> Path:
    """A synthetic session of ``n`` samples: smooth joints, noisy torques."""
    rng = np.random.default_rng(n)
    t = np.arange(n) / rate_hz
    columns = {"t": t}
    for i, name in enumerate(REQUIRED_COLUMNS[1:]):
        columns[name] = 0.3 * np.sin(0.5 * t + i) + 0.001 * rng.standard_normal(n)
    meta = SessionMeta(session_id=f"long{n}", source="sim", action="none",
                       nominal_rate_hz=rate_hz)
    return write_session(directory / f"long_{n}.parquet", columns, meta)


def _peak_above_imports(case: str, session: Path, model: Path, out: Path, rows: int) -> float:
    script = Path(__file__).parents[1] / "streaming_rss.py"
    result = subprocess.run([sys.executable, str(script), case, str(session), str(model),
                             str(out), str(rows)], capture_output=True, text=True,
                            timeout=600, check=False)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.splitlines()[-1])["above_mb"]


FLAT_MARGIN_MB = 25.0
"""Peak RSS of a 4x longer session may exceed the short one's by this much. Holding the
session would add about 2 kB per sample to a replay (over 60 MB for the 30,000 more
samples of the long case), and 0.6 kB per sample to the per-sample table."""


@pytest.mark.parametrize("case", ["replay", "features"])
@pytest.mark.parametrize("samples", [
    10_000, pytest.param(60_000, marks=pytest.mark.slow)])
def test_peak_memory_is_flat_in_session_length(tmp_path, quick_model, case, samples) -> None:
    rows = samples // 10
    peaks = [_peak_above_imports(case, _long_session(tmp_path, n), quick_model,
                                 tmp_path / f"out_{n}.{'rrd' if case == 'replay' else 'pq'}",
                                 rows)
             for n in (samples, 4 * samples)]
    assert peaks[1] - peaks[0] <= FLAT_MARGIN_MB, peaks


def _rows(rrd: Path) -> dict[str, int]:
    counts: dict[str, int] = {}
    for chunk in rc.RrdReader(rrd).stream():
        if not chunk.is_static:
            path = chunk.entity_path.lstrip("/")
            counts[path] = counts.get(path, 0) + chunk.to_record_batch().num_rows
    return counts


def _sparse_rows(force: np.ndarray) -> int:
    """Return how many rows of the applied force (N, 3) a replay logs: the non-zero
    rows, the zero rows beside them, the first and the last (replay.recording.ZeroRuns)."""
    nonzero = np.any(force != 0, axis=1)
    keep = nonzero.copy()
    keep[1:] |= nonzero[:-1]
    keep[:-1] |= nonzero[1:]
    keep[[0, -1]] = True
    return int(keep.sum())


def test_log_rate_thins_what_goes_to_rerun(tmp_path, shove, quick_model) -> None:
    session = read_session(shove)
    t = session.t  # 500 Hz: the robot is drawn every 8th sample (about 60 Hz)
    force = np.column_stack([session.table.column(f"f_ext_{a}").to_numpy() for a in "xyz"])
    rows = {}
    for log_rate in (None, 100.0):
        out = tmp_path / f"thin_{log_rate}.rrd"
        replay_session(shove, load_model(quick_model), save=out, log_rate_hz=log_rate)
        rows[log_rate] = _rows(out)
    out = tmp_path / "thin_cli.rrd"
    result = run_command("replay", str(shove), "--viewer", "none", "--save", str(out),
                         "--model", str(quick_model), "--log-rate", "20")
    assert result.returncode == 0, result.stderr
    assert_frames_ok(out)
    rows[20.0] = _rows(out)
    expected = {None: (len(t), len(t[::8])), 100.0: (len(t[::5]), len(t[::8])),
                20.0: (len(t[::25]), len(np.unique(np.floor(t[::8] * 20 + 1e-6))))}
    for log_rate, (series, robot) in expected.items():
        for entity in (layout.Q, layout.TAU, layout.RESIDUAL, layout.FORCE_NORM):
            assert rows[log_rate][entity] == series, (log_rate, entity)
        step = {None: 1, 100.0: 5, 20.0: 25}[log_rate]
        assert rows[log_rate][layout.TRUE_FORCE] == _sparse_rows(force[::step])
        assert rows[log_rate][f"{layout.JOINT_TRANSFORMS}/panda_joint1"] == robot, log_rate
        # predictions are logged at every hop, thinned or not
        assert rows[log_rate][layout.PROBABILITY] == rows[None][layout.PROBABILITY] > 100
    assert rows[None][layout.TRUE_FORCE] < len(t) / 2


def test_replay_streamed_in_small_batches_logs_the_chain(tmp_path, shove, quick_model,
                                                         monkeypatch) -> None:
    monkeypatch.setattr(engine, "BATCH_ROWS", 137)
    out = tmp_path / "small.rrd"
    summary = replay_session(shove, load_model(quick_model), save=out)
    whole = replay_session(shove, load_model(quick_model), save=tmp_path / "whole.rrd")
    assert summary.pred_t == whole.pred_t and summary.pred_label == whole.pred_label
    assert summary.offline.label == whole.offline.label
    s = read_session(shove)
    expected = TimeseriesChain().compute(s.t, s.q, s.dq, s.tau, ["r"])["r"]
    logged = [b for c in rc.RrdReader(out).stream() if not c.is_static
              and c.entity_path.lstrip("/") == layout.RESIDUAL for b in [c.to_record_batch()]]
    t = np.concatenate([b.column("time").cast("int64").to_numpy() for b in logged]) / 1e9
    values = np.concatenate([np.array(b.column("Scalars:scalars").to_pylist()) for b in logged])
    order = np.argsort(t, kind="stable")
    assert np.abs(values[order] - expected).max() <= 1e-9


def test_per_hop_predictions_grow_as_views_later_hops_leave_alone(shove, quick_model) -> None:
    """A paced replay reads the predictions while it streams: each read is a read-only
    view of the hops so far, a prefix of the final columns, and later hops leave it as
    it was."""
    stream = engine.ReplayStream(shove, load_model(quick_model), batch_rows=137)
    seen = []
    for block in stream.blocks(every_hop=True):
        seen.append((stream.pred_t, stream.pred_proba, len(block.pred_t)))
    final_t, final_proba = stream.pred_t, stream.pred_proba
    assert len(final_t) == sum(n for _, _, n in seen) > 10
    assert len(stream.pred_label) == len(stream.pred_sample) == len(final_t)
    for t, proba, _ in seen:
        assert np.array_equal(t, final_t[:len(t)])
        assert np.array_equal(proba, final_proba[:len(proba)])
    assert not final_t.flags.writeable and not final_proba.flags.writeable
    with pytest.raises(ValueError):
        final_proba[0, 0] = 2.0
