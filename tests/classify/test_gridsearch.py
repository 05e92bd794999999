"""The network grid search, the training device, and the network code on its own."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from contactkit.classify.experiments.gridsearch import (
    Protocol,
    best_trial,
    grid_trials,
    run_trials,
    write_results,
)
from contactkit.classify.kinds.networks import CNNClassifier, LSTMClassifier, resolve_device
from contactkit.classify.kinds.registry import get_kind
from contactkit.classify.training import training_set
from contactkit.schemas import InputError
from tests.conftest import make_dataset, run_command

torch = pytest.importorskip("torch")

ROOT = Path(__file__).resolve().parents[2]
TINY = Protocol(model="lstm", params={"epochs": 2, "patience": 1})
LSTM = get_kind("lstm")
NO_CUDA = "no CUDA GPU visible to PyTorch (the nn extra installs the CPU build)"


def tiny_trials():
    """Four trials: two dropouts x two step counts of a depth-1, half-width LSTM."""
    return grid_trials(LSTM, {"depth": [1], "width": [0.5], "dropout": [0.0, 0.1]}, [20, 30],
                       [("dq", "tau")])


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("grid"), poses=("A", "B"), repeats=1)


def test_grid_trials_and_checks() -> None:
    trials = tiny_trials()
    assert len(trials) == 4
    assert trials[0].label() == "depth=1 width=0.5 dropout=0 steps=20 dq+tau"
    assert len(grid_trials(LSTM, {}, [300], [("q",)])) == 27  # the declared thesis grid
    for bad in ({"depth": [0]}, {"width": [0]}, {"dropout": [1.0]}, {"steps": [2]},
                {"inputs": []}, {"epochs": [3]}, {"depth": []}):
        grid = {"depth": [1], "width": [1], "dropout": [0]}
        grid |= {k: v for k, v in bad.items() if k not in ("steps", "inputs")}
        with pytest.raises(InputError):
            grid_trials(LSTM, grid, bad.get("steps", [20]), bad.get("inputs", [("q",)]))
    with pytest.raises(InputError, match="cnn or lstm"):
        run_trials([], trials, Protocol(model="svm"))
    with pytest.raises(InputError, match="unknown timeseries feature 'no_such'"):
        run_trials([], grid_trials(LSTM, {"depth": [1], "width": [1], "dropout": [0]}, [20],
                                   [("no_such",)]), TINY)
    with pytest.raises(InputError, match="no such dataset directory"):
        run_trials([Path("no/such/dataset")], trials, TINY)  # once, before any trial


def test_gridsearch_table(dataset: Path, tmp_path: Path) -> None:
    calls = []
    results = run_trials([dataset], tiny_trials(), TINY,
                         progress=lambda label, d, t: calls.append((label, d, t)))
    assert [r.trial for r in results] == tiny_trials()
    assert all(r.report is not None for r in results)
    assert ("trials", 4, 4) in calls
    md, js = write_results(tmp_path, results, TINY)
    rows = [line for line in md.read_text().splitlines() if line[:3] in {f"| {k}" for k in "1234"}]
    assert len(rows) == 4 and " % [" in rows[0]
    doc = json.loads(js.read_text())
    assert len(doc["trials"]) == 4 and doc["protocol"]["model"] == "lstm"
    assert {"value", "low", "high"} <= set(doc["trials"][0]["report"]["balanced_accuracy"])
    assert best_trial(results) in tiny_trials()


def test_failed_trials_are_data(dataset: Path) -> None:
    def grids(options):
        if options.steps == 30:
            raise InputError("no session could be processed")
        return training_set([dataset], options).data

    results = run_trials([dataset], tiny_trials()[:3], TINY, grids=grids)
    assert [r.report is None for r in results] == [False, False, True]
    assert "no session could be processed" in results[2].problem
    with pytest.raises(InputError, match="every trial"):
        best_trial(results[2:])


def test_gridsearch_command(dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "grid"
    done = run_command("classify", "gridsearch", str(dataset), "--out", str(out), "--depths", "1",
                       "--widths", "0.5", "--dropouts", "0,0.1", "--steps", "20",
                       "--inputs", "dq,tau", "--epochs", "2", "--patience", "1", "--workers", "1",
                       "--device", "auto")
    assert done.returncode == 0, done.stderr
    assert "| 2 | 1 | 0.5 |" in done.stdout
    assert {p.name for p in out.iterdir()} == {"gridsearch.md", "gridsearch.json", "best.onnx"}
    predicted = run_command("classify", "predict", str(out / "best.onnx"),
                            str(next(dataset.glob("*.parquet"))))
    assert predicted.returncode == 0, predicted.stderr
    again = run_command("classify", "gridsearch", str(dataset), "--out", str(out))
    assert again.returncode == 2 and "already exists" in again.stderr
    bad_value = run_command("classify", "gridsearch", str(dataset), "--out", str(tmp_path / "x"),
                            "--depths", "x")
    bad_scheduler = run_command("classify", "--scheduler", "tcp://nohost", "gridsearch",
                                str(dataset), "--out", str(tmp_path / "x"))
    for bad in (bad_value, bad_scheduler):
        assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
    assert "--depths" in bad_value.stderr and "scheduler" in bad_scheduler.stderr


def _windows(n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    y = np.repeat(["a", "b"], n // 2)
    X = rng.normal(size=(n, 3, 16)).astype(np.float32)
    X[y == "b", 0] += 1.0
    return X, y


@pytest.mark.parametrize("network", [LSTMClassifier, CNNClassifier])
def test_cpu_training_repeatable(network) -> None:
    X, y = _windows()
    a = network(depth=1, width=0.5, epochs=2, seed=3, device="cpu").fit(X, y)
    b = network(depth=1, width=0.5, epochs=2, seed=3, device="cpu").fit(X, y)
    np.testing.assert_array_equal(a.predict_proba(X), b.predict_proba(X))
    assert next(a.model_.parameters()).device.type == "cpu"


def test_device_names() -> None:
    assert resolve_device(torch, "cpu").type == "cpu"
    assert resolve_device(torch, "auto").type == ("cuda" if torch.cuda.is_available()
                                                  else "cpu")
    with pytest.raises(InputError, match="unknown device"):
        resolve_device(torch, "tpu")


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA GPU")
def test_cuda_without_gpu_is_one_line(dataset: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="sees no CUDA GPU"):
        resolve_device(torch, "cuda")
    done = run_command("classify", "train", str(dataset), "--model", "lstm", "--device", "cuda",
                       "--out", str(tmp_path / "m.onnx"))
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert "no CUDA GPU" in done.stderr


@pytest.mark.skipif(not torch.cuda.is_available(), reason=NO_CUDA)
def test_cuda_training_returns_a_cpu_network() -> None:
    X, y = _windows()
    network = LSTMClassifier(depth=1, width=0.5, epochs=2, seed=3, device="cuda").fit(X, y)
    assert next(network.model_.parameters()).device.type == "cpu"
    cpu = LSTMClassifier(depth=1, width=0.5, epochs=2, seed=3, device="cpu").fit(X, y)
    assert np.abs(network.predict_proba(X) - cpu.predict_proba(X)).max() < 0.2


def test_bench_gpu_runs_without_the_chain() -> None:
    """The GPU check imports only the network code: pinocchio, rerun, polars, skops,
    aeon, dask and the robot libraries blocked, it still trains on the CPU."""
    blocked = ["pinocchio", "rerun", "polars", "skops", "aeon", "dask", "distributed",
               "rosbags", "can", "pyarrow"]
    code = ("import runpy, sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            f"        if name.split('.')[0] in {blocked!r}:\n"
            "            raise ImportError(f'{name} is not installed here')\n"
            "sys.meta_path.insert(0, Block())\n"
            "sys.argv = ['bench_gpu.py', '--device', 'cpu', '--windows', '48', '--steps',"
            " '16', '--epochs', '1', '--models', 'lstm']\n"
            "runpy.run_path('benchmarks/bench_gpu.py', run_name='__main__')\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "cpu bit-repeatable: yes" in done.stdout
    assert "GPU part skipped: --device cpu" in done.stdout
