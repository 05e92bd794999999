"""The vectorised paths replay uses (issue 26): the detector over a chunk
(:meth:`Detector.run`), the event pipeline over a chunk (:meth:`EventPipeline.update_block`)
and the hop search give what the per-sample paths give, in any chunking, gaps included."""

from __future__ import annotations

import numpy as np
import pytest

from contactkit.classify.events.contact_events import EventPipeline
from contactkit.features.detector import Detector, DetectorConfig
from contactkit.features.isolation import robot_isolator
from contactkit.features.timeseries import TimeseriesChain
from contactkit.features.timing import restarts
from contactkit.replay.engine import hop_rows, next_hop_after
from contactkit.schemas import read_session
from tests.conftest import make_session

CONFIGS = {
    "calibrated": DetectorConfig(noise=(0.5,) * 7, speed=(0.5,) * 7, accel=(0.02,) * 7),
    "default": DetectorConfig(),
    # every switch at once: many onsets and releases, no warm-up, no low-pass
    "twitchy": DetectorConfig(noise=(0.2,) * 7, speed=(0.0,) * 7, accel=(0.0,) * 7,
                              min_on_s=0.0, min_off_s=0.0, warmup_s=0.0, smooth_s=0.0),
    "no hold": DetectorConfig(noise=(0.3,) * 7, speed=(0.1,) * 7, accel=(0.0,) * 7,
                              motion_hold_s=0.0, min_off_s=0.01),
}
FLAGS = ("contact", "onset", "release")
VALUES = ("score", "e", "threshold", "baseline", "speed", "accel")


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict:
    """A 4 s simulated shove at 500 Hz, its residual, and a copy with a 2 s gap during
    the contact and a 9 s one later."""
    path = make_session(tmp_path_factory.mktemp("block"), action="shove", link=4,
                        duration_s=4.0, planned_at_s=1.5)
    session = read_session(path)
    t, q, dq, tau = session.t, session.q, session.dq, session.tau
    chain = TimeseriesChain.for_session(session.meta, names=["r"])
    gapped = t.copy()
    gapped[int(np.searchsorted(t, 1.85)):] += 2.0
    gapped[int(np.searchsorted(t, 3.0)):] += 9.0
    return {"t": t, "q": q, "dq": dq, "r": chain.compute(t, q, dq, tau)["r"],
            "gapped": gapped, "r_gapped": chain.compute(gapped, q, dq, tau)["r"],
            "isolator": robot_isolator(chain.model.setup)}


def _streams(data: dict) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(data["t"], data["r"]), (data["gapped"], data["r_gapped"])]


def _per_sample(t, r, dq, config) -> dict[str, np.ndarray]:
    detector = Detector(config)
    rows = []
    for k in range(len(t)):
        state = detector.update(float(t[k]), r[k], dq[k])
        rows.append({"contact": state.contact, "onset": state.onset, "release": state.release,
                     "score": state.score, "e": state.e, "threshold": state.threshold,
                     "baseline": detector.baseline.copy(), "speed": detector.speed,
                     "accel": detector.accel})
    return {name: np.array([row[name] for row in rows]) for name in rows[0]}


@pytest.mark.parametrize("name", list(CONFIGS))
def test_the_chunked_detector_equals_the_per_sample_one(data, name) -> None:
    config = CONFIGS[name]
    for t, r in _streams(data):
        expected = _per_sample(t, r, data["dq"], config)
        assert expected["onset"].any() or name == "default"
        for size in (1, 7, 300, len(t)):
            detector = Detector(config)
            parts = [detector.run(t[i:i + size], r[i:i + size], data["dq"][i:i + size])
                     for i in range(0, len(t), size)]
            for flag in FLAGS:
                assert np.array_equal(np.concatenate([getattr(p, flag) for p in parts]),
                                      expected[flag]), (size, flag)
            for value in VALUES:
                got = np.concatenate([getattr(p, value) for p in parts])
                assert np.abs(got - expected[value]).max() < 1e-9, (size, value)
            restarted = [i + k for i, p in zip(range(0, len(t), size), parts, strict=True)
                         for k in p.restarts]
            assert restarted == restarts(t).tolist()


def _same_events(a, b) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert (x.onset_s, x.decision_s, x.release_s, x.label) == \
               (y.onset_s, y.decision_s, y.release_s, y.label)
        assert x.peak_score == pytest.approx(y.peak_score, abs=1e-9)
        assert (x.features is None) == (y.features is None)  # released at its decision
        assert x.features is None or np.abs(x.features - y.features).max() < 1e-9
        assert [c.t_s for c in x.contact_track] == [c.t_s for c in y.contact_track]
        for u, v in ((x.contact_at_decision, y.contact_at_decision),
                     (x.contact_at_peak, y.contact_at_peak)):
            assert (u is None) == (v is None)
            assert u is None or (u.t_s, u.link) == (v.t_s, v.link)


@pytest.mark.parametrize("name", ["calibrated", "twitchy"])
def test_the_chunked_pipeline_equals_the_per_sample_one(data, name) -> None:
    config = CONFIGS[name]
    isolator = data["isolator"] if name == "calibrated" else None
    q, dq = data["q"], data["dq"]
    for t, r in _streams(data):
        pipeline = EventPipeline(config, isolator=isolator)
        labels = [pipeline.update(float(t[k]), r[k], dq[k], q[k]).label for k in range(len(t))]
        expected = pipeline.finish()
        for size in (1, 50, 925, len(t)):
            chunked = EventPipeline(config, isolator=isolator)
            got = []
            for i in range(0, len(t), size):
                got += list(chunked.update_block(t[i:i + size], r[i:i + size],
                                                 dq[i:i + size], q[i:i + size]).labels)
            assert got == labels, size
            _same_events(chunked.finish(), expected)


def test_the_hop_search_equals_the_per_sample_rule() -> None:
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(5e-4, 3e-3, 5000))
    t[1200:] += 2.0
    t[3100:] += 9.0
    t[3101:] += 0.5
    gaps = restarts(t)
    expected, next_hop = [], t[0] + 0.5
    for k in range(len(t)):
        if k in gaps:
            next_hop = t[k] + 0.5
        if t[k] >= next_hop - 1e-12:
            expected.append(k)
            next_hop = next_hop_after(next_hop, float(t[k]), 0.02)
    got, first = [], t[0] + 0.5
    for i in range(0, len(t), 700):  # batch by batch, the grid carried on
        chunk = t[i:i + 700]
        hops, first = hop_rows(chunk, restarts(chunk, t[i - 1] if i else None), first, 0.5, 0.02)
        got += [i + k for k in hops]
    assert got == expected and len(got) > 100
