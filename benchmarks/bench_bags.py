"""import-bag on a 10-minute 1 kHz ROS 2 bag (600,000 franka_msgs/FrankaRobotState
messages, as franka_ros2 records them) against rosbags reading and decoding the same
messages bare. Target: the import takes at most 1.5x the bare read.

The bag is written once with rosbags' writer (MCAP, or sqlite3 with ``--sqlite3``)
from a synthetic 1 kHz joint stream; the import writes and validates the session.

    .venv/bin/python benchmarks/bench_bags.py [minutes, default 10] [--sqlite3]

Measured on 2 cores shared with other jobs (load average 20), 1 minute (60,000
messages, 140 MB MCAP; the 10-minute bag took too long to write on that machine):
bare rosbags read + decode 111.7 s, import-bag 155.9 s, ratio 1.40x. Both run
single-threaded, so the ratio, not the absolute rate, is the figure to compare.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from bag_writers import ROS2_TOPIC, write_bag

from contactkit.recorder.importers.bags import BagImporter, default_typestore
from contactkit.recorder.importers.writer import write_importer
from contactkit.recorder.metadata import session_meta
from contactkit.schemas import joint_columns, read_session, write_session


def synthetic_session(path: Path, minutes: float) -> Path:
    """Write a session of ``minutes`` at 1 kHz with smooth joint motion; return its path."""
    t = np.arange(int(minutes * 60_000)) * 1e-3
    columns = {"t": t}
    for prefix, scale in (("q", 0.5), ("dq", 0.1), ("tau", 10.0), ("q_d", 0.5), ("dq_d", 0.1),
                          ("tau_ext_hat", 1.0)):
        for j, name in enumerate(joint_columns(prefix)):
            columns[name] = scale * np.sin(0.3 * t + j)
    write_session(path, columns, _meta())
    return path


def _meta():
    return session_meta(source="ros-bag", action="none", condition="static", pose="A",
                         target_pose=None, speed_rad_s=None, link=None, planned_at_s=None,
                         operator="bench", with_hand=True)


def bare_read(bag: Path) -> int:
    """Read and decode every message on the state topic with rosbags alone; return count."""
    from rosbags.highlevel import AnyReader

    n = 0
    with AnyReader([bag], default_typestore=default_typestore(False)) as reader:
        connections = [c for c in reader.connections if c.topic == ROS2_TOPIC]
        for connection, _, raw in reader.messages(connections=connections):
            reader.deserialize(raw, connection.msgtype)
            n += 1
    return n


def main(minutes: float, kind: str) -> None:
    """Write the bag, then time the bare read and the import; print the figures."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        session = read_session(synthetic_session(tmp_path / "source.parquet", minutes))
        start = time.perf_counter()
        bag = write_bag(session, tmp_path / "bag", kind)
        written = time.perf_counter() - start
        size = sum(f.stat().st_size for f in bag.iterdir())
        start = time.perf_counter()
        n = bare_read(bag)
        bare = time.perf_counter() - start
        out = tmp_path / "out"
        out.mkdir()
        start = time.perf_counter()
        with BagImporter.read(bag) as opened:
            imported = read_session(write_importer(opened, _meta(), out))
        ours = time.perf_counter() - start
        assert imported.n_samples == n == session.n_samples
        assert np.array_equal(imported.q, session.q)
    print(f"{kind} bag, {n} FrankaRobotState messages ({minutes:g} min at 1 kHz), "
          f"{size / 1e6:.0f} MB, written in {written:.0f} s")
    print(f"rosbags bare read + decode: {bare:.1f} s ({n / bare:,.0f} msg/s)")
    print(f"import-bag (read, decode, columns, session write + validation): {ours:.1f} s "
          f"({n / ours:,.0f} msg/s)")
    print(f"ratio {ours / bare:.2f}x (target <= 1.5x)")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(float(args[0]) if args else 10.0, "sqlite3" if "--sqlite3" in sys.argv else "mcap")
