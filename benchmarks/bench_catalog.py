"""What a catalog costs: building it against plain replays, and serving it.

1. Build time per session: ``recorder catalog DATASET --out DIR --workers 1`` against
   ``replay DATASET --viewer none --save r.rrd`` of the same sessions with the same model
   (both the real commands, start-up included, best of ``--repeats``), and in-process per
   session (``replay_into_catalog`` against ``replay_session`` with ``save``, best of
   ``--repeats`` per session, summed), which leaves out start-up and hashing the files.
   The target of issue 40: the catalog within 1.2x of the replays.
2. The catalog server: ``rerun server -d DIR`` (the binary ``recorder browse``'s server
   runs) on ``--server-sessions`` recordings (default 1,000: copies of the catalog's
   recordings' chunks re-sent under new recording ids, so that each is its own segment
   with realistic size and properties; ``rerun rrd route`` would be the tool, but it
   panics on some of them in 0.41): time until Rerun's catalog client sees
   every segment, and the server's resident memory then.

    .venv/bin/python benchmarks/bench_catalog.py [--sessions 8] [--server-sessions 1000]

The dataset is the ``smoke`` preset (12 s sessions at 500 Hz); the model the default one
(built once and cached if missing) unless ``--model``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import psutil

from contactkit.cli.default_model import build_default_model
from contactkit.recorder.sim.dataset import simulate_dataset
from contactkit.replay.catalog import CatalogJob, model_identity, replay_into_catalog
from contactkit.replay.session_replay import replay_session
from contactkit.schemas import read_session_meta
from contactkit.schemas.dataset import session_files
from contactkit.viewer.web import free_port, rerun_executable

BIN = Path(sys.executable).parent


def best_of(repeats: int, run) -> float:
    """Return the shortest wall-clock time [s] of ``repeats`` calls of ``run()``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def commands(dataset: Path, model: Path, tmp: Path, repeats: int) -> tuple[float, float]:
    """Return the best wall-clock times [s] of the replay and the catalog commands."""
    def replay() -> None:
        out = tmp / "replay"
        out.mkdir(exist_ok=True)
        subprocess.run([str(BIN / "replay"), str(dataset), "--viewer", "none", "--save",
                        str(out / "r.rrd"), "--model", str(model), "--overwrite"],
                       check=True, capture_output=True)

    def catalog() -> None:
        out = tmp / "catalog"
        subprocess.run(["rm", "-rf", str(out)], check=True)
        subprocess.run([str(BIN / "recorder"), "catalog", str(dataset), "--out", str(out),
                        "--model", str(model), "--workers", "1", "--overwrite"],
                       check=True, capture_output=True)

    return best_of(repeats, replay), best_of(repeats, catalog)


def in_process(dataset: Path, model: Path, tmp: Path, repeats: int) -> tuple[float, float]:
    """Return the summed per-session best times [s] of a replay and a catalog job."""
    identity = {"model": model_identity(model), "dynamics": None}
    replay_total = catalog_total = 0.0
    for path in session_files(dataset):
        sid = read_session_meta(path)[0].session_id
        from contactkit.replay.catalog import _model

        loaded = _model(model)
        replay_total += best_of(repeats, lambda p=path, m=loaded: replay_session(
            p, m, save=tmp / "one.rrd", overwrite=True))
        job = CatalogJob(path, path.name, tmp / f"{sid}.rrd", model, identity)
        catalog_total += best_of(repeats, lambda j=job: replay_into_catalog(j))
    return replay_total, catalog_total


def server_start(catalog: Path, sessions: int, tmp: Path) -> tuple[float, float, int]:
    """Serve ``sessions`` recordings (copies of the catalog's under new ids) with
    ``rerun server -d``; return the seconds until the client sees them all, the
    server's resident memory [MiB] then, and the folder's size [MiB]."""
    import rerun as rr
    import rerun.chunk as rc
    from rerun.catalog import CatalogClient

    sources = [list(rc.RrdReader(p).stream()) for p in sorted(catalog.glob("*.rrd"))]
    folder = tmp / "served"
    folder.mkdir()
    rerun = rerun_executable()
    for k in range(sessions):
        rec = rr.RecordingStream("contactkit-replay", recording_id=f"bench{k:05d}")
        rec.save(folder / f"bench{k:05d}.rrd")
        rr.send_chunks(sources[k % len(sources)], recording=rec)
        rec.flush()
        rec.disconnect()
    size = sum(p.stat().st_size for p in folder.iterdir()) / 2**20
    port = free_port()
    start = time.perf_counter()
    server = subprocess.Popen([rerun, "server", "--host", "127.0.0.1", "--port", str(port),
                               "-d", f"bench={folder}"], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    try:
        while True:
            try:
                seen = len(CatalogClient(f"rerun+http://127.0.0.1:{port}")
                           .get_dataset("bench").segment_ids())
            except Exception:  # not up yet
                seen = 0
            if seen >= sessions:
                break
            if server.poll() is not None:
                raise RuntimeError("the catalog server ended")
            time.sleep(0.1)
        elapsed = time.perf_counter() - start
        rss = psutil.Process(server.pid).memory_info().rss / 2**20
    finally:
        server.terminate()
        server.wait()
    return elapsed, rss, round(size)


def main() -> None:
    """Run the benchmark and print its figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=8)
    parser.add_argument("--server-sessions", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--model", type=Path, default=None)
    args = parser.parse_args()
    model = args.model or build_default_model()
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        dataset = tmp / "smoke"
        simulate_dataset(dataset, "smoke", args.sessions, 0, 1)
        n = len(session_files(dataset))
        replay_s, catalog_s = commands(dataset, model, tmp, args.repeats)
        print(f"{n} smoke sessions, one worker, best of {args.repeats}")
        print(f"commands: replay --viewer none --save {replay_s:.2f} s "
              f"({replay_s / n:.3f} s/session); recorder catalog {catalog_s:.2f} s "
              f"({catalog_s / n:.3f} s/session); ratio {catalog_s / replay_s:.2f}")
        job_dir = tmp / "jobs"
        job_dir.mkdir()
        replay_job, catalog_job = in_process(dataset, model, job_dir, args.repeats)
        print(f"in-process per session: replay_session {replay_job / n:.3f} s, catalog job "
              f"{catalog_job / n:.3f} s; ratio {catalog_job / replay_job:.2f}")
        if args.server_sessions:
            elapsed, rss, size = server_start(tmp / "catalog", args.server_sessions, tmp)
            print(f"rerun server -d on {args.server_sessions} recordings ({size} MiB): all "
                  f"segments listed after {elapsed:.2f} s, resident memory {rss:.0f} MiB")


if __name__ == "__main__":
    main()
