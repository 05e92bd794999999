"""The 20-kill check: SIGKILL a ``--realtime`` capture at random moments, recover, and
count the samples lost.

Each round starts ``recorder capture --realtime`` (1000 Hz, 8 s), SIGKILLs it at a
random time 0.3-6 s after recording started, runs ``recorder recover`` and compares
the recovered session with a full capture of the same seed. During the last second
before the kill the journal is read every 20 ms: how fast its last sample time grows
gives the capture's pace, so the sample time the capture had reached at the kill is
known even on a machine too loaded to keep up with real time (``lag_s`` says how far
behind it was). Per kill it prints the samples the journal held just before the kill,
the samples recovered, values differing from the full capture, the lag and the samples
lost beyond the flush interval. Two figures, per kill and in total, must be 0:

* samples flushed before the kill but not recovered, or recovered with other values;
* samples lost beyond the flush interval: samples the capture had produced more than
  one flush interval (0.1 s) before the kill that the recovered session lacks.

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

from contactkit.recorder.capture.journal import journal_progress

BIN = Path(sys.executable).parent
RATE_HZ = 1000.0
FLUSH_S = 0.1
ARGS = ["--pose", "C", "--action", "shove", "--seed", "21", "--duration", "8",
        "--planned-at", "4", "--rate", str(RATE_HZ)]


def kill_once(directory: Path, after_s: float) -> tuple[float, int, float | None]:
    """Capture into ``directory``, SIGKILL ``after_s`` after recording started; return the
    time [s] from that line to the kill, the journal's samples just before it and the
    sample time [s] the capture had reached at the kill (None: see :func:`reached_at`)."""
    proc = subprocess.Popen([str(BIN / "recorder"), "capture", *ARGS, "--realtime", "--out",
                             str(directory)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    polls: list[tuple[float, float]] = []
    try:
        for line in proc.stderr:
            if "recording started" in line:
                break
        started = time.monotonic()
        while (now := time.monotonic()) < started + after_s:
            if started + after_s - now > 1.0:
                time.sleep(started + after_s - now - 1.0)
                continue
            before, t_last = journal_progress(directory)
            polls.append((time.monotonic(), t_last))
            time.sleep(0.02)
        before, t_last = journal_progress(directory)
        proc.send_signal(signal.SIGKILL)
        killed = time.monotonic()
    finally:
        proc.wait(timeout=60)
    polls.append((killed, t_last))
    return killed - started, before, reached_at(polls, killed)


def reached_at(polls: list[tuple[float, float]], killed: float) -> float | None:
    """Return the sample time [s] a capture had reached at wall time ``killed``, from
    ``(wall time, journal's last sample time)`` polls: the journal's last sample time plus
    its pace (sample seconds per wall second) times the wall time since it last grew.
    None when the journal did not grow during the polls (the pace is unknown)."""
    grown = [(w, t) for (w, t), (_, before) in zip(polls[1:], polls, strict=False)
             if t > before]
    if not grown:
        return None
    (w0, t0), (w1, t1) = polls[0], grown[-1]
    pace = (t1 - t0) / (w1 - w0) if w1 > w0 else 1.0
    return t1 + min(max(pace, 0.0), 1.0) * (killed - w1)


def main() -> int:
    """Run the kills; return 1 when a sample was lost (either figure), else 0."""
    kills = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    rng = random.Random(int(sys.argv[2]) if len(sys.argv) > 2 else 0)
    from contactkit.schemas import validate_session

    with tempfile.TemporaryDirectory() as tmp:
        full = subprocess.run([str(BIN / "recorder"), "capture", *ARGS, "--out",
                               f"{tmp}/full"], capture_output=True, text=True, check=True)
        reference = pq.read_table(full.stdout.strip())
        print(f"{'kill':>4s} {'after_s':>8s} {'journal':>8s} {'recovered':>9s} "
              f"{'differing':>9s} {'lag_s':>6s} {'lost_beyond_flush':>17s}")
        lost_flushed = lost_beyond = unmeasured = 0
        for k in range(kills):
            directory = Path(tmp) / f"kill{k}"
            killed_after, before, reached = kill_once(directory, rng.uniform(0.3, 6.0))
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
            lost_flushed += max(0, before - n) + differing
            if reached is None:
                unmeasured += 1
                print(f"{k + 1:4d} {killed_after:8.2f} {before:8d} {n:9d} {differing:9d} "
                      f"{'-':>6s} {'-':>17s}")
                continue
            beyond = max(0, int(np.floor((reached - FLUSH_S - t_end) * RATE_HZ)))
            lost_beyond += beyond
            print(f"{k + 1:4d} {killed_after:8.2f} {before:8d} {n:9d} {differing:9d} "
                  f"{killed_after - reached:6.2f} {beyond:17d}")
    print(f"\n{kills} kills: {lost_flushed} flushed samples lost or changed; "
          f"{lost_beyond} samples lost beyond the {FLUSH_S} s flush interval"
          + (f" ({unmeasured} kills unmeasured: the journal did not grow in the second "
             "before the kill)" if unmeasured else ""))
    return 1 if lost_flushed or lost_beyond else 0


if __name__ == "__main__":
    sys.exit(main())
