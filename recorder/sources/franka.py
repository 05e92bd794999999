"""A Franka robot (Panda or FR3) as a capture source, read only.

The source reads the robot's 1 kHz state in a loop (libfranka ``read_once()``,
through :mod:`contactkit.recorder.sources.franka_backends`) and never commands the
robot. Time is the robot's own time stamp, shifted to start at 0. Missed states
are data: each gap in the robot's time stamps is counted, with the states it
stands for. A lost connection ends the capture with a one-line message, and what
was recorded is kept.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from contactkit.recorder.sources.base import ProtocolChoices, Source
from contactkit.recorder.sources.franka_backends import (
    BACKEND_CLASSES,
    ROW_WIDTH,
    Backend,
    ConnectionLost,
    open_backend,
    state_row,
)
from contactkit.robots import DEFAULT_ROBOT
from contactkit.schemas import joint_columns
from contactkit.schemas.columns import WRENCH_HAT_COLUMNS

log = logging.getLogger(__name__)
FRANKA_COLUMNS = ["t", *joint_columns("q"), *joint_columns("dq"), *joint_columns("tau"),
                  *joint_columns("q_d"), *joint_columns("dq_d"), *joint_columns("tau_ext_hat"),
                  *WRENCH_HAT_COLUMNS, "robot_mode", "command_success_rate"]
STATE_PERIOD_S = 0.001
CHUNK_STATES = 10


@dataclass(frozen=True)
class FrankaConfig:
    """How to reach the robot: ``host`` (the FCI address, e.g. 172.16.0.2), ``backend``
    (auto, pylibfranka or panda-python) and ``realtime_kernel`` (enforce libfranka's
    real-time check; off by default: the recorder only reads, so a normal kernel will do)."""

    host: str = field(default="172.16.0.2", metadata={"help": "The robot's FCI address."})
    backend: Literal["auto", "pylibfranka", "panda-python"] = field(default="auto", metadata={
        "help": "auto, pylibfranka (FR3, robot system 5.9+) or panda-python (Panda)."})
    realtime_kernel: bool = field(default=False, metadata={
        "help": "Enforce libfranka's real-time check (default: ignored; the recorder only "
                "reads)."})
    robot: str | None = field(default=None, metadata={
        "help": "The arm's model (panda, fr3, ...; default: from the backend that "
                "connects: pylibfranka means an FR3, panda-python a Panda)."})


@dataclass
class StateCounts:
    """What the robot's time stamps say about the states received: ``gaps`` are steps
    longer than one state period (1 ms), ``states_lost`` the states they stand for."""

    states: int = 0
    gaps: int = 0
    states_lost: int = 0
    max_gap_s: float = 0.0

    def add(self, robot_time_s: np.ndarray, previous_s: float | None) -> None:
        """Count the states of one chunk of robot time stamps [s]."""
        times = robot_time_s if previous_s is None else np.concatenate(([previous_s],
                                                                        robot_time_s))
        steps = np.diff(times)
        missed = np.round(steps / STATE_PERIOD_S).astype(int) - 1
        self.states += len(robot_time_s)
        self.gaps += int((missed > 0).sum())
        self.states_lost += int(missed[missed > 0].sum())
        if steps.size:
            self.max_gap_s = max(self.max_gap_s, float(steps.max()))


class FrankaSource(Source):
    """States of a live Franka robot, ``duration_s`` of robot time, in chunks of 10."""

    name = "franka"
    Config = FrankaConfig
    columns = FRANKA_COLUMNS
    live = True
    nominal_rate_hz = 1.0 / STATE_PERIOD_S

    def __init__(self, config: FrankaConfig, duration_s: float,
                 connect: Callable[[FrankaConfig], Backend] | None = None,
                 choices: ProtocolChoices | None = None) -> None:
        self.choices = choices or ProtocolChoices(action="none", duration_s=duration_s)
        self.planned_at_s = self.choices.timing()[0] if choices is not None else 0.0
        self.config = config
        self.duration_s = duration_s
        self.connect = connect or (lambda c: open_backend(c.host, c.backend,
                                                          c.realtime_kernel))
        self.counts = StateCounts()
        self.end_reason = ""
        self.backend_info: dict[str, Any] = {}
        self.load: dict[str, Any] = {}
        self.robot_time_start_s: float | None = None

    @classmethod
    def from_config(cls, config: FrankaConfig, choices: ProtocolChoices) -> FrankaSource:
        """Return the robot source for options ``config``, ending at the session duration."""
        _, duration = choices.timing()
        return cls(config, duration, choices=choices)

    def stream(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield chunks of states until ``duration_s`` of robot time has passed or the
        connection is lost."""
        backend = self.connect(self.config)
        self.backend_info = {"backend": backend.name, **backend.describe()}
        try:
            yield from self._read(backend)
        finally:
            backend.close()

    def _read(self, backend: Backend) -> Iterator[dict[str, np.ndarray]]:
        buffer = np.empty((CHUNK_STATES, ROW_WIDTH))
        filled = 0
        previous: float | None = None
        while True:
            try:
                state = backend.read()
                state_row(state, buffer[filled])
            except ConnectionLost as err:
                self.end_reason = f"connection lost ({err}): capture ended, everything " \
                                  "received so far is kept"
                log.warning(self.end_reason)
                break
            if self.robot_time_start_s is None:
                self.robot_time_start_s = float(buffer[0, 0])
                self.load = configured_load(state)
            done = buffer[filled, 0] - self.robot_time_start_s >= self.duration_s
            filled += 1
            if filled == CHUNK_STATES or done:
                previous = self._count(buffer[:filled], previous)
                yield self._columns(buffer[:filled])
                filled = 0
            if done:
                self.end_reason = f"reached the session duration ({self.duration_s} s)"
                break
        if filled:
            self._count(buffer[:filled], previous)
            yield self._columns(buffer[:filled])

    def _count(self, rows: np.ndarray, previous: float | None) -> float:
        self.counts.add(rows[:, 0], previous)
        return float(rows[-1, 0])

    def _columns(self, rows: np.ndarray) -> dict[str, np.ndarray]:
        columns = {name: rows[:, i].copy() for i, name in enumerate(FRANKA_COLUMNS)}
        columns["t"] = columns["t"] - self.robot_time_start_s
        columns["robot_mode"] = columns["robot_mode"].astype(np.int8)
        return columns

    def metadata(self) -> dict[str, Any]:
        """Return source and connection statistics for the session metadata: host,
        backend and client version, real-time mode, states received and lost, gaps,
        the robot's time at the first state [s], and why the capture ended."""
        info = {"host": self.config.host, "backend_requested": self.config.backend,
                "realtime": "enforced (real-time kernel)" if self.config.realtime_kernel
                else "ignored (libfranka RealtimeConfig.kIgnore)",
                **self.backend_info,
                "robot_time_start_s": self.robot_time_start_s,
                "states": self.counts.states, "states_lost": self.counts.states_lost,
                "gaps": self.counts.gaps, "max_gap_s": self.counts.max_gap_s,
                "end": self.end_reason, **self.load}
        fields = {"source": self.name, "source_info": info, "robot": self.robot_name()}
        if self.load.get("m_load_kg"):
            fields.update(payload_kg=self.load["m_load_kg"],
                          payload_com_m=self.load["F_x_Cload_m"])
        return fields

    def robot_name(self) -> str:
        """Return the arm's registry name: the ``robot`` option, else the one of the
        backend that connected (or was asked for): pylibfranka talks to an FR3,
        panda-python to a Panda; before ``--backend auto`` connects, ``panda``."""
        backend = self.backend_info.get("backend", self.config.backend)
        known = BACKEND_CLASSES.get(backend)
        return self.config.robot or (known.robot if known else DEFAULT_ROBOT)


def configured_load(state: Any) -> dict[str, Any]:
    """Return the end effector and load configured on the robot, as its state reports
    them: ``m_ee_kg`` (the end effector's mass, e.g. the Franka Hand's), ``m_load_kg``
    and ``F_x_Cload_m`` (a payload's mass [kg] and centre of mass in the flange frame
    [m]); the fields a client library does not report are left out. A payload becomes
    the session's ``payload_kg``/``payload_com_m``, which the robot model adds to link 7."""
    out: dict[str, Any] = {}
    for field_name, key in (("m_ee", "m_ee_kg"), ("m_load", "m_load_kg")):
        value = getattr(state, field_name, None)
        if isinstance(value, int | float) and np.isfinite(value) and value >= 0:
            out[key] = float(value)
    com = getattr(state, "F_x_Cload", None)
    if com is not None and np.shape(com) == (3,) and np.isfinite(com).all():
        out["F_x_Cload_m"] = [float(v) for v in com]
    if out.get("m_load_kg") and "F_x_Cload_m" not in out:
        out["F_x_Cload_m"] = [0.0, 0.0, 0.0]
    return out
