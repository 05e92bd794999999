"""A new classifier is one module and one registry line: a tiny kind registered here goes
through train, predict and replay without any change to those."""

from __future__ import annotations

import ast
import importlib.metadata
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from contactkit.classify.kinds import registry
from contactkit.classify.kinds.inputs import FEATURES
from contactkit.classify.kinds.kind import ModelKind, ModelOptions
from contactkit.classify.modelfile.model_file import load_model
from contactkit.classify.modelfile.skops_format import SKOPS
from contactkit.classify.prediction import predict_sources
from contactkit.classify.training import evaluate_kind, train
from contactkit.replay.session_replay import replay_session
from contactkit.schemas import InputError
from tests.conftest import make_dataset, run_cli
from tests.tiny_kind import TINY, _nearest_mean

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("tiny"), poses=("A", "B"), repeats=1)


@pytest.fixture
def tiny_kind():
    registry.register(TINY)
    yield TINY
    registry.unregister(TINY.name)


def test_a_registered_kind_trains_predicts_and_replays(dataset, tiny_kind, tmp_path) -> None:
    options = ModelOptions(kind="nearest-mean")
    trained = train([dataset], tmp_path / "tiny.skops", options)
    assert trained.kind == "nearest-mean" and trained.sessions == 8
    assert trained.classes == ["adjust", "bump", "none", "shove"]
    model = load_model(trained.path)
    assert model.kind is TINY and model.transformer().window == "planned"
    sessions = sorted(dataset.glob("*.parquet"))
    predictions, problems = predict_sources(model, sessions)
    assert not problems and len(predictions) == 8
    # the tiny model was fitted on these sessions: it reproduces most of their actions
    hits = sum(p.predicted == p.recorded for p in predictions)
    assert hits >= 6
    for p in predictions:
        assert sum(p.probabilities.values()) == pytest.approx(1.0)
    rrd = tmp_path / "tiny.rrd"
    summary = replay_session(sessions[0], model, save=rrd)
    assert summary.saved == rrd and rrd.stat().st_size > 10_000
    assert summary.offline.label == predictions[0].predicted
    assert len(summary.pred_t) > 10 and set(summary.pred_label) <= set(trained.classes)


def test_evaluate_takes_any_kind(dataset, tiny_kind) -> None:
    report, problems = evaluate_kind([dataset], ModelOptions(kind="nearest-mean"),
                                     protocol="group", group="pose")
    assert not problems and report.model == "nearest-mean"
    assert report.n_splits == 2 and report.n_sessions == 8
    assert 0.0 <= report.balanced_accuracy.value <= 1.0


def test_a_kind_from_an_entry_point(monkeypatch) -> None:
    point = importlib.metadata.EntryPoint(name="nearest-mean", group="contactkit.models",
                                          value=f"{__name__}:TINY")
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group: [point] if group == "contactkit.models" else [])
    registry.REGISTRY.refresh()
    try:
        assert "nearest-mean" in registry.kind_names()
        assert registry.get_kind("nearest-mean") is TINY
    finally:
        registry.unregister("nearest-mean")


def test_unknown_kind_and_model_file_of_a_missing_kind(dataset, tiny_kind, tmp_path) -> None:
    with pytest.raises(InputError, match="unknown model 'forest'"):
        registry.get_kind("forest")
    with pytest.raises(InputError, match="already registered"):
        registry.register(ModelKind("svm", "", FEATURES, _nearest_mean, SKOPS))
    path = train([dataset], tmp_path / "tiny.skops", ModelOptions(kind="nearest-mean")).path
    registry.unregister(TINY.name)
    with pytest.raises(InputError, match="is the package that provides it installed"):
        load_model(path)


