"""Shared fixtures: short simulated sessions and the real Panda reference recording."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from contactkit.recorder.sim import SimConfig, plan_session
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
MINDLAB_FILES = ("a4", "b8", "c2", "d3", "f2")
BIN = Path(sys.executable).parent


def simulate_columns(spec, config) -> dict[str, np.ndarray]:
    """Run one spec through the simulator and return its full columns."""
    chunks = list(SimSource(spec, config, chunk=100).stream())
    return {name: np.concatenate([c[name] for c in chunks]) for name in SIM_COLUMNS}


def make_session(directory: Path, *, seed: int = 3, action: str = "shove", pose: str = "B",
                 link: int | None = 7, duration_s: float = 3.0, planned_at_s: float = 1.5,
                 rate_hz: float = 500.0, **kwargs) -> Path:
    """Simulate and write a short session; return its path."""
    config = SimConfig(rate_hz=rate_hz)
    spec = plan_session(seed=seed, condition="static", action=action, pose=pose, link=link,
                        duration_s=duration_s, planned_at_s=planned_at_s, **kwargs)
    meta = SimSource(spec, config).session_meta()
    path = directory / f"{action}_{seed}.parquet"
    write_session(path, simulate_columns(spec, config), meta)
    return path


@pytest.fixture
def session_path(tmp_path: Path) -> Path:
    """A 3 s simulated shove on link 7 at 500 Hz."""
    return make_session(tmp_path)


@pytest.fixture(scope="session")
def reference_dir() -> Path:
    """The real Panda recording beside the project (always present in CI)."""
    if not REFERENCE.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"reference recording missing at {REFERENCE} (CI must have ../shared)")
        pytest.skip(f"reference recording not found at {REFERENCE}")
    return REFERENCE


@pytest.fixture(scope="session")
def mindlab_dir() -> Path:
    """The five real Panda CSV recordings with labelled touches (MindLab ZHAW)."""
    if not MINDLAB.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"MindLab recordings missing at {MINDLAB} (CI must have ../shared)")
        pytest.skip(f"MindLab recordings not found at {MINDLAB}")
    return MINDLAB


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
    """Run one of the project's console scripts and capture its output."""
    env = dict(os.environ, COLUMNS="200")
    return subprocess.run([str(BIN / args[0]), *args[1:]], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout, env=env)


def make_dataset(directory: Path, poses=("A", "B", "C", "D"), repeats: int = 2,
                 rate_hz: float = 250.0, condition: str = "static") -> Path:
    """Simulate a small balanced dataset (poses x four actions x repeats) in one batch."""
    from contactkit.recorder.dataset import simulate_specs
    from contactkit.recorder.sim import SimConfig, plan_session

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


def kill_after_recording_starts(command: list[str], seconds: float) -> tuple[int, float]:
    """Start ``command``, SIGKILL it ``seconds`` after it prints "recording started" on
    stderr; return its exit code and the time [s] from that line to the kill."""
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for line in proc.stderr:
            if "recording started" in line:
                break
        started = time.monotonic()
        time.sleep(seconds)
        proc.send_signal(signal.SIGKILL)
        killed_after = time.monotonic() - started
    finally:
        proc.wait(timeout=30)
    return proc.returncode, killed_after
