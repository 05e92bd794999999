"""CAN source: live round trip on python-can's virtual bus, log import, faults, kill."""

from __future__ import annotations

import sys
import threading
import time
import uuid
from pathlib import Path

import can
import numpy as np
import pytest

from contactkit.features.timing import sampling_stats
from contactkit.recorder.capture.journal import recover_directory
from contactkit.recorder.capture.record import capture
from contactkit.recorder.importers.can_codec import (
    SampleAssembler,
    rows_to_columns,
    session_frames,
    session_values,
)
from contactkit.recorder.importers.can_map import load_map
from contactkit.recorder.importers.can_tools import CanLogImporter, bridge_session
from contactkit.recorder.metadata import session_meta
from contactkit.recorder.sources.can import BusConfig, CanSource
from contactkit.schemas import InputError, read_session, validate_session
from tests.conftest import kill_when_journal_holds, make_session, run_cli

FMAP = load_map()
Q_STEP = 1 / 166886.0


@pytest.fixture(scope="module")
def source_session(tmp_path_factory) -> Path:
    return make_session(tmp_path_factory.mktemp("src"), seed=12, action="shove", link=6,
                        duration_s=2.0, planned_at_s=1.0, rate_hz=250.0)


def _meta():
    return session_meta(source="can", action="shove", pose="C", link=6, planned_at_s=1.0,
                        operator="test")


def _assert_quantised_equal(got, want) -> None:
    assert got.n_samples == want.n_samples
    assert np.abs(got.q - want.q).max() <= Q_STEP / 2 + 1e-12
    assert np.abs(got.dq - want.dq).max() <= Q_STEP / 2 + 1e-12
    rated = np.array([87.0] * 4 + [12.0] * 3)
    assert (np.abs(got.tau - want.tau) <= rated / 2000 + 1e-12).all()


def test_default_map() -> None:
    assert FMAP.sync_id == 0x080 and not FMAP.fd
    assert sorted(FMAP.frames) == [0x181 + i for i in range(7)] + [0x281 + i for i in range(7)]
    tau_signal = FMAP.frames[0x285].signals[0]
    assert tau_signal.quantity == "tau" and tau_signal.joint == 5
    assert tau_signal.scale == pytest.approx(0.012)


def test_live_round_trip_on_virtual_bus(source_session: Path, tmp_path: Path) -> None:
    channel = f"rt-{uuid.uuid4().hex[:8]}"
    # a loaded machine stalls the bridge for tenths of a second: the capture waits 2 s of
    # silence before it ends, and bus times are compared to 0.5 s (transport, not timing)
    source = CanSource(BusConfig("virtual", channel), FMAP, duration_s=60.0, timeout_s=2.0)
    out = tmp_path / "live.parquet"
    result = {}
    worker = threading.Thread(target=lambda: result.update(
        capture=capture(source, _meta(), out)))
    worker.start()
    time.sleep(0.5)
    recorded = read_session(source_session)
    bridge_session(recorded, FMAP, bus=BusConfig("virtual", channel), rate=1.0)
    worker.join(timeout=30)
    live = validate_session(out)
    _assert_quantised_equal(live, recorded)
    assert np.abs(live.t - recorded.t).max() < 0.5
    info = live.meta.source_info
    assert info["samples"] == recorded.n_samples and info["incomplete_samples"] == 0
    assert "bus silent" in info["end"]
    for suffix in (".asc", ".blf"):
        log = tmp_path / f"bridge{suffix}"
        bridge_session(recorded, FMAP, log=log)
        imported = run_cli("recorder", "import-can", str(log), "--pose", "C", "--action",
                           "shove", "--planned-at", "1", "--out", str(tmp_path / suffix[1:]))
        assert imported.returncode == 0, imported.stderr
        from_log = read_session(imported.stdout.strip())
        for name in [c for c in live.table.column_names if c != "t"]:
            assert np.array_equal(from_log.column(name), live.column(name)), (suffix, name)


def test_every_log_format_python_can_writes(source_session: Path, tmp_path: Path) -> None:
    recorded = read_session(source_session)
    for suffix in (".trc", ".csv", ".log", ".db"):
        log = tmp_path / f"x{suffix}"
        bridge_session(recorded, FMAP, log=log)
        with CanLogImporter.read(log, FMAP) as imported:
            assert sum(len(t) for t in imported.times()) == recorded.n_samples, suffix
            assert imported.source_info()["incomplete_samples"] == 0


