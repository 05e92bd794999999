"""CLI start-up: wall time and peak RSS of `--help` and `recorder info`.

Each command runs as a fresh process through the installed console scripts, several
times (the median is reported), against two baselines measured in the same run:
``python -c pass`` (the interpreter alone) and ``python -c "import rerun"`` (one heavy
library). Ratios, not seconds, are what compare across runs on a shared machine.

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


def make_session(directory: Path) -> Path:
    """Record a 2 s simulated session with the recorder; return its path."""
    out = subprocess.run([str(BIN / "recorder"), "capture", "--pose", "B", "--action",
                          "adjust", "--seed", "1", "--duration", "2", "--planned-at", "1", "--out",
                          str(directory)], capture_output=True, text=True, check=True)
    return Path(out.stdout.strip().splitlines()[-1])


def main() -> None:
    """Measure every command and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    repeats = parser.parse_args().repeats
    with tempfile.TemporaryDirectory() as tmp:
        session = make_session(Path(tmp))
        cases = {
            "python -c pass": [sys.executable, "-c", "pass"],
            "python -c 'import rerun'": [sys.executable, "-c", "import rerun"],
            "recorder --help": [str(BIN / "recorder"), "--help"],
            "recorder capture --help": [str(BIN / "recorder"), "capture", "--help"],
            "replay --help": [str(BIN / "replay"), "--help"],
            "classify --help": [str(BIN / "classify"), "--help"],
            "recorder info SESSION": [str(BIN / "recorder"), "info", str(session)],
        }
        results = {name: measure(command, repeats) for name, command in cases.items()}
    bare = results["python -c pass"][0]
    rerun = results["python -c 'import rerun'"][0]
    print(f"median of {repeats} runs each; ratios against baselines of this run")
    print(f"{'command':28s} {'time [s]':>9s} {'x pass':>8s} {'x rerun':>8s} {'RSS [MB]':>9s}")
    for name, (seconds, rss) in results.items():
        print(f"{name:28s} {seconds:9.3f} {seconds / bare:8.1f} {seconds / rerun:8.2f} "
              f"{rss:9.0f}")


if __name__ == "__main__":
    main()
