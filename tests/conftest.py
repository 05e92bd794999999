"""Shared fixtures: short simulated sessions and the real Panda reference recording."""

from __future__ import annotations

import contextlib
import io
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from contactkit.recorder.capture.journal import journal_progress
from contactkit.recorder.sim.simulator import SimConfig, plan_session
from contactkit.recorder.sources.sim import SIM_COLUMNS, SimSource
from contactkit.schemas import write_session

# Fuzzing: a bounded run in `make test`, a long one in benchmarks/bench_fuzz.py.
settings.register_profile("ci", max_examples=30, deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow,
                                                 HealthCheck.data_too_large])
settings.register_profile("long", deadline=None,
                          max_examples=int(os.environ.get("CONTACTKIT_FUZZ_EXAMPLES", "2000")),
                          suppress_health_check=[HealthCheck.too_slow,
                                                 HealthCheck.data_too_large])
settings.load_profile(os.environ.get("CONTACTKIT_FUZZ_PROFILE", "ci"))

REFERENCE = Path(__file__).resolve().parents[2] / "shared" / "reference" / "gaz2019-exciting-traj"
MINDLAB = REFERENCE.parent / "mindlab-contact"
FR3_REFERENCE = REFERENCE.parent / "fr3-teleop-follower"
MINDLAB_FILES = ("a4", "b8", "c2", "d3", "f2")
BIN = Path(sys.executable).parent


def simulate_columns(spec, config) -> dict[str, np.ndarray]:
    """Run one spec through the simulator and return its full columns."""
    chunks = list(SimSource(spec, config, chunk=100).stream())
    return {name: np.concatenate([c[name] for c in chunks]) for name in SIM_COLUMNS}


def make_session(directory: Path, *, seed: int = 3, action: str = "shove", pose: str = "B",
                 link: int | None = 7, duration_s: float = 3.0, planned_at_s: float = 1.5,
                 rate_hz: float = 500.0, robot: str = "panda", with_hand: bool = True,
                 **kwargs) -> Path:
    """Simulate and write a short session; return its path. ``robot`` (default panda) and
    ``with_hand`` choose the simulated arm."""
    config = SimConfig(rate_hz=rate_hz, robot=robot, with_hand=with_hand)
    spec = plan_session(seed=seed, condition="static", action=action, pose=pose, link=link,
                        duration_s=duration_s, planned_at_s=planned_at_s, robot=config.setup,
                        **kwargs)
    meta = SimSource(spec, config).session_meta()
    path = directory / f"{action}_{seed}.parquet"
    write_session(path, simulate_columns(spec, config), meta)
    return path


@pytest.fixture
def session_path(tmp_path: Path) -> Path:
    """A 3 s simulated shove on link 7 at 500 Hz."""
    return make_session(tmp_path)


def _shared(path: Path, what: str) -> Path:
    """Return a reference folder of ../shared: CI must have it, elsewhere its tests skip."""
    if not path.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"{what} missing at {path} (CI must have ../shared)")
        pytest.skip(f"{what} not found at {path}")
    return path


@pytest.fixture(scope="session")
def reference_dir() -> Path:
    """The real Panda recording beside the project (always present in CI)."""
    return _shared(REFERENCE, "reference recording")


@pytest.fixture(scope="session")
def fr3_dir() -> Path:
    """The two real FR3 recordings in teleoperated free motion (no contact)."""
    return _shared(FR3_REFERENCE, "FR3 recordings")


@pytest.fixture(scope="session")
def mindlab_dir() -> Path:
    """The five real Panda CSV recordings with labelled touches (MindLab ZHAW)."""
    return _shared(MINDLAB, "MindLab recordings")


def load_mindlab(path: Path) -> dict[str, np.ndarray]:
    """Read one MindLab CSV: ``t`` [s], ``q``, ``dq``, ``tau``, ``tau_ext`` (N, 7) and
    ``contact`` (N,) bool, with the rows that repeat the previous state dropped."""
    import polars as pl

    frame = pl.read_csv(path)

    def joints(prefix: str) -> np.ndarray:
        return np.column_stack([frame[f"{prefix}{i}"].to_numpy() for i in range(7)])

    out = {"t": frame["time"].to_numpy(), "q": joints("q"), "dq": joints("dq"),
           "tau": joints("tau_J"), "tau_ext": joints("tau_ext"),
           "contact": frame["label"].to_numpy().astype(bool)}
    state = np.hstack([out["q"], out["dq"], out["tau"]])
    keep = np.ones(len(state), bool)
    keep[1:] = (np.diff(state, axis=0) != 0).any(axis=1)
    return {name: values[keep] for name, values in out.items()}


