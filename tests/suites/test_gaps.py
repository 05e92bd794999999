"""Gaps in a session: after a step over RESTART_STEP_S the observer and the detector
restart as at the start, no event spans the gap, and batch, chunked and per-sample
runs agree; replay goes through such a session (issue 25)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from contactkit.classify.events.contact_events import EventPipeline, batch_events, stream_events
from contactkit.classify.modelfile.model_file import load_model
from contactkit.features.detector import Detector, DetectorConfig, detect
from contactkit.features.timeseries import TimeseriesChain
from contactkit.features.timing import RESTART_STEP_S, restarts, sampling_stats
from contactkit.replay.engine import ReplayStream
from contactkit.replay.session_replay import replay_sessions
from contactkit.schemas import read_session
from contactkit.schemas.session import SampleBatch
from tests.conftest import MINDLAB_FILES, load_mindlab, make_session, save_quick_model

DETECTOR = DetectorConfig(noise=(0.5,) * 7, speed=(0.5,) * 7, accel=(0.02,) * 7)
HOLE = (1.85, 3.85)  # s cut out, while the shove (detected 1.75-2.01 s) is on
SHIFT_AFTER, SHIFT_S = 4.5, 9.0  # s: a 9 s gap, within the 10 s time rule


@pytest.fixture(scope="module")
def gapped(tmp_path_factory) -> Path:
    """A 6 s simulated shove at 500 Hz with a 2 s hole cut out during the contact and a
    9 s gap later."""
    directory = tmp_path_factory.mktemp("gaps")
    path = make_session(directory, action="shove", link=4, duration_s=6.0, planned_at_s=1.5)
    table = pq.read_table(path)
    t = table.column("t").to_numpy()
    table = table.filter(pa.array((t < HOLE[0]) | (t >= HOLE[1])))
    t = table.column("t").to_numpy().copy()
    t[t > SHIFT_AFTER] += SHIFT_S
    out = directory / "gapped.parquet"
    pq.write_table(table.set_column(table.column_names.index("t"), "t", pa.array(t)), out)
    return out


@pytest.fixture(scope="module")
def data(gapped) -> dict[str, np.ndarray]:
    session = read_session(gapped)
    t, q, dq, tau = session.t, session.q, session.dq, session.tau
    chain = TimeseriesChain(names=["r", "ddq"])
    return {"t": t, "q": q, "dq": dq, "tau": tau, **chain.compute(t, q, dq, tau)}


def test_the_gap_rule_passes_every_real_step_and_finds_the_gaps(data) -> None:
    gaps = restarts(data["t"])
    assert len(gaps) == 2
    assert np.diff(data["t"])[gaps - 1] == pytest.approx([2.0, SHIFT_S + 0.002], abs=3e-3)
    assert sampling_stats(data["t"]).restarts == 2


def test_the_observer_restarts_at_zero_after_a_gap(data) -> None:
    for k in restarts(data["t"]):
        assert not data["r"][k].any() and not data["ddq"][k].any()
        assert np.abs(data["r"][k - 1]).max() > 0
    plain = TimeseriesChain(names=["r"])
    k = int(restarts(data["t"])[1])
    alone = plain.compute(*(data[c][k:] for c in ("t", "q", "dq", "tau")))["r"]
    assert np.abs(alone - data["r"][k:]).max() < 1e-9  # as if the session started there


@pytest.mark.parametrize("size", [1, 7, 450, 1000, 4096])
def test_chunked_and_per_sample_chain_equal_the_batch_across_gaps(data, size) -> None:
    chain = TimeseriesChain(names=["r", "ddq"])
    t, q, dq, tau = (data[c] for c in ("t", "q", "dq", "tau"))
    parts = [chain.feed(SampleBatch(t[i:i + size], q[i:i + size], dq[i:i + size],
                                    tau[i:i + size])) for i in range(0, len(t), size)]
    for name in ("r", "ddq"):
        assert np.abs(np.concatenate([p[name] for p in parts]) - data[name]).max() < 1e-9


def test_per_sample_update_equals_the_batch_across_gaps(data) -> None:
    chain = TimeseriesChain(names=["r"])
    r = np.array([chain.update(*(data[c][k] for c in ("t", "q", "dq", "tau")))["r"]
                  for k in range(len(data["t"]))])
    assert np.abs(r - data["r"]).max() < 1e-9


def test_the_detector_restarts_and_no_contact_spans_a_gap(data) -> None:
    t = data["t"]
    found = detect(t, data["r"], data["dq"], DETECTOR)
    gaps = restarts(t)
    assert found.restarts == gaps.tolist()
    cut = [(a, b) for a, b in found.intervals if b is not None and b + 1 in gaps]
    assert cut, "the shove is on when the hole starts"
    for onset, release in found.intervals:
        end = len(t) if release is None else release
        assert not ((gaps > onset) & (gaps <= end)).any()
    for k in gaps:  # warm-up again: no contact, baseline follows r
        settle = t[k:] < t[k] + DETECTOR.warmup_s
        assert not found.contact[k:][settle].any()
    detector = Detector(DETECTOR)
    streamed = [detector.update(float(t[k]), data["r"][k], data["dq"][k]).contact
                for k in range(len(t))]
    assert np.array_equal(streamed, found.contact)


def test_events_end_before_a_gap_the_same_in_batch_and_streaming(data) -> None:
    t = data["t"]
    gap_t = t[restarts(t)]
    found = detect(t, data["r"], data["dq"], DETECTOR)
    batch = batch_events(t, data["r"], found)
    arrays, labels = stream_events(t, data["r"], data["dq"], DETECTOR)
    chain, pipeline = TimeseriesChain(names=["r"]), EventPipeline(DETECTOR)
    live = []
    for k in range(len(t)):
        r = chain.update(*(data[c][k] for c in ("t", "q", "dq", "tau")))["r"]
        live.append(pipeline.update(float(t[k]), r, data["dq"][k]).label)
    assert labels == live
    events = pipeline.finish()
    for a, b, c in zip(batch, arrays, events, strict=True):
        assert (a.onset_s, a.decision_s, a.release_s, a.label) == \
               (b.onset_s, b.decision_s, b.release_s, b.label) == \
               (c.onset_s, c.decision_s, c.release_s, c.label)
        assert np.allclose(a.features, c.features, atol=1e-9)
    assert len(events) == len(batch) >= 1
    first = events[0]
    assert first.release_s == first.decision_s == t[t < HOLE[0]][-1]  # cut, decided there
    for event in events:
        end = np.inf if event.release_s is None else event.release_s
        assert not ((gap_t > event.onset_s) & (gap_t <= end)).any()


@pytest.fixture(scope="module")
def quick_model(tmp_path_factory) -> Path:
    """An SVM on random rows of the default features: fast to build, predicts anything."""
    return save_quick_model(tmp_path_factory.mktemp("model") / "m.skops")


@pytest.mark.timeout(300)
def test_replay_goes_through_the_gaps(gapped, data, quick_model, tmp_path) -> None:
    model = load_model(quick_model)
    stream = ReplayStream(gapped, model, detector=DETECTOR, batch_rows=700).run()
    t = data["t"]
    gap_t = t[restarts(t)]
    assert stream.n_samples == len(t)
    pred_t = np.array(stream.pred_t)
    for g in gap_t:  # the hops start again one window after the gap
        assert not ((pred_t >= g) & (pred_t < g + stream.window_s - 1e-9)).any()
        assert (pred_t >= g + stream.window_s - 1e-9).any()
    for event in stream.events:
        end = np.inf if event.release_s is None else event.release_s
        assert not ((gap_t > event.onset_s) & (gap_t <= end)).any()
        assert event.release_s is None or t[stream.event_samples[event.release_s]] \
            == event.release_s
    _, problems = replay_sessions([gapped], model, save=tmp_path / "g.rrd")
    assert not problems and (tmp_path / "g.rrd").exists()


def test_no_step_of_the_real_recordings_restarts_the_chain(reference_dir, mindlab_dir,
                                                           fr3_dir) -> None:
    times = [np.loadtxt(reference_dir / "time.txt").ravel()]
    times += [load_mindlab(mindlab_dir / f"{name}.csv")["t"] for name in MINDLAB_FILES]
    times += [np.loadtxt(path, delimiter=",", skiprows=1, usecols=0) * 1e-9
              for path in sorted(fr3_dir.glob("*.csv"))]
    assert len(times) == 8
    for t in times:
        assert restarts(t).size == 0 and np.diff(t).max() < RESTART_STEP_S / 2