def test_faults_are_counted_not_raised(source_session: Path, tmp_path: Path) -> None:
    recorded = read_session(source_session)
    frames = list(session_frames(FMAP, recorded.t, session_values(recorded.q, recorded.dq,
                                                                  recorded.tau)))
    per_sample = len(FMAP.frames) + 1
    out = []
    for i, msg in enumerate(frames):
        k, slot = divmod(i, per_sample)
        shifted = msg.timestamp + (2.0 if k > 60 else 0.0)
        msg = can.Message(timestamp=shifted, arbitration_id=msg.arbitration_id,
                          data=msg.data, is_extended_id=False)
        if k == 10 and msg.arbitration_id == 0x283:
            continue
        if k == 40 and msg.arbitration_id == 0x182:
            msg = can.Message(timestamp=shifted, arbitration_id=0x182, data=msg.data[:4],
                              is_extended_id=False)
        if k == 80 and msg.arbitration_id == FMAP.sync_id:
            continue
        out.append(msg)
        if k == 20 and msg.arbitration_id == 0x181:
            out.append(msg)
        if k == 30 and slot == 0:
            out.append(can.Message(timestamp=shifted, arbitration_id=0x555, data=b"\x01",
                                   is_extended_id=False))
            out.append(can.Message(timestamp=shifted, is_error_frame=True,
                                   arbitration_id=0, is_extended_id=False))
    log = tmp_path / "faults.asc"
    with can.Logger(log) as writer:
        for msg in out:
            writer.on_message_received(msg)
    result = run_cli("recorder", "import-can", str(log), "--pose", "C", "--action", "shove",
                     "--out", str(tmp_path / "o"))
    assert result.returncode == 0, result.stderr
    session = validate_session(result.stdout.strip())
    stats = session.meta.source_info
    assert stats["samples"] == recorded.n_samples - 1
    assert stats["incomplete_samples"] == 2
    assert stats["duplicates"] == 1 + len(FMAP.frames)
    assert stats["unknown_ids"] == 1 and stats["bad_lengths"] == 1 and stats["bus_errors"] == 1
    assert stats["lost_syncs"] == 1
    assert np.isnan(session.column("tau_3")[10]) and np.isnan(session.column("q_2")[40])
    assert sampling_stats(session.t).gaps == 1
    assert session.complete().n_samples == session.n_samples - 2


def test_silent_bus_ends_capture_and_keeps_data(tmp_path: Path) -> None:
    channel = f"quiet-{uuid.uuid4().hex[:8]}"
    source = CanSource(BusConfig("virtual", channel), FMAP, duration_s=60.0, timeout_s=0.3,
                       first_frame_timeout_s=0.3)
    with pytest.raises(InputError, match="no samples were recorded"):
        capture(source, _meta(), tmp_path / "empty.parquet")
    assert "bus silent" in source.end_reason
    assert list(tmp_path.iterdir()) == []


def test_can_capture_killed_midway_recovers(source_session: Path, tmp_path: Path) -> None:
    helper = (
        "import pathlib, sys, threading, time\n"
        "from contactkit.recorder.importers.can_map import load_map\n"
        "from contactkit.recorder.importers.can_tools import bridge_session\n"
        "from contactkit.cli.recorder import main\n"
        "from contactkit.recorder.sources.can import BusConfig\n"
        "from contactkit.schemas import read_session\n"
        f"s = read_session({str(source_session)!r})\n"
        "def feed():\n"
        f"    while not list(pathlib.Path({str(tmp_path)!r}).glob('*.journal')):\n"
        "        time.sleep(0.05)\n"
        "    time.sleep(0.3)\n"
        "    for _ in range(5):\n"
        "        bridge_session(s, load_map(), bus=BusConfig('virtual', 'kill'), rate=1.0)\n"
        "threading.Thread(target=feed, daemon=True).start()\n"
        "sys.argv = ['recorder', 'capture', '--source', 'can', '--interface', 'virtual',\n"
        "            '--channel', 'kill', '--pose', 'C', '--action', 'bump', '--duration',\n"
        f"            '30', '--timeout', '3', '--out', {str(tmp_path)!r}]\n"
        "main()\n")
    _, held = kill_when_journal_holds([sys.executable, "-c", helper], tmp_path, 200)
    (recovery,) = recover_directory(tmp_path)
    session = validate_session(recovery.session)
    assert session.meta.recovered and session.meta.source == "can"
    assert session.n_samples >= held >= 200  # every sample flushed before the kill
    recorded = read_session(source_session)
    n = session.n_samples
    assert np.abs(session.q - recorded.q[:n]).max() <= Q_STEP / 2 + 1e-12


def test_assembler_uses_late_frames_to_fill_the_previous_sample() -> None:
    values = np.arange(21, dtype=float) * 0.01
    first = [m for m in session_frames(FMAP, np.array([0.0, 0.004]), np.vstack([values] * 2))]
    late = next(m for m in first[:15] if m.arbitration_id == 0x184)
    ordered = [m for m in first if m is not late]
    ordered.insert(20, late)
    assembler = SampleAssembler(FMAP)
    rows = [r for m in ordered for r in assembler.feed(m)] + assembler.finish()
    columns = rows_to_columns(rows)
    assert assembler.stats.out_of_order == 1 and assembler.stats.incomplete_samples == 0
    assert columns["q_4"][0] == pytest.approx(values[3], abs=Q_STEP)


def test_cue_frame_goes_out_at_the_planned_time(source_session: Path, tmp_path: Path) -> None:
    from contactkit.recorder.sources.can import Cue

    channel = f"cue-{uuid.uuid4().hex[:8]}"
    listener = can.Bus(interface="virtual", channel=channel)
    source = CanSource(BusConfig("virtual", channel), FMAP, duration_s=60.0, timeout_s=0.5,
                       cue=Cue(0x700, b"\x01", planned_at_s=1.0))
    worker = threading.Thread(target=lambda: capture(source, _meta(), tmp_path / "c.parquet"))
    worker.start()
    time.sleep(0.5)
    bridge_session(read_session(source_session), FMAP, bus=BusConfig("virtual", channel),
                   rate=1.0)
    worker.join(timeout=30)
    seen = []
    while (msg := listener.recv(timeout=0.1)) is not None:
        seen.append(msg)
    listener.shutdown()
    cues = [m for m in seen if m.arbitration_id == 0x700]
    assert len(cues) == 1 and cues[0].data == b"\x01"
    info = validate_session(tmp_path / "c.parquet").meta.source_info
    assert info["cue_id"] == 0x700
    assert 1.0 <= info["cue_bus_time_s"] < 1.1
