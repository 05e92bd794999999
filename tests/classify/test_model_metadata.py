"""Model files whose metadata was rewritten and re-sealed (the digest recomputed, as
anyone can): each malformed or inconsistent document is one line naming the model file,
exit code 2, no traceback, from both ``classify predict`` and ``replay --model``."""

from __future__ import annotations

import copy
import hashlib
import json
import math
import zipfile
from collections.abc import Callable
from pathlib import Path

import pytest

from contactkit.classify.modelfile.model_file import load_model
from contactkit.schemas import InputError
from tests.conftest import make_session, run_command, save_quick_model

META = "contactkit.json"


def reseal(source: Path, target: Path, change: Callable[[dict], object]) -> Path:
    """Copy the skops model file ``source`` to ``target`` with its metadata changed in
    place by ``change`` and its digest recomputed as an attacker would: SHA-256 over
    every other member (name, NUL, bytes, NUL, in name order), then over the metadata as
    canonical JSON without the digest."""
    with zipfile.ZipFile(source) as archive:
        members = {n: archive.read(n) for n in archive.namelist()}
    meta = json.loads(members.pop(META))
    change(meta)
    meta.pop("members_sha256", None)
    digest = hashlib.sha256()
    for name in sorted(members):
        digest.update(name.encode() + b"\0" + members[name] + b"\0")
    digest.update(META.encode() + b"\0" + json.dumps(meta, sort_keys=True).encode() + b"\0")
    meta["members_sha256"] = digest.hexdigest()
    with zipfile.ZipFile(target, "w") as out:
        for name, data in members.items():
            out.writestr(name, data)
        out.writestr(META, json.dumps(meta))
    return target


def _set(*keys, value):
    def change(meta: dict) -> None:
        doc = meta
        for key in keys[:-1]:
            doc = doc[key]
        doc[keys[-1]] = value
    return change


def _drop(*keys):
    def change(meta: dict) -> None:
        doc = meta
        for key in keys[:-1]:
            doc = doc[key]
        del doc[keys[-1]]
    return change


FEATURE_CASES = {
    "features-list": _set("features", value=["range"]),
    "features-missing": _drop("features"),
    "features-null": _set("features", value=None),
    "window_s-string": _set("features", "window_s", value="x"),
    "window_s-negative": _set("features", "window_s", value=-0.5),
    "window_s-zero": _set("features", "window_s", value=0),
    "window_s-nan": _set("features", "window_s", value=math.nan),
    "window_s-inf": _set("features", "window_s", value=math.inf),
    "window_s-bool": _set("features", "window_s", value=True),
    "shift_s-string": _set("features", "shift_s", value="x"),
    "window_s-huge": _set("features", "window_s", value=1e300),
    "shift_s-huge": _set("features", "shift_s", value=-1e300),
    "unknown-scalar": _set("features", "scalars", value=["bogus"]),
    "scalars-string": _set("features", "scalars", value="range"),
    "scalars-empty": _set("features", "scalars", value=[]),
    "unknown-timeseries": _set("features", "timeseries", value=["bogus"]),
    "timeseries-string": _set("features", "timeseries", value="dq"),
    "timeseries-numbers": _set("features", "timeseries", value=[1, 2]),
    "unknown-setting": _set("features", "bogus", value=1),
    "window-method": _set("features", "window", value="bogus"),
    "window-method-list": _set("features", "window", value=["planned"]),
    "signal": _set("features", "signal", value=7),
    "calibration": _set("features", "calibration", value="bogus"),
    "fft_k-string": _set("features", "fft_k", value="3"),
    "fft_k-zero": _set("features", "fft_k", value=0),
    "gain-string": _set("features", "gain", value="fast"),
    "gain-negative": _set("features", "gain", value=-5.0),
    "friction-string": _set("features", "friction", value="yes"),
    "wrench-frame": _set("features", "wrench_frame", value=99),
    "robot-unknown": _set("features", "robot", value="bogus"),
    "robot-number": _set("features", "robot", value=3),
    "robot-dev-zero": _set("features", "robot", value="urdf:/dev/zero"),
    "robot-directory": _set("features", "robot", value="urdf:/"),
}
OTHER_CASES = {
    "classes-numbers": _set("classes", value=[1, 2, 3, 4]),
    "classes-empty": _set("classes", value=[]),
    "classes-string": _set("classes", value="none,bump,adjust,shove"),
    "classes-repeated": _set("classes", value=["none", "none", "bump", "shove"]),
    "classes-missing": _drop("classes"),
    "classes-too-few": _set("classes", value=["none", "bump"]),
    "classes-reversed": lambda meta: meta["classes"].reverse(),
    "feature_names-string": _set("feature_names", value="range(dq_1)"),
    "feature_names-numbers": _set("feature_names", value=list(range(21))),
    "feature_names-other": lambda meta: meta["feature_names"].reverse(),
    "feature_names-short": lambda meta: meta["feature_names"].pop(),
    "kind-number": _set("kind", value=3),
    "input-wrong": _set("input", value="grid"),
    "detector-list": _set("detector", value=[1, 2]),
    "detector-bad-setting": _set("detector", value={"format": "bogus"}),
    "scheme-number": _set("scheme", value=3),
}
EVENT_CASES = {
    "events-list": _set("events", value=[1]),
    "events-classes-numbers": _set("events", "classes", value=[1, 2]),
    "events-classes-missing": _drop("events", "classes"),
    "events-decide-string": _set("events", "decide_after_s", value="x"),
    "events-decide-negative": _set("events", "decide_after_s", value=-1.0),
    "events-decide-missing": _drop("events", "decide_after_s"),
    "events-features-other": _set("events", "features", value=["a"]),
    "events-low-short": _set("events", "low", value=[0.0]),
    "events-low-strings": lambda meta: meta["events"].__setitem__(
        "low", ["x"] * len(meta["events"]["low"])),
    "events-high-missing": _drop("events", "high"),
    "events-weak-list": _set("events", "weak", value=[3.0, 0.35]),
    "events-weak-negative": _set("events", "weak", value={"score": -1.0,
                                                          "decide_after_s": 0.35}),
    "events-weak-late": _set("events", "weak", value={"score": 3.0, "decide_after_s": 60.0}),
    "events-weak-string": _set("events", "weak", value={"score": "x",
                                                        "decide_after_s": 0.35}),
    "events-weak-missing-delay": _set("events", "weak", value={"score": 3.0}),
    "detector-string": _set("detector", value="default"),
}


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> dict[str, Path]:
    """One quick model, one with a detector and event classifier, and a session."""
    root = tmp_path_factory.mktemp("models")
    return {"plain": save_quick_model(root / "plain.skops"),
            "events": save_quick_model(root / "events.skops", events=True),
            "session": make_session(root, duration_s=2.0, rate_hz=250.0)}


