"""Live capture from a simulated FR3: franky-sim (MuJoCo behind the FCI protocol) on a
loopback address, read through pylibfranka by the franka source into a session file
(journal included), server and recorder on the same cores.

Prints states recorded and lost (from the gaps in the robot's time stamps), the
robot time covered against the wall time it took (franky-sim steps MuJoCo at 1 kHz
when it can; on a loaded machine its clock runs slower than the wall clock), and the
recorder's CPU share (this process: the read loop, the journal and the session write).

    .venv/bin/python benchmarks/bench_franka.py [seconds of robot time, default 60]

Measured (2 cores shared with about 8 other jobs, load average 15): 60 s of robot
time, 59,573 states recorded, 428 lost (0.71 %) in 188 gaps, the longest 45 ms;
franky-sim's clock ran at 0.16x real time (378 s wall); recorder CPU 9.6 s, 3 % of
one core, 161 us per state.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from contactkit.recorder.capture.record import capture
from contactkit.recorder.metadata import session_meta
from contactkit.recorder.sources.franka import FrankaConfig, FrankaSource
from contactkit.schemas import validate_session

BIN = Path(sys.executable).parent


def main(seconds: float) -> None:
    """Run one capture of ``seconds`` of robot time and print its figures."""
    server = subprocess.Popen([str(BIN / "franky-sim"), "--simulator", "mujoco"],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        host = next(line.split("'")[1] for line in server.stdout if "using '" in line)
        threading.Thread(target=server.stdout.read, daemon=True).start()
        meta = session_meta(source="franka", action="none", condition="static", pose="A",
                             target_pose=None, speed_rad_s=None, link=None,
                             planned_at_s=1.0, operator="bench", with_hand=True)
        source = FrankaSource(FrankaConfig(host=host, backend="pylibfranka"), seconds)
        with tempfile.TemporaryDirectory() as out:
            cpu0, wall0 = time.process_time(), time.monotonic()
            result = capture(source, meta, Path(out) / "bench.parquet")
            cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
            session = validate_session(result.path)
    finally:
        server.kill()
        server.wait()
    info = session.meta.source_info
    ticks = session.n_samples + info["states_lost"]
    print(f"{seconds:.0f} s of robot time at 1 kHz from franky-sim ({host}), pylibfranka "
          f"{info['client_version']}")
    print(f"states recorded {session.n_samples}, lost {info['states_lost']} "
          f"({100 * info['states_lost'] / ticks:.2f} %) in {info['gaps']} gaps, longest "
          f"{1e3 * info['max_gap_s']:.0f} ms")
    print(f"wall time {wall:.1f} s for {session.duration_s:.1f} s of robot time "
          f"(server clock at {session.duration_s / wall:.2f}x real time)")
    print(f"recorder CPU {cpu:.1f} s = {100 * cpu / wall:.0f} % of one core "
          f"({1e6 * cpu / session.n_samples:.0f} us per state)")


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else 60.0)
