"""recorder stats speed: index-only on 100,000 sessions, --deep on 1 and 2 workers.

Index-only: statistics of a synthetic 100,000-row index.parquet, against the
baseline of reading that file with Polars, measured in the same run. Deep: sessions
per second over a small simulated dataset with 1 and 2 worker processes, and the
speed-up from 1 to 2.

    .venv/bin/python benchmarks/bench_stats.py
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import polars as pl

from contactkit.recorder.sim.dataset import simulate_specs
from contactkit.recorder.sim.simulator import SimConfig, plan_session
from contactkit.recorder.stats.summary import deep_stats, index_stats
from contactkit.schemas import ACTIONS

ROWS = 100_000


def synthetic_index(path: Path) -> Path:
    """Write a 100,000-row index with the real index's columns."""
    rng = np.random.default_rng(0)
    dynamic = rng.random(ROWS) < 0.5
    frame = pl.DataFrame({
        "file": [f"s{i:06d}.parquet" for i in range(ROWS)],
        "session_id": [f"{i:016x}" for i in range(ROWS)],
        "source": "sim",
        "condition": np.where(dynamic, "dynamic", "static"),
        "pose": np.where(dynamic, "A", rng.choice(list("ABCDEFGH"), ROWS)),
        "target_pose": [t if d else None for t, d in zip(rng.choice(list("BCDEFGH"), ROWS),
                                                          dynamic, strict=True)],
        "action": rng.choice(ACTIONS, ROWS),
        "link": rng.integers(1, 8, ROWS).astype(np.int8),
        "speed_rad_s": np.where(dynamic, rng.uniform(0.1, 0.5, ROWS), np.nan),
        "planned_at_s": 5.0,
        "nominal_rate_hz": 600.0,
        "n_samples": 7201,
        "t_start_s": 0.0,
        "t_end_s": 12.0,
        "duration_s": 12.0,
        "operator": rng.choice([f"sim-op-{i}" for i in range(1, 6)], ROWS),
        "with_hand": True,
        "recovered": False,
        "created_utc": "2026-01-01T00:00:00Z",
        "schema_version": 1,
        "file_bytes": rng.integers(1_000_000, 2_000_000, ROWS),
        "metadata_json": "{}",
    })
    frame.write_parquet(path)
    return path


def deep_dataset(directory: Path, sessions: int = 24) -> list[Path]:
    """Simulate ``sessions`` 6 s static sessions at 500 Hz."""
    directory.mkdir()
    specs = [plan_session(seed=k, condition="static", action=ACTIONS[k % 4],
                          pose="ABCDEFGH"[k % 8], duration_s=6.0, planned_at_s=3.0)
             for k in range(sessions)]
    return [Path(p) for p in simulate_specs(specs, SimConfig(rate_hz=500.0), directory)]


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        index = synthetic_index(Path(tmp) / "index.parquet")
        start = time.perf_counter()
        pl.read_parquet(index)
        baseline = time.perf_counter() - start
        start = time.perf_counter()
        stats = index_stats(pl.scan_parquet(index))
        elapsed = time.perf_counter() - start
        print(f"index-only stats of {stats['sessions']} sessions: {elapsed:.3f} s "
              f"(reading the index alone: {baseline:.3f} s, ratio {elapsed / baseline:.1f})")
        files = deep_dataset(Path(tmp) / "deep")
        rates = {}
        for workers in (1, 2):
            start = time.perf_counter()
            deep_stats(files, workers)
            rates[workers] = len(files) / (time.perf_counter() - start)
            print(f"--deep with {workers} worker(s): {rates[workers]:.1f} sessions/s "
                  f"({len(files)} sessions of 6 s at 500 Hz)")
        print(f"--deep speed-up from 1 to 2 workers: {rates[2] / rates[1]:.2f}x")


if __name__ == "__main__":
    main()