def _one_line(result, name: str) -> None:
    text = result.stdout + result.stderr
    assert result.returncode == 2, text
    assert "Traceback" not in text, text
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, text
    assert name in lines[0], text


def _check_both(model: Path, session: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError) as caught:
        load_model(model, lazy=True)
    assert model.name in str(caught.value) and "\n" not in str(caught.value)
    with pytest.raises(InputError, match=model.name):
        load_model(model)
    _one_line(run_command("classify", "predict", str(model), str(session)), model.name)
    rrd = tmp_path / "x.rrd"
    _one_line(run_command("replay", str(session), "--model", str(model), "--viewer", "none",
                          "--save", str(rrd)), model.name)
    assert not rrd.exists()


def test_resealed_unchanged_model_still_loads_and_predicts(made, tmp_path: Path) -> None:
    same = reseal(made["plain"], tmp_path / "same.skops", lambda meta: None)
    assert load_model(same).meta == load_model(made["plain"]).meta
    result = run_command("classify", "predict", str(same), str(made["session"]))
    assert result.returncode == 0, result.stderr
    events = reseal(made["events"], tmp_path / "same-events.skops", lambda meta: None)
    assert load_model(events, lazy=True).event_model() is not None


@pytest.mark.parametrize("case", sorted(FEATURE_CASES) + sorted(OTHER_CASES))
def test_malformed_metadata_is_one_line(made, tmp_path: Path, case: str) -> None:
    change = FEATURE_CASES.get(case) or OTHER_CASES[case]
    model = reseal(made["plain"], tmp_path / f"hostile-{case}.skops", change)
    _check_both(model, made["session"], tmp_path)


@pytest.mark.parametrize("case", sorted(EVENT_CASES))
def test_malformed_event_settings_are_one_line(made, tmp_path: Path, case: str) -> None:
    model = reseal(made["events"], tmp_path / f"hostile-{case}.skops", EVENT_CASES[case])
    _check_both(model, made["session"], tmp_path)


