"""The classify command line: train, evaluate, predict and every experiment."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.conftest import make_dataset, run_cli


@pytest.fixture(scope="module")
def static(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("static"))


@pytest.fixture(scope="module")
def dynamic(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("dynamic"), poses=("C", "E"), repeats=3,
                        rate_hz=200.0, condition="dynamic")


def test_train_evaluate_predict(static: Path, tmp_path: Path) -> None:
    model = tmp_path / "model.skops"
    trained = run_cli("classify", "train", str(static), "--out", str(model), "--model",
                      "three-joint", "--workers", "1")
    assert trained.returncode == 0, trained.stderr
    report = run_cli("classify", "evaluate", str(static), "--protocol", "group", "--group",
                     "pose", "--json", str(tmp_path / "r.json"), "--workers", "1")
    assert report.returncode == 0, report.stderr
    assert "balanced accuracy" in report.stdout and "recall shove" in report.stdout
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["n_splits"] == 4 and doc["group_by"] == "pose"
    thesis = run_cli("classify", "evaluate", str(static), "--protocol", "thesis", "--scheme",
                     "contact", "--workers", "1")
    assert thesis.returncode == 0 and "25 random 80/20 splits" in thesis.stdout
    session = sorted(static.glob("*.parquet"))[0]
    predicted = run_cli("classify", "predict", str(model), str(session), "--json")
    assert predicted.returncode == 0, predicted.stderr
    line = json.loads(predicted.stdout.splitlines()[0])
    assert line["predicted"] in {"none", "bump", "adjust", "shove"}
    assert sum(line["probabilities"].values()) == pytest.approx(1.0, abs=1e-3)
    features = tmp_path / "wide.parquet"
    run_cli("classify", "features", str(static), "--out", str(features), "--scalars", "mean")
    refused = run_cli("classify", "predict", str(model), str(features))
    assert refused.returncode == 2 and "other features" in refused.stderr


def test_bad_input(static: Path, tmp_path: Path) -> None:
    cases = [
        (["evaluate", str(static), "--protocol", "vibes"], "'vibes' is not one of 'thesis'"),
        (["evaluate", str(static), "--group", "colour"], "'colour' is not one of 'pose'"),
        (["train", str(static), "--out", str(tmp_path / "m"), "--model", "forest"],
         "'forest' is not one of 'svm'"),
        (["evaluate", str(tmp_path / "missing")], "no such dataset"),
        (["predict", str(tmp_path / "nope.skops"), str(static)], "no such model file"),
    ]
    for args, message in cases:
        result = run_cli("classify", *args, "--workers", "1") if args[0] != "predict" else \
            run_cli("classify", *args)
        assert result.returncode == 2, (args, result.stderr)
        assert message in result.stderr and "Traceback" not in result.stderr


@pytest.mark.parametrize("name", ["features", "rfe", "window"])
def test_experiments_write_table_json_and_plot(static: Path, tmp_path: Path, name: str) -> None:
    result = run_cli("classify", "experiment", name, str(static), "--out", str(tmp_path),
                     "--workers", "2")
    assert result.returncode == 0, result.stderr
    for ext in ("md", "json", "png"):
        assert (tmp_path / f"{name}.{ext}").stat().st_size > 100
    doc = json.loads((tmp_path / f"{name}.json").read_text())
    assert doc["rows"] and "balanced_accuracy" in doc["rows"][0]["report"]


def test_speed_experiment(static: Path, dynamic: Path, tmp_path: Path) -> None:
    result = run_cli("classify", "experiment", "speed", str(static), str(dynamic), "--out",
                     str(tmp_path), "--group", "session", "--workers", "2")
    assert result.returncode == 0, result.stderr
    table = (tmp_path / "speed.md").read_text()
    assert "at or below + static" in table
