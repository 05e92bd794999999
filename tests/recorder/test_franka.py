"""The franka source: pylibfranka against franky-sim (a simulated FR3 behind the real FCI
protocol, on a loopback address), and panda-python against a stand-in robot."""

from __future__ import annotations

import importlib.util
import subprocess
import threading
import time
from enum import IntEnum
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import BIN, kill_when_journal_holds, run_cli

from contactkit.errors import DependencyMissing
from contactkit.recorder.capture.record import capture
from contactkit.recorder.metadata import session_meta
from contactkit.recorder.sources import source_class
from contactkit.recorder.sources.franka import FrankaConfig, FrankaSource
from contactkit.recorder.sources.franka_backends import EXTRAS, PandaPyBackend, open_backend
from contactkit.schemas import InputError, validate_session

MISSING = [m for m in ("pylibfranka", "franky_sim") if importlib.util.find_spec(m) is None]
needs_server = pytest.mark.skipif(
    bool(MISSING), reason=f"{' and '.join(MISSING)} not installed (pip install "
                          "'contactkit[sim-robot]'; not available on every platform)")


def start_server() -> tuple[subprocess.Popen, str]:
    """Start franky-sim (MuJoCo) on a free loopback address; return it and the address."""
    proc = subprocess.Popen([str(BIN / "franky-sim"), "--simulator", "mujoco"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 120
    for line in proc.stdout:
        if "using '" in line:
            host = line.split("'")[1]
            threading.Thread(target=proc.stdout.read, daemon=True).start()
            return proc, host
        if time.monotonic() > deadline:
            break
    proc.kill()
    raise RuntimeError("franky-sim did not start")


def stop_server(proc: subprocess.Popen) -> None:
    proc.kill()
    proc.wait(timeout=30)


@pytest.fixture(scope="module")
def server():
    proc, host = start_server()
    yield host
    stop_server(proc)


def meta():
    return session_meta(source="franka", action="none", condition="static", pose="A",
                         target_pose=None, speed_rad_s=None, link=None, planned_at_s=1.0,
                         operator="", with_hand=True)


@needs_server
def test_capture_from_simulated_fr3(server, tmp_path):
    source = FrankaSource(FrankaConfig(host=server, backend="pylibfranka"), duration_s=2.0)
    result = capture(source, meta(), tmp_path / "s.parquet")
    session = validate_session(result.path)
    info = session.meta.source_info
    assert info["end"] == "reached the session duration (2.0 s)"
    assert info["backend"] == "pylibfranka" and "ignored" in info["realtime"]
    # every robot tick (1 ms) up to the last state is either recorded or counted as lost;
    # the capture ends at the first state at or past 2 s (a gap may straddle it)
    assert session.t[-1] >= 2.0 > session.t[-2]
    assert session.n_samples + info["states_lost"] == round(session.t[-1] * 1e3) + 1
    # transport, not timing: a loaded machine loses states, never most of them
    assert session.n_samples >= 0.5 * 2000
    steps_ms = np.diff(session.t) * 1e3
    assert (steps_ms > 0).all() and np.allclose(steps_ms, np.round(steps_ms), atol=1e-6)
    assert info["gaps"] == int((np.round(steps_ms) > 1).sum())
    # the simulated robot holds still: velocities agree with the change of position
    dq_from_q = np.diff(session.q, axis=0) / np.diff(session.t)[:, None]
    assert np.abs(dq_from_q - session.dq[1:]).max() < 1e-3
    assert np.abs(session.dq).max() < 1e-2
    assert set(np.unique(session.column("robot_mode"))) <= {1, 2}
    assert session.has("tau_ext_hat_7") and session.has("f_ext_hat_z")


@needs_server
def test_server_killed_mid_capture_keeps_the_session(tmp_path):
    proc, host = start_server()
    try:
        capture_proc = subprocess.Popen(
            [str(BIN / "recorder"), "capture", "--source", "franka", "--host", host,
             "--pose", "A", "--action", "none", "--duration", "60", "--out", str(tmp_path)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for line in capture_proc.stderr:
            if "recording started" in line:
                break
        time.sleep(1.0)
    finally:
        stop_server(proc)
    out, err = capture_proc.communicate(timeout=120)
    assert capture_proc.returncode == 0, err
    session = validate_session(Path(out.strip()))
    assert session.meta.source_info["end"].startswith("connection lost")
    assert "connection lost" in err and session.n_samples > 100


@needs_server
def test_sigkill_then_recover(server, tmp_path):
    command = [str(BIN / "recorder"), "capture", "--source", "franka", "--host", server,
               "--pose", "A", "--action", "none", "--duration", "60", "--out", str(tmp_path)]
    code, held = kill_when_journal_holds(command, tmp_path, 200)
    assert code == -9
    result = run_cli("recorder", "recover", str(tmp_path))
    assert result.returncode == 0, result.stderr
    session = validate_session(next(tmp_path.glob("*.parquet")))
    assert session.meta.recovered and session.n_samples >= held >= 200
    assert (np.diff(session.t) > 0).all()


class StandInMode(IntEnum):
    """libfranka's RobotMode as panda_py binds it (an enum with ``value``)."""

    kIdle = 1
    kMove = 2


class StandInRobot:
    """A stand-in for ``panda_py.libfranka.Robot``: the state interface only. Serves
    ``n`` states 1 ms apart, skipping the times in ``skip``, then raises as libfranka
    does when the robot stops answering."""

    def __init__(self, host: str, realtime_config=None, n: int = 500, skip=(100, 101, 300)):
        self.host, self.realtime_config = host, realtime_config
        self.ticks = iter([k for k in range(n + len(skip)) if k not in skip])

    def server_version(self) -> int:
        return 5

    def read_once(self):
        tick = next(self.ticks, None)
        if tick is None:
            raise RuntimeError("libfranka: UDP receive: Timeout")
        joint = np.full(7, tick * 1e-3)
        return SimpleNamespace(
            time=SimpleNamespace(to_sec=lambda: 7.0 + tick * 1e-3), q=joint, dq=joint + 1,
            tau_J=joint + 2, q_d=joint + 3, dq_d=joint + 4, tau_ext_hat_filtered=joint + 5,
            O_F_ext_hat_K=np.arange(6.0), robot_mode=StandInMode.kMove,
            control_command_success_rate=0.5, m_ee=0.73, m_load=0.4,
            F_x_Cload=np.array([0.0, 0.01, 0.05]))


STANDIN = SimpleNamespace(libfranka=SimpleNamespace(
    Robot=StandInRobot, RealtimeConfig=SimpleNamespace(kIgnore=1, kEnforce=0)))


def test_panda_python_backend_against_stand_in(tmp_path):
    source = FrankaSource(FrankaConfig(host="172.16.0.2", backend="panda-python"), 10.0,
                          connect=lambda c: PandaPyBackend(c.host, c.realtime_kernel,
                                                           module=STANDIN))
    session = validate_session(capture(source, meta(), tmp_path / "p.parquet").path)
    info = session.meta.source_info
    assert session.n_samples == 500
    assert info["states_lost"] == 3 and info["gaps"] == 2
    assert info["end"].startswith("connection lost (libfranka: UDP receive: Timeout)")
    assert info["server_version"] == 5 and info["robot_time_start_s"] == 7.0
    assert np.allclose(session.t[:3], [0.0, 0.001, 0.002])
    assert np.allclose(session.column("tau_3") - session.column("q_3"), 2.0)
    assert np.allclose(session.column("f_ext_hat_y"), 1.0)
    assert (session.column("robot_mode") == 2).all()
    assert np.allclose(session.column("command_success_rate"), 0.5)
    # the configured end effector and load, and the arm the backend talks to
    assert info["m_ee_kg"] == 0.73 and session.meta.robot == "panda"
    assert session.meta.payload_kg == 0.4 and session.meta.payload_com_m == [0.0, 0.01, 0.05]
    assert session.meta.robot_setup().payload_kg == 0.4


def test_missing_extra_names_it(monkeypatch):
    monkeypatch.setitem(EXTRAS, "panda-python", ("no_such_module_for_test", "panda"))
    with pytest.raises(DependencyMissing, match=r"contactkit\[panda\]"):
        open_backend("172.16.0.2", "panda-python", False)
    with pytest.raises(InputError, match="unknown franka backend"):
        open_backend("172.16.0.2", "ros", False)
    assert source_class("franka") is FrankaSource
