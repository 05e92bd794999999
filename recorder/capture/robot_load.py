"""The robot's configured load as the payload of an identification, during a capture.

``recorder capture --dynamics FILE --robot-load`` takes the load a robot reports once it
is connected (libfranka's ``m_load`` and ``F_x_Cload``: the franka source stores them as
the session's ``payload_kg`` and ``payload_com_m``) as the payload of the identified
dynamics, in place of the one identified
(:func:`contactkit.robots.dynamics.with_payload`). The load is known only when the first
state has arrived, so :class:`RobotLoad` sets the session's dynamics then, and only then
starts what follows the capture with them (the live event pipeline).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from contactkit.recorder.capture.record import CaptureListener
from contactkit.recorder.sources import Source
from contactkit.robots.dynamics import ArmDynamics, with_payload
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


class RobotLoad:
    """Capture listener: on the first chunk, ``dynamics`` with the load ``source``
    reports as their payload become the session's (``meta.dynamics``); then
    ``follow(meta)`` starts the listener that uses them (None: none), which sees that
    chunk and every later one. A source that reports no load keeps the identified
    payload, with a warning."""

    def __init__(self, meta: SessionMeta, source: Source, dynamics: ArmDynamics,
                 follow: Callable[[SessionMeta], CaptureListener | None]) -> None:
        self.meta, self.source, self.dynamics, self.follow = meta, source, dynamics, follow
        self.listener: CaptureListener | None = None
        self.started = False

    def on_chunk(self, chunk: dict[str, np.ndarray]) -> None:
        """Take the next chunk of session columns."""
        if not self.started:
            self.started = True
            load = reported_load(self.source)
            if load is None:
                log.warning("the source reports no configured load: the identified payload "
                            "(%.3f kg) is kept", self.dynamics.payload.mass_kg)
            else:
                self.meta.dynamics = with_payload(self.dynamics, *load).to_dict()
            self.listener = self.follow(self.meta)
        if self.listener is not None:
            self.listener.on_chunk(chunk)

    def session_fields(self) -> dict[str, Any]:
        """Return the session's ``dynamics`` and the followed listener's fields."""
        fields = {} if self.listener is None else dict(self.listener.session_fields())
        return {"dynamics": self.meta.dynamics, **fields}
