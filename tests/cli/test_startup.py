"""Start-up: `--help` of every command and `recorder info` import no heavy library.

An import-set test, not a timing test: each command runs in a fresh interpreter through
its console script's ``main``, and the modules it left in ``sys.modules`` are checked.
The heavy libraries are imported only where they are used: torch and onnxruntime for
network kinds, skops for model files, scikit-learn for classifying, rerun for logging,
pinocchio for the chain, scipy where its functions run, dask with --scheduler,
matplotlib and polars for reports and imports.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from contactkit.classify.kinds import registry
from contactkit.errors import InputError
from tests.conftest import make_session, save_quick_model

HEAVY = ("torch", "onnxruntime", "onnx", "skops", "sklearn", "rerun", "pinocchio", "scipy",
         "dask", "distributed", "matplotlib", "polars", "aeon")

# Runs ``main`` of a command with the given argv, then prints the modules it loaded.
PROBE = """
import json, sys
from importlib import import_module
tool, argv = sys.argv[1], sys.argv[2:]
sys.argv = [tool, *argv]
try:
    import_module(f"contactkit.cli.{tool}").main()
except SystemExit as done:
    code = done.code
else:
    code = 0
print("\\n" + json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def _modules(tool: str, *argv: str) -> tuple[int, set[str], str]:
    """Run ``tool argv`` in a fresh interpreter; return its exit code, the modules it
    imported and its output."""
    proc = subprocess.run([sys.executable, "-c", PROBE, tool, *argv], capture_output=True,
                          text=True, timeout=300, env=dict(os.environ, COLUMNS="200"))
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    return report["code"], set(report["modules"]), proc.stdout


def _loaded(tool: str, *argv: str) -> tuple[int, set[str], str]:
    """Run ``tool argv`` in a fresh interpreter; return its exit code, the top-level
    packages it imported and its output."""
    code, modules, out = _modules(tool, *argv)
    return code, {m.split(".")[0] for m in modules}, out


@pytest.mark.parametrize("argv", [
    ("recorder", "--help"),
    ("recorder", "capture", "--help"),
    ("replay", "--help"),
    ("classify", "--help"),
    ("classify", "train", "--help"),
])
def test_help_imports_no_heavy_library(argv) -> None:
    code, modules, out = _loaded(*argv)
    assert code == 0, out
    assert "Usage" in out
    assert sorted(modules & set(HEAVY)) == []


@pytest.mark.parametrize("argv", [("recorder", "--help"), ("replay", "--help")])
def test_help_reads_no_distribution_metadata(argv) -> None:
    """Versions and entry points come through importlib.metadata, whose import alone
    takes some 35 ms: these helps need neither (``classify --help`` lists the model
    kinds that plugins declare, so it looks them up)."""
    code, modules, out = _modules(*argv)
    assert code == 0, out
    assert "importlib.metadata" not in modules


def test_recorder_help_loads_no_source() -> None:
    """`recorder --help` lists capture and sources without loading a source (whose
    modules, plugins included, may import robot SDKs and python-can) or the capture's
    writer; capture's own help loads them all, to list their options, but not
    python-can."""
    code, modules, out = _modules("recorder", "--help")
    assert code == 0 and "capture" in out and "sources" in out, out
    sources = {f"contactkit.recorder.sources.{name}" for name in ("sim", "can", "franka")}
    writer = {"contactkit.cli.capture", "contactkit.recorder.capture.record",
              "contactkit.recorder.capture.journal"}
    assert sorted(modules & (sources | writer | {"can"})) == []
    code, modules, out = _modules("recorder", "capture", "--help")
    assert code == 0 and "--channel" in out, out
    assert sources <= modules
    assert "can" not in modules  # python-can (80 ms) only when a bus opens or frames are made


def test_deferred_commands_list_the_help_they_have_once_built() -> None:
    """The one-line help `recorder --help` shows for capture and sources before they are
    built is the first line of their own help."""
    import typer

    from contactkit.cli.recorder import app

    group = typer.main.get_group(app)
    ctx = group.context_class(group)
    listed = {name: group.get_command(ctx, name).help for name in group.deferred}
    assert set(listed) == {"capture", "sources"}
    for name, summary in listed.items():
        group.build(name)
        built = group.get_command(ctx, name)
        assert " ".join(built.help.split("\n\n")[0].split()) == summary


def test_a_mistyped_deferred_command_gets_a_suggestion(capsys) -> None:
    from contactkit.cli.common import run_app
    from contactkit.cli.recorder import app

    assert run_app(app, "recorder", ["captur", "--pose", "B"]) == 2
    assert "Did you mean 'capture'?" in capsys.readouterr().err


def test_recorder_info_imports_no_heavy_library(tmp_path: Path) -> None:
    """Nor pandas, which pyarrow imports on ``to_numpy()`` (the session schema reads
    columns without it)."""
    session = make_session(tmp_path, duration_s=1.0, planned_at_s=0.5)
    code, modules, out = _loaded("recorder", "info", str(session))
    assert code == 0, out
    assert "shove" in out
    assert sorted(modules & {*HEAVY, "pandas"}) == []


def test_replay_imports_no_classifier_library(tmp_path: Path) -> None:
    """A replay with an SVM model (its per-hop and event classifiers compiled to arrays
    in the file) and its contact detector imports neither scikit-learn, skops nor scipy,
    nor pandas (which pyarrow would import for Rerun's lists); rerun and pinocchio are
    what it uses."""
    session = make_session(tmp_path, duration_s=2.0, planned_at_s=1.0)
    model = save_quick_model(tmp_path / "m.skops", events=True)
    code, modules, out = _loaded("replay", str(session), "--model", str(model), "--viewer",
                                 "none", "--save", str(tmp_path / "r.rrd"))
    assert code == 0, out
    assert (tmp_path / "r.rrd").is_file()
    assert sorted(modules & {*HEAVY, "pandas"}) == ["pinocchio", "rerun"]


def test_skops_is_imported_without_torch_or_dask() -> None:
    """skops' trusted-type table is built without the array-API shims that import torch
    and dask, and still trusts scikit-learn's estimators."""
    probe = ("import json, sys\n"
             "from contactkit.classify.modelfile.skops_import import WALK_SKIPS, skops_io\n"
             "skops_io()\n"
             "from skops.io._trusted_types import SKLEARN_ESTIMATOR_TYPE_NAMES as names\n"
             "print(json.dumps({'torch': 'torch' in sys.modules, 'dask': 'dask' in "
             "sys.modules, 'left': [n for n in WALK_SKIPS if n in sys.modules], "
             "'svc': 'sklearn.svm._classes.SVC' in names, "
             "'pipeline': 'sklearn.pipeline.Pipeline' in names}))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=300, check=True)
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == {
        "torch": False, "dask": False, "left": [], "svc": True, "pipeline": True}


def test_listing_model_kinds_imports_no_plugin(monkeypatch) -> None:
    """An entry point's kind is listed by name and imported only when asked for: a
    plugin that cannot even be imported does not break the listing."""
    point = importlib.metadata.EntryPoint(name="absent-kind", group=registry.ENTRY_POINT_GROUP,
                                          value="contactkit_absent_plugin:KIND")
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group: [point] if group == registry.ENTRY_POINT_GROUP else [])
    registry.REGISTRY.refresh()
    try:
        assert registry.kind_names()[-1] == "absent-kind"
        assert "contactkit_absent_plugin" not in sys.modules
        with pytest.raises(InputError, match=r"'absent-kind' .* cannot be loaded"):
            registry.get_kind("absent-kind")
    finally:
        registry.unregister("absent-kind")
