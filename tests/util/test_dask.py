"""The executor seam on Dask distributed: a LocalCluster of 2 workers on 127.0.0.1
gives the same results, in the same order, as the local pool; a killed worker loses
nothing; an unreachable scheduler is a one-line ResourceError."""

from __future__ import annotations

import dataclasses
import functools
import os
import signal
import socket
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from sklearn.svm import SVC

from contactkit.errors import InputError, ResourceError
from contactkit.features.extract import SessionFeatures, _session_feature_row
from contactkit.recorder.sim.dataset import PRESETS, preset_specs, simulate_specs
from contactkit.recorder.sim.simulator import SimConfig
from contactkit.util import dask_executor
from contactkit.util.parallel import map_ordered, resolve_scheduler

pytest.importorskip("distributed")

CLUSTER = "local:2"


@pytest.fixture(scope="module")
def cluster():
    """A LocalCluster of 2 single-threaded workers on 127.0.0.1, shut down after."""
    yield dask_executor.get_client(CLUSTER)
    dask_executor.close_clients()


def _slow_square(x: int) -> int:
    time.sleep(0.05)
    return x * x


def _fit_predict(task: tuple) -> np.ndarray:
    estimator, X_train, y_train, X_test = task
    return estimator.fit(X_train, y_train).predict(X_test)


def test_scheduler_strings(monkeypatch):
    assert resolve_scheduler(None) is None
    assert resolve_scheduler("local") is None
    assert resolve_scheduler("local:3") == "local:3"
    assert resolve_scheduler("tcp://10.0.0.1:8786") == "tcp://10.0.0.1:8786"
    monkeypatch.setenv("CONTACTKIT_SCHEDULER", "local:2")
    assert resolve_scheduler(None) is None  # the library reads no environment
    for bad in ("local:0", "local:x", "http://host:1", "tcp://host"):
        with pytest.raises(InputError):
            resolve_scheduler(bad)


def test_same_results_order_and_progress(cluster):
    calls_local, calls_dask = [], []
    local = list(map_ordered(_slow_square, range(12), workers=1,
                             progress=lambda d, t: calls_local.append((d, t))))
    remote = list(map_ordered(_slow_square, range(12), scheduler=CLUSTER,
                              progress=lambda d, t: calls_dask.append((d, t))))
    assert remote == local == [x * x for x in range(12)]
    assert calls_dask == calls_local == [(d, 12) for d in range(1, 13)]


def _square(x: int) -> int:
    return x * x


def test_short_jobs_go_out_in_batches_in_order(cluster):
    assert dask_executor.batch_size(100, 2) == 6 and dask_executor.batch_size(12, 2) == 1
    assert dask_executor.batch_size(None, 2) == 1
    calls = []
    results = list(map_ordered(_square, range(100), scheduler=CLUSTER,
                               progress=lambda d, t: calls.append((d, t))))
    assert results == [x * x for x in range(100)]
    assert calls[-1] == (100, 100) and len(calls) == 17  # 16 batches of 6, one of 4
    assert [d for d, _ in calls] == sorted(d for d, _ in calls)


def test_simulate_identical(cluster, tmp_path):
    config = SimConfig(rate_hz=PRESETS["smoke"].rate_hz)
    specs = [dataclasses.replace(spec, duration_s=1.5, planned_at_s=0.5)
             for spec in preset_specs(PRESETS["smoke"], 2, seed=5)]
    batches = [specs[:1], specs[1:]]
    results = {}
    for name, scheduler in (("local", "local"), ("dask", CLUSTER)):
        out = tmp_path / name
        out.mkdir()
        job = functools.partial(simulate_specs, config=config, out_dir=str(out))
        results[name] = [Path(p) for paths in map_ordered(job, batches, scheduler=scheduler)
                         for p in paths]
    assert [p.name for p in results["local"]] == [p.name for p in results["dask"]]
    for a, b in zip(results["local"], results["dask"], strict=True):
        assert pq.read_table(a).equals(pq.read_table(b))


