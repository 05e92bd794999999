"""What every data source implements, and the protocol choices it is given."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from contactkit.recorder.metadata import session_meta
from contactkit.recorder.protocol import check_duration, default_timing
from contactkit.schemas import InputError, SessionMeta


@dataclass(frozen=True)
class ProtocolChoices:
    """What a session records, as chosen by the person running it (thesis section 3.2).

    Pose names A-H, speed in rad/s, times in s. ``None`` means the protocol's default
    (for a simulated session, the simulator's timing and a random link).
    """

    action: str
    pose: str | None = None
    condition: str = "static"
    target_pose: str | None = None
    speed_rad_s: float | None = None
    link: int | None = None
    planned_at_s: float | None = None
    duration_s: float | None = None
    operator: str = ""
    with_hand: bool = True
    notes: str = ""

    def timing(self) -> tuple[float, float]:
        """Return the planned interaction time and the session duration [s] of a session
        recorded from a robot or bus: as chosen, else the thesis's static timing (5 s
        of 12 s). Raises InputError when the planned time lies outside the session."""
        timing = default_timing("static")
        duration = timing.duration_s if self.duration_s is None else self.duration_s
        planned = timing.planned_at_s if self.planned_at_s is None else self.planned_at_s
        check_duration(duration)
        if not 0 <= planned < duration:
            raise InputError(f"planned interaction time {planned} s must lie within the "
                             f"session (0 to {duration} s)")
        return planned, duration


class Source(ABC):
    """A stream of samples of one session in session-file columns.

    A source class has a ``name`` (its registry key), a ``Config`` dataclass whose
    fields are its options (see :mod:`contactkit.recorder.sources`), the ``columns``
    it produces, and ``live``: true when the world paces it (a robot or a bus); a
    simulated source is not, and the capture paces it in real-time mode.

    :meth:`from_config` builds a source from its options and the protocol choices and
    resolves ``planned_at_s`` and ``duration_s`` [s] and ``nominal_rate_hz`` [Hz]
    (None when the source cannot know it beforehand). :meth:`metadata` returns the
    fields the source contributes to the session metadata (``source``,
    ``source_info``, ``simulator``) and is called again after the stream ends, so
    statistics gathered while streaming (frames, gaps, end reason) go in too.
    """

    name: ClassVar[str]
    Config: ClassVar[type]
    columns: ClassVar[list[str]]
    live: ClassVar[bool]
    choices: ProtocolChoices
    planned_at_s: float
    duration_s: float
    nominal_rate_hz: float | None = None

    @classmethod
    @abstractmethod
    def from_config(cls, config: Any, choices: ProtocolChoices) -> Source:
        """Return the source for options ``config`` (an instance of ``cls.Config``) and
        the protocol ``choices``; raise InputError for unusable options."""

    @abstractmethod
    def stream(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield chunks of rows (dict of equal-length arrays, ``t`` in s, increasing)."""

    @abstractmethod
    def metadata(self) -> dict[str, Any]:
        """Return the session-metadata fields this source contributes."""

    def session_meta(self) -> SessionMeta:
        """Return the metadata of the session this source records: the protocol choices,
        the resolved timing and rate, and the source's own fields."""
        c = self.choices
        return session_meta(
            action=c.action, condition=c.condition, pose=c.pose, target_pose=c.target_pose,
            speed_rad_s=c.speed_rad_s, link=c.link, planned_at_s=self.planned_at_s,
            nominal_rate_hz=self.nominal_rate_hz, operator=c.operator, notes=c.notes,
            with_hand=c.with_hand, **self.metadata())
