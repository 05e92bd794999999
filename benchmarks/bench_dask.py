"""The Dask path against the local pool, on the same cores.

Runs the real jobs of three steps through :func:`contactkit.util.parallel.map_ordered`
with the local pool and with a Dask ``LocalCluster`` (``local:N``), and prints:

* overhead of Dask against the local pool, 2 workers each: scalar features of
  ``--sessions`` sessions (the jobs cycle over a small simulated set, each one
  reading and processing its file in full) and a 5-fold SVM evaluation on those
  features (target: at most 10 % slower);
* speed-up from 1 to 2 workers, local pool and Dask, for ``simulate`` (the smoke preset,
  one session per job) and for features (target: at least 1.7x).

The cluster is started before timing (once per worker count); the first map on it
warms its workers (imports) and is not timed. The per-session chain cache is off
(``CONTACTKIT_CHAIN_CACHE=0``), so every feature job computes its chain. Results are
checked identical. Run it on a quiet machine: the figures are wall-clock times.

    .venv/bin/python benchmarks/bench_dask.py                  # 500 feature jobs
    .venv/bin/python benchmarks/bench_dask.py --sessions 40 --simulate 4    # a smoke run
"""

from __future__ import annotations

import argparse
import functools
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ["CONTACTKIT_CHAIN_CACHE"] = "0"

import numpy as np
from sklearn.model_selection import StratifiedKFold

from contactkit.classify.kinds.registry import make_estimator
from contactkit.features.extract import SessionFeatures, _session_feature_row
from contactkit.recorder.sim.dataset import PRESETS, preset_specs, simulate_specs
from contactkit.recorder.sim.simulator import SimConfig
from contactkit.util.dask_executor import close_clients, get_client
from contactkit.util.parallel import map_ordered


def _fit_predict(task: tuple) -> np.ndarray:
    estimator, X_train, y_train, X_test = task
    return estimator.fit(X_train, y_train).predict(X_test)


def _warm(_: int) -> int:
    """Import on a worker what the timed jobs need (the local pool forks with them)."""
    import contactkit.classify.kinds.registry
    import contactkit.features.extract
    import contactkit.recorder.sim.dataset  # noqa: F401

    return 0


def timed(label: str, fn, items, **how) -> tuple[float, list]:
    """Return the seconds ``map_ordered`` takes over ``items`` and its results; print them."""
    start = time.perf_counter()
    results = list(map_ordered(fn, items, **how))
    seconds = time.perf_counter() - start
    print(f"  {label}: {seconds:.2f} s", flush=True)
    return seconds, results


def executors(workers: int) -> dict[str, dict]:
    """The local pool and a warmed-up Dask LocalCluster with ``workers`` workers."""
    address = f"local:{workers}"
    client = get_client(address)
    client.wait_for_workers(workers)
    list(map_ordered(_warm, range(4 * workers), scheduler=address))
    return {"local pool": {"workers": workers, "scheduler": "local"},
            "dask": {"scheduler": address}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=500, help="feature jobs")
    parser.add_argument("--simulate", type=int, default=8, help="sessions simulated")
    args = parser.parse_args()
    if args.simulate < 4 or args.sessions < 40:
        parser.error("the 5-fold SVM needs all four actions: --simulate 4 or more, "
                     "--sessions 40 or more")
    with tempfile.TemporaryDirectory() as tmp:
        config = SimConfig(rate_hz=PRESETS["smoke"].rate_hz)
        specs = preset_specs(PRESETS["smoke"], args.simulate, seed=1)
        batches = [[spec] for spec in specs]
        times: dict[tuple[str, str, int], float] = {}
        for workers in (1, 2):
            for name, how in executors(workers).items():
                out = Path(tmp) / f"sim_{name.replace(' ', '_')}_{workers}"
                out.mkdir()
                job = functools.partial(simulate_specs, config=config, out_dir=str(out))
                times["simulate", name, workers], _ = timed(f"simulate {name} {workers}", job,
                                                           batches, **how)
            close_clients()
        files = sorted(str(p) for p in (Path(tmp) / "sim_local_pool_1").glob("*.parquet"))
        paths = [files[k % len(files)] for k in range(args.sessions)]
        extractor = SessionFeatures()
        extractor.fit(None)
        jobs = [(path, extractor.get_params()) for path in paths]
        reference = None
        for workers in (1, 2):
            for name, how in executors(workers).items():
                times["features", name, workers], rows = timed(
                    f"features {name} {workers}", _session_feature_row, jobs, **how)
                reference = reference or rows
                assert [r[1] for r in rows] == [r[1] for r in reference]
            close_clients()
        names = list(extractor.get_feature_names_out())
        X = np.array([[r[1][n] for n in names] for r in reference], dtype=float)
        y = np.array([r[1]["action"] for r in reference])
        folds = list(StratifiedKFold(5, shuffle=True, random_state=0).split(X, y))
        tasks = [(make_estimator("svm", names, seed=0, c=1.0), X[tr], y[tr], X[te])
                 for tr, te in folds]
        predicted = {}
        for name, how in executors(2).items():
            times["svm 5-fold", name, 2], predicted[name] = timed(f"svm {name}", _fit_predict,
                                                                  tasks, **how)
        assert all(np.array_equal(a, b) for a, b in zip(*predicted.values(), strict=True))
        close_clients()
    print(f"{args.sessions} feature jobs over {len(files)} sessions, {args.simulate} "
          f"simulated sessions; 2 workers unless stated")
    for step in ("features", "svm 5-fold"):
        local, dask = times[step, "local pool", 2], times[step, "dask", 2]
        print(f"{step:11s} local pool {local:7.2f} s   dask {dask:7.2f} s   "
              f"dask overhead {100 * (dask / local - 1):+5.1f} %")
    for step in ("simulate", "features"):
        for name in ("local pool", "dask"):
            one, two = times[step, name, 1], times[step, name, 2]
            print(f"{step:11s} {name:10s} 1 worker {one:7.2f} s   2 workers {two:7.2f} s   "
                  f"speed-up {one / two:4.2f}x")


if __name__ == "__main__":
    main()
