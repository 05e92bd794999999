"""CLI start-up: wall time and peak RSS of `--help`, `recorder info` and a short replay.

Each command runs as a fresh process through the installed console scripts, several
times (the median is reported), against two baselines measured in the same run:
``python -c pass`` (the interpreter alone) and ``python -c "import rerun"`` (one heavy
library). Ratios, not seconds, are what compare across runs on a shared machine.

The replay (``replay SESSION --viewer none --save out.rrd`` of a 12 s session at 1 kHz
with the default model: detector, event classifier, per-hop SVM) is the whole command
a user waits for, start-up included; its baseline is ``python -c "import rerun,
pinocchio"``, the two libraries it computes and logs with. A first replay, not
counted, builds the default model if it is not cached yet (minutes, once).

This script imports no contactkit module: a child's peak RSS starts from its parent's
at the fork, so the parent stays small.

    .venv/bin/python benchmarks/bench_startup.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent


def run_once(command: list[str]) -> tuple[float, float]:
    """Return wall time [s] and peak RSS [MB] of one run of ``command``."""
    start = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=dict(os.environ, COLUMNS="200"))
    _, status, usage = os.wait4(proc.pid, 0)
    elapsed = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(command)} exited with {proc.returncode}")
    return elapsed, usage.ru_maxrss / 1024  # Linux: ru_maxrss in KiB


def measure(command: list[str], repeats: int) -> tuple[float, float]:
    """Return the median wall time [s] and the median peak RSS [MB] over ``repeats``."""
    runs = [run_once(command) for _ in range(repeats)]
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)


def make_session(directory: Path, duration_s: float = 2.0) -> Path:
    """Record a simulated session of ``duration_s`` [s] at 1 kHz with the recorder (the
    planned touch half-way); return its path."""
    out = subprocess.run([str(BIN / "recorder"), "capture", "--pose", "B", "--action",
                          "adjust", "--seed", "1", "--duration", str(duration_s),
                          "--planned-at", str(duration_s / 2), "--rate", "1000", "--out",
                          str(directory / f"{duration_s:g}s")],
                         capture_output=True, text=True, check=True)
    return Path(out.stdout.strip().splitlines()[-1])


def main() -> None:
    """Measure every command and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    repeats = parser.parse_args().repeats
    with tempfile.TemporaryDirectory() as tmp:
        session = make_session(Path(tmp))
        long_session = make_session(Path(tmp), 12.0)
        cases = {
            "python -c pass": [sys.executable, "-c", "pass"],
            "python -c 'import rerun'": [sys.executable, "-c", "import rerun"],
            "recorder --help": [str(BIN / "recorder"), "--help"],
            "recorder capture --help": [str(BIN / "recorder"), "capture", "--help"],
            "replay --help": [str(BIN / "replay"), "--help"],
            "classify --help": [str(BIN / "classify"), "--help"],
            "recorder info SESSION": [str(BIN / "recorder"), "info", str(session)],
            "python -c 'import rerun, pin'": [sys.executable, "-c",
                                              "import rerun, pinocchio"],
            "replay 12 s --viewer none": [str(BIN / "replay"), str(long_session), "--viewer",
                                          "none", "--save", str(Path(tmp) / "r.rrd"),
                                          "--overwrite"],
        }
        run_once(cases["replay 12 s --viewer none"])  # builds the default model if missing
        results = {name: measure(command, repeats) for name, command in cases.items()}
    bare = results["python -c pass"][0]
    rerun = results["python -c 'import rerun'"][0]
    print(f"median of {repeats} runs each; ratios against baselines of this run")
    print(f"{'command':28s} {'time [s]':>9s} {'x pass':>8s} {'x rerun':>8s} {'RSS [MB]':>9s}")
    for name, (seconds, rss) in results.items():
        print(f"{name:28s} {seconds:9.3f} {seconds / bare:8.1f} {seconds / rerun:8.2f} "
              f"{rss:9.0f}")
    replay, libraries = results["replay 12 s --viewer none"], results[
        "python -c 'import rerun, pin'"]
    print(f"replay of 12 s: {replay[0] / libraries[0]:.2f}x the time and "
          f"{replay[1] / libraries[1]:.2f}x the peak RSS of importing rerun and pinocchio")


if __name__ == "__main__":
    main()