def run_cli(*args: str, cwd: Path | None = None, timeout: float = 300
            ) -> subprocess.CompletedProcess:
    """Run one of the project's console scripts and capture its output.

    The command runs in a process group of its own; on ``timeout`` [s] the whole group
    is killed (a child that outlives its parent, such as a browser, would otherwise keep
    the output pipes open and the test waiting forever) and TimeoutExpired raised.
    """
    env = dict(os.environ, COLUMNS="200")
    with subprocess.Popen([str(BIN / args[0]), *args[1:]], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True, cwd=cwd, env=env,
                          start_new_session=True) as proc:
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate(timeout=60)
            raise
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


CLI_MODULES = {"recorder": "contactkit.cli.recorder", "replay": "contactkit.cli.replay",
               "classify": "contactkit.cli.classify"}


def run_command(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run one of the project's commands in this process, as its console script would
    (the same ``run_app``: its exit codes, its one-line errors), and capture its output.

    For tests of what a command does with its inputs, where a new interpreter would
    only add its start-up; :func:`run_cli` runs the real console script, for what
    needs one (start-up, signals, the installed entry points, a terminal's width)."""
    import importlib

    from contactkit.cli.common import run_app
    from contactkit.util.progress import err_console

    app = importlib.import_module(CLI_MODULES[args[0]]).app
    stdout, stderr = io.StringIO(), io.StringIO()
    # 200 columns, as run_cli's: for the consoles the command makes, and for the shared
    # stderr console, made at import with the width then in the environment (xdist's
    # workers set COLUMNS=80)
    columns, width = os.environ.get("COLUMNS"), err_console.width
    os.environ["COLUMNS"] = "200"
    err_console.width = 200
    try:
        with (contextlib.chdir(cwd or Path.cwd()), contextlib.redirect_stdout(stdout),
              contextlib.redirect_stderr(stderr)):
            code = run_app(app, args[0], list(args[1:]))
    finally:
        err_console.width = width
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns
    return subprocess.CompletedProcess(list(args), code, stdout.getvalue(), stderr.getvalue())


def save_quick_model(path: Path, *, events: bool = False) -> Path:
    """Save an SVM on random rows of the default features (fast to build, predicts
    anything) at ``path``; with ``events``, also the default contact detector and an
    event classifier on random event features. Return the path."""
    from contactkit.classify.events.contact_events import EVENT_FEATURES, EventModel
    from contactkit.classify.kinds.registry import get_kind, make_estimator
    from contactkit.classify.modelfile.model_file import save_model
    from contactkit.features.detector import DetectorConfig
    from contactkit.features.extract import SessionFeatures

    extractor = SessionFeatures(window="planned").fit(None)
    names = list(extractor.get_feature_names_out())
    rng = np.random.default_rng(0)
    labels = np.array(["none", "bump", "adjust", "shove"] * 10)
    estimator = make_estimator("svm", names).fit(rng.normal(size=(40, len(names))), labels)
    extra = {}
    if events:
        X, y = rng.normal(size=(40, len(EVENT_FEATURES))), np.array(["bump", "shove"] * 20)
        intent = make_estimator("svm", []).fit(X + (y == "shove")[:, None], y)
        event_model = EventModel(intent, list(intent.classes_), 0.15, X.min(axis=0),
                                 X.max(axis=0))
        extra = {"detector": DetectorConfig().to_dict(),
                 "events": (intent, event_model.meta())}
    return save_model(path, estimator, transformer=extractor, feature_names=names,
                      classes=list(estimator.classes_), kind=get_kind("svm"), scheme="full",
                      fingerprint="", training={}, **extra)


def make_dataset(directory: Path, poses=("A", "B", "C", "D"), repeats: int = 2,
                 rate_hz: float = 250.0, condition: str = "static") -> Path:
    """Simulate a small balanced dataset (poses x four actions x repeats) in one batch."""
    from contactkit.recorder.sim.dataset import simulate_specs
    from contactkit.recorder.sim.simulator import SimConfig, plan_session

    specs = []
    for rep in range(repeats):
        for p_index, pose in enumerate(poses):
            for a_index, action in enumerate(("none", "bump", "adjust", "shove")):
                seed = 1000 * rep + 10 * p_index + a_index
                operator = f"op{(a_index + rep) % 3}"
                if condition == "dynamic":
                    specs.append(plan_session(seed=seed, condition="dynamic", action=action,
                                              pose="A", target_pose=pose, operator=operator,
                                              speed_rad_s=0.4 + 0.1 * rep))
                else:
                    specs.append(plan_session(seed=seed, condition="static", action=action,
                                              pose=pose, duration_s=5.0, planned_at_s=3.0,
                                              operator=operator))
    directory.mkdir(parents=True, exist_ok=True)
    simulate_specs(specs, SimConfig(rate_hz=rate_hz), directory)
    return directory


def kill_when_journal_holds(command: list[str], directory: Path, samples: int,
                            timeout_s: float = 180.0) -> tuple[int, int]:
    """Start ``command`` (a capture into ``directory``) and SIGKILL it as soon as its
    journal holds at least ``samples`` complete samples (read every 20 ms); return its
    exit code and the samples the journal held just before the kill.

    Nothing here depends on how fast the machine is: a capture that lags behind the
    wall clock is simply killed later. Fails the test when the capture ends on its own
    or its journal stays short for ``timeout_s`` [s].
    """
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + timeout_s
            held = 0
            while proc.poll() is None and time.monotonic() < deadline:
                held = journal_progress(directory)[0]
                if held >= samples:
                    break
                time.sleep(0.02)
            if proc.poll() is not None or held < samples:
                log.seek(0)
                pytest.fail(f"the capture ended or stalled before its journal held {samples} "
                            f"samples (it held {held}): "
                            f"{log.read().decode(errors='replace')[-2000:]}")
            proc.send_signal(signal.SIGKILL)
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.wait(timeout=60)
    return proc.returncode, held


@pytest.fixture(autouse=True)
def _written_recordings_pass_rerun_verify(request):
    """Every .rrd a test writes into its ``tmp_path`` must pass ``rerun rrd verify``
    (issue 25): the SDK rejects files the viewer might still show."""
    yield
    tmp = request.node.funcargs.get("tmp_path") if hasattr(request.node, "funcargs") else None
    if tmp is None:
        return
    written = sorted(p for p in Path(tmp).rglob("*.rrd") if p.is_file() and not p.is_symlink()
                     and _starts_with(p, b"RRF"))
    from tests.rrd_frames import verify_problems

    problems = verify_problems(*written)
    assert not problems, "rerun rrd verify: " + "\n".join(problems)


def _starts_with(path: Path, magic: bytes) -> bool:
    with open(path, "rb") as fh:
        return fh.read(len(magic)) == magic


def write_imported(importer, meta, out_dir: Path, name: str | None = None) -> Path:
    """Write the session an opened importer (``BagImporter.read(...)``,
    ``CsvImporter.read(...)``, ...) streams, through the one writer every import takes
    (:func:`contactkit.recorder.importers.writer.write_importer`), and close the importer;
    return the session's path."""
    from contactkit.recorder.importers.writer import write_importer

    with importer:
        return write_importer(importer, meta, out_dir, name)


def import_array_files(t_path: Path, q_path: Path, dq_path: Path, tau_path: Path,
                       out_dir: Path, meta_pairs: list[str]) -> Path:
    """Import joint arrays as ``recorder import --format arrays`` does (the one import path,
    :func:`contactkit.recorder.importers.jobs.import_file`); return the session's path."""
    from contactkit.recorder.importers.jobs import ImportJob, import_file, protocol_from

    return import_file(ImportJob(Path(t_path), out_dir, protocol_from({}, meta_pairs), "arrays",
                                 {"q": q_path, "dq": dq_path, "tau": tau_path})).session


# Markers by file or test, so that `make check` can leave out what needs the nn extra
# (torch, aeon, onnx, onnxruntime) or builds the documentation, without each test file
# saying so; and a longer timeout for the tests marked slow or nn than the default
# (pyproject.toml's `timeout`), which is sized to catch a hang in minutes.
NN_FILES = {"test_nn.py", "test_gridsearch.py"}
NN_TESTS = {"test_gridsearch_and_lstm_evaluate_identical",
            "test_onnx_model_with_metadata_of_the_wrong_shape_is_one_line",
            "test_malformed_onnx_metadata_is_one_line",
            "test_onnx_graph_that_onnxruntime_refuses_is_one_line",
            "test_onnx_without_onnxruntime_names_the_extra"}
DOCS_FILES = {"test_notebook.py"}
LONG_TIMEOUT_S = 900


def pytest_collection_modifyitems(config, items) -> None:
    for item in items:
        if item.path.name in NN_FILES or getattr(item, "originalname", "") in NN_TESTS:
            item.add_marker(pytest.mark.nn)
        if item.path.name in DOCS_FILES:
            item.add_marker(pytest.mark.docs)
        if (item.get_closest_marker("slow") or item.get_closest_marker("nn")) \
                and not item.get_closest_marker("timeout"):
            item.add_marker(pytest.mark.timeout(LONG_TIMEOUT_S))
