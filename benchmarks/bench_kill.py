"""The 20-kill check: SIGKILL a ``--realtime`` capture at random moments, recover, and
count the samples lost.

Each round starts ``recorder capture --realtime`` (1000 Hz, 8 s), reads its journal
just before a SIGKILL at a random time 0.3-6 s after recording started, runs
``recorder recover`` and compares the recovered session with a full capture of the
same seed. Per kill it prints the samples the journal held before the kill, the
samples recovered, values differing from the full capture, and the gap between the
kill and the last recovered sample. Two figures must be 0:

* samples flushed before the kill but not recovered, or recovered with other values;
* samples lost beyond the flush interval: samples older than (kill - 0.1 s) missing.
  The second also counts samples the capture had not yet produced, so it is only
  meaningful on a machine that keeps up with real time (the gap column shows it).

    .venv/bin/python benchmarks/bench_kill.py [kills, default 20] [seed, default 0]
"""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

BIN = Path(sys.executable).parent
RATE_HZ = 1000.0
FLUSH_S = 0.1
ARGS = ["--pose", "C", "--action", "shove", "--seed", "21", "--duration", "8",
        "--planned-at", "4", "--rate", str(RATE_HZ)]


def journal_rows(directory: Path) -> int:
    """Return the complete samples the journal in ``directory`` holds now (0 if none)."""
    from contactkit.recorder.journal import read_journal
    from contactkit.schemas import InputError

    for journal in directory.glob("*.journal"):
        try:
            return read_journal(journal).table.num_rows
        except InputError:
            return 0
    return 0


def kill_once(directory: Path, after_s: float) -> tuple[float, int]:
    """Capture into ``directory``, SIGKILL ``after_s`` after recording started; return the
    time [s] from that line to the kill and the journal's samples just before it."""
    proc = subprocess.Popen([str(BIN / "recorder"), "capture", *ARGS, "--realtime", "--out",
                             str(directory)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        for line in proc.stderr:
            if "recording started" in line:
                break
        started = time.monotonic()
        time.sleep(after_s)
        before = journal_rows(directory)
        proc.send_signal(signal.SIGKILL)
        killed_after = time.monotonic() - started
    finally:
        proc.wait(timeout=60)
    return killed_after, before


def main() -> int:
    """Run the kills; return 1 when a flushed sample was lost, else 0."""
    kills = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    rng = random.Random(int(sys.argv[2]) if len(sys.argv) > 2 else 0)
    from contactkit.schemas import validate_session

    with tempfile.TemporaryDirectory() as tmp:
        full = subprocess.run([str(BIN / "recorder"), "capture", *ARGS, "--out",
                               f"{tmp}/full"], capture_output=True, text=True, check=True)
        reference = pq.read_table(full.stdout.strip())
        print(f"{'kill':>4s} {'after_s':>8s} {'journal':>8s} {'recovered':>9s} "
              f"{'differing':>9s} {'gap_s':>6s} {'lost_beyond_flush':>17s}")
        lost_flushed = lost_beyond = 0
        for k in range(kills):
            directory = Path(tmp) / f"kill{k}"
            killed_after, before = kill_once(directory, rng.uniform(0.3, 6.0))
            subprocess.run([str(BIN / "recorder"), "recover", str(directory)],
                           capture_output=True, check=True)
            sessions = list(directory.glob("*.parquet"))
            session = validate_session(sessions[0]) if sessions else None
            n = session.n_samples if session else 0
            differing = 0
            if session is not None:
                for name in session.table.column_names:
                    want = reference.column(name).to_numpy()[:n]
                    differing += int((session.column(name) != want).sum())
            t_end = float(session.t[-1]) if session else 0.0
            gap = killed_after - t_end
            beyond = max(0, int(np.floor((gap - FLUSH_S) * RATE_HZ)))
            lost_flushed += max(0, before - n) + differing
            lost_beyond += beyond
            print(f"{k + 1:4d} {killed_after:8.2f} {before:8d} {n:9d} {differing:9d} "
                  f"{gap:6.3f} {beyond:17d}")
    print(f"\n{kills} kills: {lost_flushed} flushed samples lost or changed; "
          f"{lost_beyond} samples lost beyond the {FLUSH_S} s flush interval")
    return 1 if lost_flushed else 0


if __name__ == "__main__":
    sys.exit(main())
