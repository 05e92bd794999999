"""The classify command line: train, evaluate, predict and every experiment."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from contactkit.classify.data import load_features
from contactkit.classify.evaluate import evaluate
from contactkit.classify.kinds.svm_estimators import svm_pipeline
from contactkit.classify.schemes import scheme_classes
from contactkit.features.extract import SessionFeatures
from tests.conftest import make_dataset, make_session, run_command


@pytest.fixture(scope="module")
def static(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("static"))


@pytest.fixture(scope="module")
def dynamic(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("dynamic"), poses=("C", "E"), repeats=3,
                        rate_hz=200.0, condition="dynamic")


def test_train_evaluate_predict(static: Path, tmp_path: Path) -> None:
    model = tmp_path / "model.skops"
    trained = run_command("classify", "train", str(static), "--out", str(model), "--model",
                          "three-joint", "--workers", "1")
    assert trained.returncode == 0, trained.stderr
    report = run_command("classify", "evaluate", str(static), "--protocol", "group", "--group",
                         "pose", "--json", str(tmp_path / "r.json"), "--workers", "1")
    assert report.returncode == 0, report.stderr
    assert "balanced accuracy" in report.stdout and "recall shove" in report.stdout
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["n_splits"] == 4 and doc["group_by"] == "pose"
    thesis = run_command("classify", "evaluate", str(static), "--protocol", "thesis", "--scheme",
                         "contact", "--workers", "1")
    assert thesis.returncode == 0 and "25 random 80/20 splits" in thesis.stdout
    session = sorted(static.glob("*.parquet"))[0]
    predicted = run_command("classify", "predict", str(model), str(session), "--json")
    assert predicted.returncode == 0, predicted.stderr
    line = json.loads(predicted.stdout.splitlines()[0])
    assert line["predicted"] in {"none", "bump", "adjust", "shove"}
    assert sum(line["probabilities"].values()) == pytest.approx(1.0, abs=1e-3)
    features = tmp_path / "wide.parquet"
    made = run_command("classify", "features", str(static), "--out", str(features), "--scalars",
                       "mean")
    assert made.returncode == 0, made.stderr
    refused = run_command("classify", "predict", str(model), str(features))
    assert refused.returncode == 2 and "other features" in refused.stderr


def test_a_model_says_when_a_session_comes_from_an_arm_it_was_not_trained_on(
        static: Path, tmp_path: Path) -> None:
    """A model file lists the arms of its training sessions; predicting or replaying a
    session of another arm warns once, naming the session and both arms, and goes on
    (its features come from that arm's own model)."""
    from contactkit.classify.modelfile.model_file import load_model

    model = tmp_path / "model.skops"
    trained = run_command("classify", "train", str(static), "--out", str(model), "--model",
                          "three-joint", "--workers", "1")
    assert trained.returncode == 0, trained.stderr
    assert load_model(model).trained_robots == ["panda"]
    fr3 = make_session(tmp_path, seed=5, action="bump", link=5, robot="fr3", duration_s=2.0,
                       planned_at_s=1.0, rate_hz=200.0)
    panda = sorted(static.glob("*.parquet"))[0]
    for command in (["classify", "predict", str(model)],
                    ["replay", "--viewer", "none", "--save", str(tmp_path / "r.rrd"),
                     "--overwrite", "--model", str(model)]):
        warned = run_command(*command, str(fr3), str(panda))
        assert warned.returncode == 0, warned.stderr
        text = " ".join(warned.stderr.split())
        assert text.count("the model was trained on panda sessions only") == 1, text
        assert f"{fr3.name}: the model was trained on panda sessions only, this session's " \
               "arm is fr3" in text
        quiet = run_command(*command, str(panda))
        assert "trained on" not in quiet.stderr, quiet.stderr


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
        result = run_command("classify", *args, "--workers", "1") if args[0] != "predict" else \
            run_command("classify", *args)
        assert result.returncode == 2, (args, result.stderr)
        assert message in result.stderr and "Traceback" not in result.stderr


@pytest.mark.parametrize("name", ["features", "rfe", "window"])
def test_experiments_write_table_json_and_plot(static: Path, tmp_path: Path, name: str) -> None:
    result = run_command("classify", "experiment", name, str(static), "--out", str(tmp_path),
                         "--workers", "2")
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == [str(tmp_path / f"{name}.{ext}")
                                     for ext in ("md", "json", "png")]
    doc = json.loads((tmp_path / f"{name}.json").read_text())
    assert doc["experiment"] == name and doc["setting"]["c"] == 10.0
    table = (tmp_path / f"{name}.md").read_text()
    rows = doc["rows"]
    assert rows and len([line for line in table.splitlines() if line.startswith("| ")]) == \
        len(rows) + 1
    for row in rows:
        report = row["report"]
        assert report["n_sessions"] == 32 and report["n_splits"] == 4
        assert report["group_by"] == "pose" and report["classes"] == ["none", "bump",
                                                                      "adjust", "shove"]
        for key in ("accuracy", "balanced_accuracy", "macro_f1"):
            value = report[key]
            assert 0.0 <= value["low"] <= value["value"] <= value["high"] <= 1.0
        ba = report["balanced_accuracy"]
        assert (f"| {row['label']} | {row['detail']} | 32 | " in table
                and f"{100 * ba['value']:.1f} % [{100 * ba['low']:.1f}, "
                    f"{100 * ba['high']:.1f}]" in table)
        assert sum(map(sum, report["confusion_counts"])) == 32
    png = (tmp_path / f"{name}.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 10_000
    if name == "window":
        assert [r["label"] for r in rows] == ["0.1 s", "0.2 s", "0.3 s", "0.5 s"]
        data = load_features([static], SessionFeatures(window="difference", window_s=0.5))
        expected = evaluate(data.X, data.labels(), lambda: svm_pipeline(10.0,
                                                                         probability=False),
                            protocol="group", model="svm", groups=data.groups("pose"),
                            group_by="pose", classes=scheme_classes("full"))
        assert rows[-1]["report"]["balanced_accuracy"]["value"] == \
            pytest.approx(expected.balanced_accuracy.value, abs=1e-12)
        assert rows[-1]["report"]["confusion_counts"] == expected.confusion_counts
    if name == "rfe":
        assert doc["chosen"] and all("(" in feature for feature in doc["chosen"])


def test_an_experiment_never_replaces_a_users_file_of_its_names(static: Path,
                                                                 tmp_path: Path) -> None:
    """window.md is a fixed name: a user's own Markdown there (it starts with '# ' as
    the tool's results do) is refused, not replaced."""
    notes = tmp_path / "window.md"
    notes.write_text("# My notes\n\nprecious\n")
    result = run_command("classify", "experiment", "window", str(static), "--out",
                         str(tmp_path), "--workers", "2")
    assert result.returncode == 2 and "not a file contactkit wrote" in result.stderr
    assert "Traceback" not in result.stderr
    assert notes.read_text() == "# My notes\n\nprecious\n"
    notes.unlink()
    for _ in range(2):  # a re-run replaces its own results (the .json was refused)
        result = run_command("classify", "experiment", "window", str(static), "--out",
                             str(tmp_path), "--workers", "2")
        assert result.returncode == 0, result.stderr


def test_speed_experiment(static: Path, dynamic: Path, tmp_path: Path) -> None:
    result = run_command("classify", "experiment", "speed", str(static), str(dynamic), "--out",
                         str(tmp_path), "--group", "session", "--workers", "2")
    assert result.returncode == 0, result.stderr
    table = (tmp_path / "speed.md").read_text()
    assert "at or below + static" in table
