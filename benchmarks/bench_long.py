"""Long sessions: peak RSS and time against session length, case by case (capture,
reading, replay, features, stats and the importers).

Each case runs in a fresh Python process (so its peak RSS is its own) on a synthetic
1 kHz stream with the simulator's 52 columns, generated in chunks as a source
would (the simulator itself would dominate the time):

* ``capture``: :func:`contactkit.recorder.capture.record.capture` through the journal to
  the final Parquet file, exactly as ``recorder capture`` writes it;
* ``read``: the whole session read and validated at once (``read_session``);
* ``chunks``: the same file read and validated row group by row group
  (``iter_session_batches``);
* ``replay``: ``replay FILE --viewer none --save out.rrd`` with the default model
  (contact detector, event classifier, hop classifier), streamed batch by batch;
* ``features``: ``classify features FILE --per-sample --out samples.parquet``, every
  timeseries feature of every sample, streamed batch by batch;
* ``windows``: ``classify features`` without ``--per-sample``: the thesis's default
  window features (range of dq, tau, r in the Difference window; the session's planned
  time is at 30 s, so the window is found early and the rest is only validated);
* ``stats-deep``: the per-session summary of ``recorder stats --deep`` (exact medians
  in a few passes, the chain run once);
* ``import-bag``: ``recorder import-bag`` of an MCAP bag of ``sensor_msgs/JointState``
  on ``/joint_states`` at 1 kHz, written beforehand with rosbags' writer;
* ``import-csv``: ``recorder import-csv`` of a CSV file with the MindLab map's columns
  at 1 kHz, written beforehand.

Prints, per length: seconds, peak RSS [MB] and the process's RSS after imports, the
ratios of time and of memory above that baseline to the shortest case, and per case
the slopes between the shortest and the longest run: seconds per minute of session
and MB of peak RSS per minute (flat memory: about 0).

    .venv/bin/python benchmarks/bench_long.py                       # 1 and 10 min
    .venv/bin/python benchmarks/bench_long.py --minutes 1 10 60 --cases replay
    .venv/bin/python benchmarks/bench_long.py --cases stats-deep windows import-bag import-csv
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq

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


def write_long_session(minutes: float, path: Path) -> int:
    """Capture a synthetic session of ``minutes`` at 1 kHz to ``path``; return its samples."""
    from contactkit.recorder.capture.record import capture
    from contactkit.schemas import SessionMeta

    path.unlink(missing_ok=True)
    meta = SessionMeta(session_id="bench", source="sim", action="none",
                       nominal_rate_hz=RATE_HZ, planned_at_s=PLANNED_AT_S)
    return capture(SyntheticSource(minutes), meta, path).samples


PLANNED_AT_S = 30.0
BAG_TOPIC = "/joint_states"


def write_long_bag(minutes: float, path: Path) -> None:
    """Write an MCAP bag of ``sensor_msgs/JointState`` at 1 kHz for ``minutes``, as a
    recorder would (chunk by chunk, nothing held)."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer

    from contactkit.recorder.importers.bags import JOINT_STATE, default_typestore

    store = default_typestore(False)
    types = store.types
    names = [f"panda_joint{j}" for j in range(1, 8)]
    start_ns = 1_700_000_000_000_000_000
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(BAG_TOPIC, JOINT_STATE, typestore=store)
        for chunk in SyntheticSource(minutes).stream():
            for i, t in enumerate(chunk["t"]):
                stamp = start_ns + round(t * 1e9)
                header = types["std_msgs/msg/Header"](
                    stamp=types["builtin_interfaces/msg/Time"](sec=stamp // 10**9,
                                                               nanosec=stamp % 10**9),
                    frame_id="")
                values = [np.array([chunk[f"{p}_{j}"][i] for j in range(1, 8)])
                          for p in ("q", "dq", "tau")]
                msg = types[JOINT_STATE](header=header, name=names, position=values[0],
                                         velocity=values[1], effort=values[2])
                writer.write(connection, stamp, store.serialize_cdr(msg, JOINT_STATE))


def write_long_csv(minutes: float, path: Path) -> None:
    """Write a CSV file with the MindLab map's columns at 1 kHz for ``minutes``."""
    import polars as pl

    with open(path, "w") as fh:
        for n, chunk in enumerate(SyntheticSource(minutes).stream()):
            frame = {"time": chunk["t"]}
            for prefix, csv in (("q", "q"), ("dq", "dq"), ("tau", "tau_J"), ("q", "q_d"),
                                ("dq", "dq_d"), ("tau", "tau_ext")):
                frame.update({f"{csv}{j - 1}": chunk[f"{prefix}_{j}"] for j in range(1, 8)})
            frame["label"] = chunk["contact"].astype(int)
            fh.write(pl.DataFrame(frame).write_csv(include_header=n == 0))


INPUTS = {"import-bag": ("rosbag2", write_long_bag), "import-csv": ("csv", write_long_csv)}