def test_parameters_are_checked_where_they_are_declared(tiny_kind) -> None:
    checked = TINY.check_options(ModelOptions(kind="nearest-mean", params={"shrink": 1}))
    assert checked.params == {"shrink": 1.0}
    assert TINY.check_options(ModelOptions(kind="nearest-mean")).params == {"shrink": 0.0}
    cases = [("nearest-mean", {"shrink": 2.0}, r"shrink must be in \[0, 1\], got 2.0"),
             ("nearest-mean", {"c": 1.0}, "takes no parameter 'c'"),
             ("svm", {"c": 0.0}, "c must be positive, got 0.0"),
             ("lstm", {"dropout": 1.0}, r"dropout must be in \[0, 1\)"),
             ("lstm", {"device": "tpu"}, "device must be one of auto, cpu, cuda"),
             ("minirocket", {"epochs": 5}, "model 'minirocket' takes no parameter 'epochs'")]
    for kind, params, message in cases:
        with pytest.raises(InputError, match=message):
            registry.make_estimator(kind, [], **params)
    with pytest.raises(InputError, match="seed must be at least 0"):
        registry.make_estimator("svm", [], seed=-1)


def test_declarations_load_without_sklearn_or_torch() -> None:
    code = textwrap.dedent("""
        import sys
        from contactkit.classify.kinds import registry
        for name in registry.kind_names():
            registry.get_kind(name).params
        heavy = [m for m in ("sklearn", "torch", "skops", "aeon") if m in sys.modules]
        assert not heavy, heavy
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr


def test_a_kind_from_an_entry_point_through_the_command_line(dataset, tiny_kind, tmp_path,
                                                             monkeypatch) -> None:
    """One module (tests/tiny_kind.py) and one entry-point line: its parameter becomes
    an option of train, is checked where declared, and its model predicts."""
    site = tmp_path / "site"
    dist = site / "tinykind-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: tinykind\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[contactkit.models]\nnearest-mean = tests.tiny_kind:TINY\n")
    monkeypatch.setenv("PYTHONPATH", f"{site}:{ROOT}")
    helptext = " ".join(run_cli("classify", "train", "--help").stdout.split())
    assert "--shrink <float>" in helptext and "(models: nearest-mean)" in helptext
    out = tmp_path / "tiny.skops"
    trained = run_cli("classify", "train", str(dataset), "--model", "nearest-mean",
                      "--shrink", "0.25", "--out", str(out), "--workers", "1")
    assert trained.returncode == 0, trained.stderr
    meta = load_model(out).meta
    assert meta["kind"] == "nearest-mean"
    assert meta["training"]["options"]["params"] == {"shrink": 0.25}
    predicted = run_cli("classify", "predict", str(out), str(sorted(dataset.glob("*.parquet"))[0]),
                        "--json")
    assert predicted.returncode == 0, predicted.stderr
    line = json.loads(predicted.stdout.splitlines()[0])
    assert sum(line["probabilities"].values()) == pytest.approx(1.0, abs=1e-3)
    for args, message in ((["--shrink", "2"], r"shrink must be in [0, 1], got 2.0"),
                          (["--C", "1"], "--C is not an option of model 'nearest-mean' (it "
                                         "belongs to svm, per-joint, three-joint)")):
        bad = run_cli("classify", "train", str(dataset), "--model", "nearest-mean", *args,
                      "--out", str(tmp_path / "bad.skops"), "--workers", "1")
        assert bad.returncode == 2 and message in bad.stderr, bad.stderr
        assert bad.stderr.count("\n") == 1


def test_no_branch_on_a_kind_name_outside_its_module() -> None:
    """A kind's name appears, as a string, only in the module that declares it: nothing
    else in the library compares with it or picks it as a default."""
    from tests.suites.test_layering import all_modules, source_folders

    declared_in = {name: registry.get_kind(name).make.__module__
                   for name in registry.kind_names() if name != TINY.name}
    found = []
    for module, path in all_modules(source_folders()).items():
        tree = ast.parse(path.read_text(), filename=str(path))
        # a package's __all__ names its modules (classify.kinds has modules svm, minirocket)
        module_names = {id(c) for node in ast.walk(tree) if isinstance(node, ast.Assign)
                        and any(getattr(t, "id", None) == "__all__" for t in node.targets)
                        for c in ast.walk(node.value)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and node.value in declared_in and \
                    declared_in[node.value] != module and id(node) not in module_names:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.value!r}")
    assert found == [], "\n".join(found)
