"""Networks on window grids: CNN, LSTM, MiniRocket, ONNX export, and the nn extra."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from contactkit.classify.grids import GridSpec, load_grids, resample_window, window_grid
from contactkit.classify.kinds.networks import CNNClassifier, LSTMClassifier
from contactkit.classify.modelfile.model_file import load_model
from contactkit.features.observer import ObserverConfig
from contactkit.features.timeseries import ChainConfig, TimeseriesChain
from contactkit.schemas import read_session
from tests.conftest import make_dataset, run_command

torch = pytest.importorskip("torch")
SMALL = {"depth": 1, "width": 0.5, "epochs": 3, "patience": 2}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("nn"))


@pytest.fixture(scope="module")
def grids(dataset):
    return load_grids([dataset], GridSpec(steps=40))


def test_grid_shape_and_resampling(grids) -> None:
    assert grids.X.shape == (32, 21, 40)
    t = np.arange(0, 1, 0.01)
    values = np.column_stack([t, 2 * t])
    out = resample_window(t, values, 0.5, 0.2, 4)
    assert np.allclose(out, [[0.5, 0.55, 0.6, 0.65], [1.0, 1.1, 1.2, 1.3]])


def test_grid_is_relative_to_the_pre_window_mean() -> None:
    t = np.arange(0, 1, 0.01)
    ramp = np.where(t < 0.5, 0.0, t - 0.5)
    values = np.column_stack([ramp + 3.0, ramp - 40.0])
    spec = GridSpec(window_s=0.2, steps=4, baseline_s=0.1)
    out = window_grid(t, values, 0.5, spec)
    assert np.allclose(out, [[0.0, 0.05, 0.1, 0.15]] * 2)
    absolute = window_grid(t, values, 0.5, GridSpec(window_s=0.2, steps=4, baseline_s=0.0))
    assert np.allclose(absolute, resample_window(t, values, 0.5, 0.2, 4))
    at_start = window_grid(t, values, 0.0, spec)
    assert np.allclose(at_start, 0.0)


@pytest.mark.parametrize("cls", [CNNClassifier, LSTMClassifier])
def test_same_seed_same_network(grids, cls) -> None:
    y = grids.labels()
    a = cls(seed=3, **SMALL).fit(grids.X, y).predict_proba(grids.X)
    b = cls(seed=3, **SMALL).fit(grids.X, y).predict_proba(grids.X)
    assert np.array_equal(a, b)
    assert np.allclose(a.sum(axis=1), 1.0, atol=1e-5)


def test_onnx_model_file_round_trip_and_refusal(dataset: Path, tmp_path: Path) -> None:
    model = tmp_path / "cnn.onnx"
    trained = run_command("classify", "train", str(dataset), "--model", "cnn", "--epochs", "2",
                          "--steps", "40", "--out", str(model), "--workers", "1", "--depth", "1",
                          "--width", "0.5")
    assert trained.returncode == 0, trained.stderr
    options = load_model(model).meta["training"]["options"]
    assert options["params"]["depth"] == 1 and options["params"]["width"] == 0.5
    bad = run_command("classify", "train", str(dataset), "--model", "cnn", "--depth", "0",
                      "--out", str(tmp_path / "bad.onnx"))
    assert bad.returncode == 2 and "depth must be at least 1" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1
    session = sorted(dataset.glob("static_*.parquet"))[0]
    predicted = run_command("classify", "predict", str(model), str(session), "--json")
    assert predicted.returncode == 0, predicted.stderr
    import json

    line = json.loads(predicted.stdout.splitlines()[0])
    # --json rounds each probability to 4 decimals: the sum is 1 to within 0.5e-4 per class
    probabilities = line["probabilities"].values()
    assert sum(probabilities) == pytest.approx(1.0, abs=0.5e-4 * len(probabilities))
    import onnx

    graph = onnx.load(str(model))
    graph.graph.initializer[0].raw_data = bytes(len(graph.graph.initializer[0].raw_data))
    tampered = tmp_path / "tampered.onnx"
    onnx.save(graph, str(tampered))
    refused = run_command("classify", "predict", str(tampered), str(session))
    assert refused.returncode == 2 and "modified after it was written" in refused.stderr


def test_parallel_splits_give_the_same_report(grids) -> None:
    from contactkit.classify.evaluate import evaluate

    def run(workers: int):
        return evaluate(grids.X, grids.labels(), lambda: LSTMClassifier(seed=2, **SMALL),
                        protocol="group", model="lstm", groups=grids.groups("pose"),
                        workers=workers)

    serial, parallel = run(1), run(2)
    assert serial.confusion_counts == parallel.confusion_counts
    assert serial.balanced_accuracy == parallel.balanced_accuracy


def test_onnx_equals_torch(grids, tmp_path: Path) -> None:
    import onnxruntime as ort

    net = LSTMClassifier(seed=1, **SMALL).fit(grids.X, grids.labels())
    path = tmp_path / "l.onnx"
    net.export_onnx(path, grids.X.shape[1], grids.X.shape[2])
    session = ort.InferenceSession(str(path))
    out = session.run(None, {"grid": grids.X.astype(np.float32)})[0]
    assert np.abs(out - net.predict_proba(grids.X)).max() < 1e-5


def test_group_protocol_and_minirocket(dataset: Path, tmp_path: Path) -> None:
    result = run_command("classify", "evaluate", str(dataset), "--model", "lstm", "--epochs",
                         "2", "--steps", "30", "--protocol", "group", "--group", "pose",
                         "--workers", "1")
    assert result.returncode == 0, result.stderr
    assert "balanced accuracy" in result.stdout and "4 splits" in result.stdout
    model = tmp_path / "mr.skops"
    trained = run_command("classify", "train", str(dataset), "--model", "minirocket", "--steps",
                          "30", "--out", str(model), "--workers", "1")
    assert trained.returncode == 0, trained.stderr
    session = sorted(dataset.glob("static_*.parquet"))[0]
    assert run_command("classify", "predict", str(model), str(session)).returncode == 0


def test_without_torch_a_network_gives_one_line(dataset: Path, tmp_path: Path) -> None:
    code = ("import sys, importlib.abc\n"
            "class NoTorch(importlib.abc.MetaPathFinder):\n"
            "    def find_spec(self, name, path, target=None):\n"
            "        if name.split('.')[0] == 'torch':\n"
            "            raise ImportError('No module named torch')\n"
            "sys.meta_path.insert(0, NoTorch())\n"
            "from contactkit.cli.classify import main\n"
            f"sys.argv = ['classify', 'train', {str(dataset)!r}, '--model', 'cnn', '--out', "
            f"{str(tmp_path / 'x.onnx')!r}, '--workers', '1', '--steps', '20']\n"
            "main()\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 2
    assert "pip install 'contactkit[nn]'" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_replay_with_an_onnx_network(dataset: Path, tmp_path: Path) -> None:
    import rerun.chunk as rc

    model = tmp_path / "lstm.onnx"
    trained = run_command("classify", "train", str(dataset), "--model", "lstm", "--epochs", "2",
                          "--steps", "30", "--out", str(model), "--workers", "1")
    assert trained.returncode == 0, trained.stderr
    session = sorted(dataset.glob("static_*.parquet"))[0]
    rrd = tmp_path / "r.rrd"
    result = run_command("replay", str(session), "--model", str(model), "--viewer", "none",
                         "--save", str(rrd))
    assert result.returncode == 0, result.stderr
    rows = [c.to_record_batch() for c in rc.RrdReader(rrd).stream()
            if c.entity_path == "/classifier/probability" and not c.is_static]
    proba = np.array([v for b in rows for v in b.column("Scalars:scalars").to_pylist()])
    assert len(proba) > 10 and np.allclose(proba.sum(axis=1), 1.0, atol=1e-4)
    t_pred = np.concatenate([b.column("time").cast("int64").to_numpy() for b in rows]) / 1e9
    order = np.argsort(t_pred, kind="stable")
    t_pred, proba = t_pred[order], proba[order]
    s = read_session(session)
    spec = load_model(model).transformer().spec
    net = load_model(model).estimator
    for k in (0, len(t_pred) // 2, len(t_pred) - 1):
        past = slice(0, int(np.searchsorted(s.t, t_pred[k] + 1e-9)))
        chain = TimeseriesChain(ChainConfig(ObserverConfig(gain=spec.gain))).compute(
            s.t[past], s.q[past], s.dq[past], s.tau[past], list(spec.timeseries))
        values = np.column_stack([chain[n] for n in spec.timeseries])
        grid = window_grid(s.t[past], values, s.t[past][-1] - spec.window_s, spec)
        assert np.allclose(proba[k], net.predict_proba(grid[None])[0], atol=1e-5)


def test_augmentation_experiment_end_to_end(tmp_path: Path) -> None:
    for preset, directory in (("aug-real", "real"), ("aug-sim", "sim")):
        made = run_command("recorder", "simulate", str(tmp_path / directory), "--preset", preset,
                           "--sessions", "16", "--rate", "200", "--workers", "1")
        assert made.returncode == 0, made.stderr
    import json

    from contactkit.schemas import read_session

    sim_links = {read_session(p).meta.link for p in (tmp_path / "sim").glob("static_*.parquet")}
    assert sim_links <= {None, 5, 6, 7}
    result = run_command("classify", "experiment", "augmentation", str(tmp_path / "real"),
                         str(tmp_path / "sim"), "--out", str(tmp_path / "out"), "--model", "lstm",
                         "--repeats", "2", "--epochs", "2", "--steps", "30", "--workers", "1")
    assert result.returncode == 0, result.stderr
    doc = json.loads((tmp_path / "out" / "augmentation.json").read_text())
    cells = {(c["fraction"], c["condition"]) for c in doc["cells"]}
    assert len(cells) == 18 and (0.5, "noise x10") in cells
    assert all(len(c["balanced_accuracy"]) == 2 for c in doc["cells"])
    assert (tmp_path / "out" / "augmentation.png").stat().st_size > 10_000
    bad = run_command("classify", "experiment", "augmentation", str(tmp_path / "real"), "--out",
                      str(tmp_path / "x"))
    assert bad.returncode == 2 and "REAL_DIR SIM_DIR" in bad.stderr