def run_case(case: str, minutes: float, directory: Path, model: Path | None = None) -> dict:
    """Run one case in this process on ``directory/long_<minutes>.parquet`` (written by
    the capture case); return seconds, peak and baseline RSS [MB]
    (baseline: after the imports and, for replay, the model)."""
    from contactkit.schemas import read_session
    from contactkit.schemas.session import iter_session_batches

    path = directory / f"long_{minutes:g}.parquet"
    if case.startswith("make-"):
        suffix, write = INPUTS[case[len("make-"):]]
        write(minutes, directory / f"long_{minutes:g}.{suffix}")
        return {}
    if case == "replay":
        from contactkit.cli.default_model import model_or_default
        from contactkit.cli.replay import pyarrow_without_pandas
        from contactkit.replay.session_replay import replay_session

        pyarrow_without_pandas()  # as the console script does
        replay_model = model_or_default(model)
    elif case == "features":
        from contactkit.features.per_sample import write_per_sample_table
    elif case == "windows":
        from contactkit.features.extract import SessionFeatures, feature_rows

        os.environ["CONTACTKIT_CHAIN_CACHE"] = "0"  # short sessions: no cache hit, none left
    elif case == "stats-deep":
        from contactkit.recorder.stats.deep import session_summary
    elif case == "import-bag":
        from contactkit.recorder.importers.bags import BagImporter
        from contactkit.recorder.importers.writer import write_importer
        from contactkit.recorder.metadata import session_meta
    elif case == "import-csv":
        from contactkit.recorder.importers.csv_import import CsvImporter
        from contactkit.recorder.importers.csv_map import load_csv_map, mindlab_map_path
        from contactkit.recorder.importers.writer import write_importer
        from contactkit.recorder.metadata import session_meta
    out_dir = directory / f"out_{case}_{minutes:g}"
    out_dir.mkdir(exist_ok=True)
    baseline = _rss_mb()
    start = time.perf_counter()
    if case == "capture":
        samples = write_long_session(minutes, path)
    elif case == "read":
        samples = read_session(path).n_samples
    elif case == "chunks":
        samples = sum(batch.num_rows for batch in iter_session_batches(path))
    elif case == "replay":
        out = directory / f"long_{minutes:g}.rrd"
        replay_session(path, replay_model, save=out)
        samples = pq.ParquetFile(path).metadata.num_rows
    elif case == "features":
        out = directory / f"long_{minutes:g}_samples.parquet"
        write_per_sample_table([path], out)
        samples = pq.ParquetFile(out).metadata.num_rows
    elif case == "windows":
        result = feature_rows([path], SessionFeatures())
        assert len(result) and not result.problems, result.problems
        samples = pq.ParquetFile(path).metadata.num_rows
    elif case == "stats-deep":
        summary = session_summary(str(path))
        assert "problem" not in summary, summary
        samples = summary["sampling"]["samples"]
    elif case == "import-bag":
        meta = session_meta(source="ros-bag", action="none", condition="static", pose="A")
        with BagImporter.read(directory / f"long_{minutes:g}.rosbag2") as bag:
            written = write_importer(bag, meta, out_dir)
        samples = pq.ParquetFile(written).metadata.num_rows
    else:
        meta = session_meta(source="csv", action="none", condition="static", pose="A")
        with CsvImporter.read(directory / f"long_{minutes:g}.csv",
                              load_csv_map(mindlab_map_path())) as csv:
            written = write_importer(csv, meta, out_dir)
        samples = pq.ParquetFile(written).metadata.num_rows
    return {"case": case, "minutes": minutes, "samples": samples,
            "seconds": time.perf_counter() - start, "peak_mb": _rss_mb(),
            "baseline_mb": baseline}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, nargs="+", default=[1, 10])
    parser.add_argument("--cases", nargs="+",
                        default=["capture", "read", "chunks", "replay", "features", "windows",
                                 "stats-deep", "import-bag", "import-csv"])
    parser.add_argument("--model", type=Path, help="model file for replay (default: the "
                                                   "default model)")
    parser.add_argument("--one", nargs=3, metavar=("CASE", "MINUTES", "DIR"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_case(args.one[0], float(args.one[1]), Path(args.one[2]),
                                  args.model)))
        return
    with tempfile.TemporaryDirectory() as tmp:
        needed = [] if "capture" in args.cases else ["capture"]  # the sessions read
        needed += [f"make-{case}" for case in args.cases if case in INPUTS]
        for step in needed:
            for minutes in args.minutes:
                subprocess.run([sys.executable, __file__, "--one", step, str(minutes),
                                tmp], check=True, capture_output=True)
        for case in args.cases:
            rows = []
            for minutes in args.minutes:
                command = [sys.executable, __file__, "--one", case, str(minutes), tmp]
                if args.model:
                    command += ["--model", str(args.model)]
                out = subprocess.run(command, capture_output=True, text=True)
                if out.returncode:
                    sys.exit(f"{case} {minutes:g} min failed:\n{out.stderr[-2000:]}")
                row = json.loads(out.stdout)
                rows.append(row)
                above = row["peak_mb"] - row["baseline_mb"]
                first = (rows[0]["seconds"], max(rows[0]["peak_mb"] - rows[0]["baseline_mb"],
                                                 1.0))
                print(f"{case:10s} {minutes:5g} min  {row['samples']:>9d} samples  "
                      f"{row['seconds']:7.1f} s  peak {row['peak_mb']:7.0f} MB "
                      f"(imports {row['baseline_mb']:4.0f} MB)  "
                      f"time x{row['seconds'] / first[0]:5.1f}"
                      f"  memory above imports x{above / first[1]:5.1f}", flush=True)
            if len(rows) > 1:
                span = rows[-1]["minutes"] - rows[0]["minutes"]
                print(f"{case:10s} slope: {(rows[-1]['seconds'] - rows[0]['seconds']) / span:.2f}"
                      f" s per minute of session, "
                      f"{(rows[-1]['peak_mb'] - rows[0]['peak_mb']) / span:+.2f} MB peak RSS "
                      f"per minute", flush=True)


if __name__ == "__main__":
    main()