def test_features_and_svm_identical(cluster, tmp_path, session_path):
    bad = tmp_path / "broken.parquet"
    bad.write_bytes(b"not parquet")
    extractor = SessionFeatures()
    extractor.fit(None)
    params = extractor.get_params()
    jobs = [(str(p), params, None) for p in (session_path, bad, session_path)]
    local = list(map_ordered(_session_feature_row, jobs, workers=2))
    remote = list(map_ordered(_session_feature_row, jobs, scheduler=CLUSTER))
    assert [r[2] is None for r in remote] == [True, False, True]  # the bad file is data
    assert [r[0] for r in remote] == [r[0] for r in local]
    assert [r[2] for r in remote] == [r[2] for r in local]

    rng = np.random.default_rng(0)
    X, y = rng.normal(size=(60, 4)), np.repeat(["a", "b", "c"], 20)
    X[y == "b"] += 1.5
    folds = [(np.arange(60) % 5 != k, np.arange(60) % 5 == k) for k in range(5)]
    tasks = [(SVC(), X[tr], y[tr], X[te]) for tr, te in folds]
    local = list(map_ordered(_fit_predict, tasks))
    remote = list(map_ordered(_fit_predict, tasks, scheduler=CLUSTER))
    for a, b in zip(local, remote, strict=True):
        np.testing.assert_array_equal(a, b)


def test_killed_worker_loses_nothing(cluster):
    pids = list(cluster.run(os.getpid).values())
    assert len(pids) == 2
    killed = []

    def kill_one(done: int, total: int) -> None:
        if done >= 3 and not killed:  # progress counts items; batches of 2 here
            os.kill(pids[0], signal.SIGKILL)
            killed.append(pids[0])

    items = list(range(40))
    results = list(map_ordered(_slow_square, items, scheduler=CLUSTER, progress=kill_one))
    assert killed
    assert results == [x * x for x in items]


def test_unreachable_scheduler(monkeypatch):
    monkeypatch.setattr(dask_executor, "CONNECT_TIMEOUT_S", 2.0)
    with socket.socket() as probe:  # a port that nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    with pytest.raises(ResourceError) as caught:
        list(map_ordered(_slow_square, [1], scheduler=address))
    assert "cannot reach the Dask scheduler" in str(caught.value)
    assert "\n" not in str(caught.value)


def test_gridsearch_and_lstm_evaluate_identical(cluster, tmp_path, monkeypatch):
    """A 4-trial grid search and a small LSTM evaluation give the same reports on the
    cluster as on the local path."""
    pytest.importorskip("torch")
    from contactkit.classify.experiments.gridsearch import Protocol, grid_trials, run_trials
    from contactkit.classify.kinds.kind import ModelOptions
    from contactkit.classify.kinds.registry import get_kind
    from contactkit.classify.training import evaluate_kind
    from tests.conftest import make_dataset

    dataset = make_dataset(tmp_path, poses=("A", "B"), repeats=1)
    trials = grid_trials(get_kind("lstm"), {"depth": [1], "width": [0.5], "dropout": [0.0, 0.1]},
                         [20, 30], [("dq", "tau")])
    protocol = Protocol(model="lstm", params={"epochs": 2, "patience": 1})
    local = run_trials([dataset], trials, protocol, scheduler="local")
    remote = run_trials([dataset], trials, protocol, scheduler=CLUSTER)
    assert [r.trial for r in remote] == trials
    assert [r.report.as_dict() for r in remote] == [r.report.as_dict() for r in local]

    options = ModelOptions(kind="lstm", timeseries=("dq", "tau"), steps=20,
                           params={"epochs": 2, "depth": 1, "width": 0.5, "patience": 1})
    local_report, _ = evaluate_kind([dataset], options, workers=2)
    remote_report, _ = evaluate_kind([dataset], options, workers=2, scheduler=CLUSTER)
    assert remote_report.as_dict() == local_report.as_dict()


def test_scheduler_without_workers(monkeypatch):
    import distributed

    monkeypatch.setattr(dask_executor, "CONNECT_TIMEOUT_S", 2.0)
    with (distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp",
                                   host="127.0.0.1", dashboard_address=None) as empty,
          pytest.raises(ResourceError, match="has no worker")):
        list(map_ordered(_slow_square, [1], scheduler=empty.scheduler_address))


def test_cli_scheduler_option(tmp_path, session_path, monkeypatch):
    """--scheduler on the root of a command (or $CONTACTKIT_SCHEDULER, its default)
    sends its jobs to Dask; same table."""
    from tests.conftest import run_cli

    tables = {}
    for name, root in (("local", ()), ("dask", ("--scheduler", "local:1")), ("env", ())):
        if name == "env":
            monkeypatch.setenv("CONTACTKIT_SCHEDULER", "local:1")
        out = tmp_path / f"{name}.parquet"
        done = run_cli("classify", *root, "features", str(session_path), "--out", str(out),
                       "--workers", "1")
        assert done.returncode == 0, done.stderr
        tables[name] = pq.read_table(out)
    assert tables["dask"].equals(tables["local"]) and tables["env"].equals(tables["local"])
