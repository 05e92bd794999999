"""The long fuzz run: every reader of tests/suites/test_fuzz.py,
tests/suites/test_fuzz_imports.py and tests/suites/test_fuzz_inputs.py
under the ``long`` Hypothesis profile (2000 examples each, random seeds, instead of 30
fixed ones in ``make test``).

Prints, per reader, the examples run and how many the reader accepted or refused
with an InputError (from Hypothesis' statistics), the wall time, and whether any
example failed (a traceback, a hang, a file outside the output directory).

    .venv/bin/python benchmarks/bench_fuzz.py [examples per reader, default 2000] [readers]

``readers`` is a pytest ``-k`` expression (for example ``bag`` or ``"csv or calibration"``)
that runs only some readers.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    """Run the fuzz suite with the long profile; return pytest's exit code."""
    examples = int(sys.argv[1]) if len(sys.argv) > 1 else 2000
    readers = ["-k", f"test_fuzz_ and ({sys.argv[2]})"] if len(sys.argv) > 2 else \
        ["-k", "test_fuzz_"]
    env = dict(os.environ, CONTACTKIT_FUZZ_PROFILE="long",
               CONTACTKIT_FUZZ_EXAMPLES=str(examples))
    started = time.monotonic()
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          "tests/suites/test_fuzz.py", "tests/suites/test_fuzz_imports.py",
                          "tests/suites/test_fuzz_inputs.py", *readers,
                          "--hypothesis-show-statistics"],
                         cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.monotonic() - started
    report = run.stdout
    print(f"{'reader':30s} {'examples':>8s} {'failing':>8s}  accepted / refused")
    rows = 0
    for name, block in re.findall(r"tests/test_fuzz\w*\.py::(test_fuzz_\w+):\n(.*?)(?=\n\S|\Z)",
                                  report, flags=re.S):
        counts = re.findall(r"(\d+) passing, (\d+) failing", block)
        passing = sum(int(p) for p, _ in counts)
        failing = sum(int(f) for _, f in counts)
        events = "; ".join(f"{what} {share}" for share, what in
                           re.findall(r"\* ([\d.]+%), (\w+: \w+|recovered|left in place)",
                                      block))
        print(f"{name:30s} {passing + failing:8d} {failing:8d}  {events}")
        rows += 1
    print(f"{rows} readers")
    summary = report.strip().splitlines()[-1] if report.strip() else run.stderr[-500:]
    print(f"\n{summary}\nwall time {seconds:.0f} s; exit code {run.returncode}")
    if run.returncode:
        print(report[-6000:])
    return run.returncode


if __name__ == "__main__":
    sys.exit(main())
