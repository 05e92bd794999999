"""Long sessions: peak RSS and time against session length, for capture and reading.

Each case runs in a fresh Python process (so its peak RSS is its own) on a synthetic
1 kHz stream with the simulator's 52 columns, generated in chunks as a source
would (the simulator itself would dominate the time):

* ``capture``: :func:`contactkit.recorder.capture.capture` through the journal to
  the final Parquet file, exactly as ``recorder capture`` writes it;
* ``read``: the whole session read and validated at once (``read_session``);
* ``chunks``: the same file read and validated row group by row group
  (``iter_session_batches``).

Prints, per length: seconds, peak RSS [MB] and the process's RSS after imports, and
the ratios of time and of memory above that baseline to the 1-minute case.

    .venv/bin/python benchmarks/bench_long.py              # 1 and 10 min
    .venv/bin/python benchmarks/bench_long.py --minutes 1 10 60
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RATE_HZ = 1000.0
CHUNK = 100


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


class SyntheticSource:
    """A 1 kHz stream of the simulator's columns: smooth joints, noisy torques."""

    name = "sim"
    live = False

    def __init__(self, minutes: float) -> None:
        from contactkit.recorder.sources.sim import SIM_COLUMNS

        self.columns = SIM_COLUMNS
        self.n = int(minutes * 60 * RATE_HZ)

    def stream(self):
        """Yield chunks of CHUNK samples."""
        import numpy as np

        rng = np.random.default_rng(0)
        for start in range(0, self.n, CHUNK):
            t = np.arange(start, min(start + CHUNK, self.n)) / RATE_HZ
            chunk = {"t": t, "contact": (t % 10) > 8}
            for name in self.columns[1:-1]:
                chunk[name] = np.sin(t) + 0.01 * rng.standard_normal(len(t))
            yield chunk

    def metadata(self) -> dict:
        """Return the source fields of the session metadata."""
        return {"source": "sim"}


def run_case(case: str, minutes: float, directory: Path) -> dict:
    """Run one case in this process; return seconds, peak and baseline RSS [MB]."""
    from contactkit.recorder.capture import capture
    from contactkit.schemas import SessionMeta, read_session

    path = directory / f"long_{minutes:g}.parquet"
    baseline = _rss_mb()
    start = time.perf_counter()
    if case == "capture":
        path.unlink(missing_ok=True)
        meta = SessionMeta(session_id="bench", source="sim", action="none",
                           nominal_rate_hz=RATE_HZ)
        samples = capture(SyntheticSource(minutes), meta, path).samples
    elif case == "read":
        samples = read_session(path).n_samples
    else:
        from contactkit.schemas.session import iter_session_batches

        samples = sum(batch.num_rows for batch in iter_session_batches(path))
    return {"case": case, "minutes": minutes, "samples": samples,
            "seconds": time.perf_counter() - start, "peak_mb": _rss_mb(),
            "baseline_mb": baseline}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, nargs="+", default=[1, 10])
    parser.add_argument("--cases", nargs="+", default=["capture", "read", "chunks"])
    parser.add_argument("--one", nargs=3, metavar=("CASE", "MINUTES", "DIR"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_case(args.one[0], float(args.one[1]), Path(args.one[2]))))
        return
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases:
            first = None
            for minutes in args.minutes:
                out = subprocess.run([sys.executable, __file__, "--one", case, str(minutes),
                                      tmp], check=True, capture_output=True, text=True)
                row = json.loads(out.stdout)
                above = row["peak_mb"] - row["baseline_mb"]
                first = first or (row["seconds"], max(above, 1.0))
                print(f"{case:8s} {minutes:5g} min  {row['samples']:>9d} samples  "
                      f"{row['seconds']:7.1f} s  peak {row['peak_mb']:7.0f} MB "
                      f"(imports {row['baseline_mb']:4.0f} MB)  "
                      f"time x{row['seconds'] / first[0]:5.1f}"
                      f"  memory above imports x{above / first[1]:5.1f}", flush=True)


if __name__ == "__main__":
    main()
