"""A replay's isolated contacts: logged block by block as the session streams, nothing
kept per estimate beyond a batch, and the recording's contact track the one the
events' whole tracks give (several events, one cut by a gap, one open at the end)."""

from __future__ import annotations

import gc
import json
from collections import defaultdict
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import rerun.chunk as rc

from contactkit.classify.events.contact_events import EventPipeline
from contactkit.classify.modelfile.model_file import load_model
from contactkit.errors import InputError
from contactkit.features.detector import DetectorConfig
from contactkit.features.isolation import ContactEstimate
from contactkit.replay import engine
from contactkit.replay.engine import ReplayStream
from contactkit.replay.session_replay import replay_session
from contactkit.viewer import layout
from tests.conftest import make_session, save_quick_model

DETECTOR = DetectorConfig(noise=(0.03,) * 7, speed=(0.5,) * 7, accel=(0.02,) * 7,
                          min_off_s=0.2)
"""Sensitive and holding a contact through dips of 0.2 s: three long contacts here."""
HOLE = (1.85, 3.85)  # s cut out while the shove is on: its event is cut by the gap
END_S = 5.0  # s: the session ends here, in a contact
BATCH = 200  # samples per batch in these replays (0.4 s at 500 Hz)


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return load_model(save_quick_model(tmp_path_factory.mktemp("model") / "m.skops"))


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """A simulated shove at 500 Hz with a 2 s hole during the contact, ending in a
    contact."""
    directory = tmp_path_factory.mktemp("contacts")
    path = make_session(directory, action="shove", link=4, duration_s=6.0, planned_at_s=1.5)
    table = pq.read_table(path)
    t = table.column("t").to_numpy()
    out = directory / "cut.parquet"
    pq.write_table(table.filter(pa.array(((t < HOLE[0]) | (t >= HOLE[1])) & (t < END_S))), out)
    return out


def _stream(session: Path, model, keep_track: bool = False) -> ReplayStream:
    stream = ReplayStream(session, model, detector=DETECTOR, batch_rows=BATCH)
    if keep_track:  # the library's default pipeline, on the same samples
        old = stream.pipeline
        stream.pipeline = EventPipeline(stream.detector, old.model, old.decide_after_s,
                                        old.isolator)
    return stream


def test_the_pipeline_refuses_a_keep_track_that_is_not_a_bool() -> None:
    with pytest.raises(InputError, match="keep_track"):
        EventPipeline(keep_track="no")


def test_a_replay_keeps_no_estimate_beyond_a_batch(session, model) -> None:
    gc.collect()
    before = sum(type(o) is ContactEstimate for o in gc.get_objects())
    stream = _stream(session, model)
    per_block = [len(block.estimates) for block in stream.blocks()]
    events = stream.events
    gc.collect()
    held = sum(type(o) is ContactEstimate for o in gc.get_objects()) - before
    assert sum(per_block) > 3 * max(per_block)  # the contacts span many batches
    assert max(per_block) <= BATCH // 10 + 1  # 50 Hz at 500 Hz: one every 10 samples
    assert all(not event.contact_track for event in events)
    # what is left: each event's estimates at the decision and at the peak, and the
    # open event's last track estimate
    assert held <= 2 * len(events) + 1


def test_the_blocks_carry_the_whole_tracks_of_the_events(session, model) -> None:
    streamed = _stream(session, model)
    got = [(k, e) for block in streamed.blocks() for k, e in block.estimates]
    kept = _stream(session, model, keep_track=True).run()
    expected = [e for event in kept.events for e in event.contact_track]
    assert [e.to_dict() for _, e in got] == [e.to_dict() for e in expected]
    t = np.concatenate([b.t for b in _stream(session, model).blocks()])
    assert [t[k] for k, _ in got] == [e.t_s for e in expected]
    assert [e.to_dict() for e in streamed.events] == [e.to_dict() for e in kept.events]


def _rows(path: Path) -> dict[str, list[dict]]:
    """Return contact entity (point, force, link highlights) -> its rows (``time`` [ns],
    ``sample`` and the components), sorted."""
    out = defaultdict(list)
    for chunk in rc.RrdReader(path).stream():
        entity = chunk.entity_path.lstrip("/")
        if chunk.is_static or not (entity in (layout.CONTACT_POINT, layout.CONTACT_FORCE)
                                   or entity.startswith(layout.CONTACT_LINK)):
            continue
        batch = chunk.to_record_batch()
        columns = {n: batch.column(n).cast("int64").to_pylist() if n == "time"
                   else batch.column(n).to_pylist()
                   for n in batch.schema.names if n == "time" or n == "sample" or ":" in n}
        out[entity] += [{n: v[i] for n, v in columns.items()} for i in range(batch.num_rows)]
    return {k: sorted(v, key=lambda row: json.dumps(row, sort_keys=True))
            for k, v in out.items()}


def _whole_track(session: Path, model) -> tuple[list[tuple[int, np.ndarray | None]],
                                                 np.ndarray, list]:
    """Return the contact track's rows as the events' whole tracks (the library's
    default pipeline) give them: (sample, point [m] or None) of each estimate, and a
    clearing row at each release (at the last sample for an event open at the end)
    when the event's last estimate came before it; the session's times [s] and its
    events."""
    kept = _stream(session, model, keep_track=True)
    t = np.concatenate([block.t for block in kept.blocks()])
    rows = []
    for event in kept.events:
        rows += [(int(np.searchsorted(t, e.t_s)), e.point_base) for e in event.contact_track]
        end = len(t) - 1 if event.release_s is None else kept.event_samples[event.release_s]
        if rows and rows[-1][0] < end:
            rows.append((end, None))
    return rows, t, kept.events


def test_the_recorded_track_is_the_one_of_the_whole_tracks(session, model, tmp_path,
                                                          monkeypatch) -> None:
    expected, t, events = _whole_track(session, model)
    assert len(events) >= 3 and events[-1].release_s is None
    assert any(e.release_s == t[t < HOLE[0]][-1] for e in events)  # cut by the hole
    monkeypatch.setattr(engine, "BATCH_ROWS", BATCH)
    saved = {}
    for name, rate in (("max", None), ("paced", 1000.0)):
        saved[name] = tmp_path / f"{name}.rrd"
        replay_session(session, model, save=saved[name], rate=rate, detector=DETECTOR)
    got = _rows(saved["max"])
    assert got == _rows(saved["paced"])
    assert any(entity.startswith(layout.CONTACT_LINK) for entity in got)
    for entity in (layout.CONTACT_POINT, layout.CONTACT_FORCE):
        rows = sorted(got[entity], key=lambda row: row["sample"])
        assert [row["sample"] for row in rows] == [k for k, _ in expected], entity
        assert np.allclose([row["time"] / 1e9 for row in rows], t[[k for k, _ in expected]],
                           atol=1e-9, rtol=0)
        for row, (_, point) in zip(rows, expected, strict=True):
            values = row["Points3D:positions" if entity == layout.CONTACT_POINT
                         else "Arrows3D:origins"]
            assert not values if point is None else np.allclose(values, [point], atol=1e-6)
