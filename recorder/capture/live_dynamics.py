"""Identified dynamics during a capture: the arm they are for, and the robot's configured
load as their payload.

``recorder capture --dynamics FILE`` stores the dynamics with the session and gives them
to the live event pipeline. They were checked against the arm the source named before it
connected; a robot's backend may name another once connected (``--backend auto``), so
:class:`LiveDynamics` checks them again at the first chunk and stops the capture then,
in one line, rather than when the session is written. With ``--robot-load`` it takes the
load a robot reports once connected (libfranka's ``m_load`` and ``F_x_Cload``: the franka
source stores them as the session's ``payload_kg`` and ``payload_com_m``) as the
payload of the identification, in place of the one identified
(:func:`contactkit.robots.dynamics.with_payload`): the load is known only when the first
state has arrived, so the session's dynamics are set then, and only then is what follows
the capture with them (the live event pipeline) started.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from contactkit.recorder.capture.record import CaptureListener
from contactkit.recorder.sources import Source
from contactkit.robots import RobotSetup, canonical_robot_name
from contactkit.robots.dynamics import ArmDynamics, check_arm, with_payload
from contactkit.schemas import SessionMeta

log = logging.getLogger(__name__)


def reported_load(source: Source) -> tuple[float, tuple[float, float, float]] | None:
    """Return the load the connected robot reports (mass [kg], centre of mass [m] in the
    flange frame; 0 kg when it reports none), or None when the source does not say
    (not a robot, or a client library that does not report it)."""
    fields = source.metadata()
    info = fields.get("source_info")
    if not (isinstance(info, dict) and "m_load_kg" in info):
        return None
    com = fields.get("payload_com_m") or (0.0, 0.0, 0.0)
    return float(fields.get("payload_kg", 0.0)), (float(com[0]), float(com[1]), float(com[2]))


class LiveDynamics:
    """Capture listener for a session carrying identified ``dynamics``: at the first
    chunk, checks them against the arm ``source`` names now (InputError: the capture
    stops); with ``robot_load``, sets ``meta.dynamics`` to them with the load the source
    reports as their payload (a source that reports none keeps the identified payload,
    with a warning). ``follow(meta)`` starts the listener that uses them (None: none):
    before the capture without ``robot_load`` (building a model takes longer than a
    live robot waits), at the first chunk with it. That listener sees every chunk."""

    def __init__(self, meta: SessionMeta, source: Source, dynamics: ArmDynamics,
                 follow: Callable[[SessionMeta], CaptureListener | None],
                 robot_load: bool = False) -> None:
        self.meta, self.source, self.dynamics = meta, source, dynamics
        self.follow, self.robot_load = follow, robot_load
        self.listener = None if robot_load else follow(meta)
        self.started = False

    def on_chunk(self, chunk: dict[str, np.ndarray]) -> None:
        """Take the next chunk of session columns."""
        if not self.started:
            self.started = True
            robot = canonical_robot_name(self.source.metadata().get("robot", self.meta.robot))
            check_arm(self.dynamics, RobotSetup(robot, self.meta.with_hand))
            if self.robot_load:
                load = reported_load(self.source)
                if load is None:
                    log.warning("the source reports no configured load: the identified "
                                "payload (%.3f kg) is kept", self.dynamics.payload.mass_kg)
                else:
                    self.meta.dynamics = with_payload(self.dynamics, *load).to_dict()
                self.listener = self.follow(self.meta)
        if self.listener is not None:
            self.listener.on_chunk(chunk)

    def session_fields(self) -> dict[str, Any]:
        """Return the session's ``dynamics`` and the followed listener's fields."""
        fields = {} if self.listener is None else dict(self.listener.session_fields())
        return {"dynamics": self.meta.dynamics, **fields}