def _zero_member(source: Path, target: Path, member: str) -> Path:
    """Copy ``source`` with the .npy ``member`` zeroed, re-sealed."""
    import io

    import numpy as np

    with zipfile.ZipFile(source) as archive:
        members = {n: archive.read(n) for n in archive.namelist()}
    array = np.load(io.BytesIO(members[member]))
    out = io.BytesIO()
    np.save(out, np.zeros_like(array))
    members[member] = out.getvalue()
    with zipfile.ZipFile(target, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return reseal(target, target, lambda meta: None)


def test_compiled_arrays_changed_apart_from_the_estimator_are_refused_by_both(
        made, tmp_path: Path) -> None:
    """Zeroed compiled support vectors: replay (compiled arrays) and predict (the
    estimator) had classified two ways; both refuse the file now."""
    model = _zero_member(made["plain"], tmp_path / "zeroed.skops",
                         "online/0/support_vectors.npy")
    _check_both(model, made["session"], tmp_path)
    events = _zero_member(made["events"], tmp_path / "zeroed-events.skops",
                          "events-online/0/support_vectors.npy")
    _check_both(events, made["session"], tmp_path)


def test_old_files_without_feature_names_still_load(made, tmp_path: Path) -> None:
    """feature_names was optional (taken from the transformer): it still is."""
    model = reseal(made["plain"], tmp_path / "old.skops", _drop("feature_names"))
    loaded = load_model(model, lazy=True)
    assert loaded.feature_names == load_model(made["plain"]).feature_names
    assert run_command("classify", "predict", str(model),
                       str(made["session"])).returncode == 0


# ONNX: a graph built with onnx alone (no PyTorch), its digest recomputed.

def _onnx_model(tmp_path: Path, meta: dict, name: str = "net.onnx", opset: int = 13) -> Path:
    """An ONNX file whose graph averages the grid over its channels (a valid graph in
    opset 13; in opset 18 ReduceMean takes its axes as an input, so onnxruntime refuses
    it) with ``meta`` as contactkit's metadata and the graph's digest."""
    onnx = pytest.importorskip("onnx", reason="ONNX cases need onnx")
    from onnx import TensorProto, helper

    from contactkit.classify.modelfile.onnx_model import _graph_digest

    x = helper.make_tensor_value_info("grid", TensorProto.FLOAT, [1, 21, 30])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 30])
    graph = helper.make_graph([helper.make_node("ReduceMean", ["grid"], ["y"], axes=[1],
                                                keepdims=0)], "g", [x], [y])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
    entry = model.metadata_props.add()
    entry.key, entry.value = "contactkit", json.dumps(meta | {"graph_sha256":
                                                              _graph_digest(model)})
    path = tmp_path / name
    onnx.save(model, str(path))
    return path


GOOD_ONNX = {"format": "contactkit-model/3", "kind": "cnn", "input": "grid",
             "classes": ["none", "bump", "adjust", "shove"], "scheme": "full",
             "grid": {"timeseries": ["q", "dq", "tau"], "window": "planned", "window_s": 0.5,
                      "steps": 30, "gain": 50.0, "baseline_s": 0.1}}
ONNX_CASES = {
    "grid-missing": _drop("grid"),
    "grid-list": _set("grid", value=[1]),
    "grid-window_s": _set("grid", "window_s", value=-1),
    "grid-steps": _set("grid", "steps", value="x"),
    "grid-timeseries": _set("grid", "timeseries", value=["bogus"]),
    "grid-unknown-setting": _set("grid", "bogus", value=1),
    "classes-repeated": _set("classes", value=["none", "none"]),
}


@pytest.mark.parametrize("case", sorted(ONNX_CASES))
def test_malformed_onnx_metadata_is_one_line(made, tmp_path: Path, case: str) -> None:
    pytest.importorskip("onnxruntime", reason="ONNX models load with onnxruntime")
    meta = copy.deepcopy(GOOD_ONNX)
    ONNX_CASES[case](meta)
    model = _onnx_model(tmp_path, meta)
    _check_both(model, made["session"], tmp_path)


def test_onnx_graph_that_onnxruntime_refuses_is_one_line(made, tmp_path: Path) -> None:
    """A whole file (its digest matches) whose graph onnxruntime cannot load: one line,
    not onnxruntime's InvalidGraph traceback."""
    pytest.importorskip("onnxruntime", reason="ONNX models load with onnxruntime")
    good = load_model(_onnx_model(tmp_path, copy.deepcopy(GOOD_ONNX), "good.onnx"))
    assert good.classes == GOOD_ONNX["classes"] and len(good.feature_names) == 21
    model = _onnx_model(tmp_path, copy.deepcopy(GOOD_ONNX), opset=18)
    _check_both(model, made["session"], tmp_path)


def test_onnx_without_onnxruntime_names_the_extra(made, tmp_path: Path, monkeypatch) -> None:
    """onnx installed but not onnxruntime: the missing extra, one line (exit 2)."""
    import sys

    model = _onnx_model(tmp_path, copy.deepcopy(GOOD_ONNX))
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # import raises ImportError
    for args in (("classify", "predict", str(model), str(made["session"])),
                 ("replay", str(made["session"]), "--model", str(model), "--viewer", "none",
                  "--save", str(tmp_path / "x.rrd"))):
        result = run_command(*args)
        _one_line(result, model.name)
        assert "contactkit[nn]" in result.stderr
