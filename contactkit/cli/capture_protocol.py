"""What ``recorder capture`` offers before any source is loaded: the protocol's option
types and flags, the :class:`CaptureExtension` through which the ``recorder``
composition root adds options and a listener, and the one-line help of ``capture`` and
``sources``, which ``recorder --help`` lists without building them
(:mod:`contactkit.cli.capture` builds them, loading every source).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from contactkit.recorder.protocol import POSES
from contactkit.schemas import ACTIONS, SessionMeta
from contactkit.util.params import Param

if TYPE_CHECKING:
    from contactkit.recorder.capture.record import CaptureListener
    from contactkit.recorder.sources import Source

Condition = Literal["static", "dynamic"]
Action = Literal[ACTIONS]  # type: ignore[valid-type]
if TYPE_CHECKING:  # the poses are known at run time: a name for the type checker
    Pose = str
else:
    Pose = Literal[tuple(POSES)]


@dataclass(frozen=True)
class CaptureExtension:
    """Extra ``capture`` options and what to do with them: ``parameters`` are declared
    like a source's options and become flags; ``start`` is called with their values
    (declared defaults for those not given), the session metadata and the source before
    recording; it returns a listener that sees every chunk as it is recorded (or None to
    stay out)."""

    parameters: tuple[Param, ...]
    start: Callable[[dict[str, Any], SessionMeta, Source], CaptureListener | None]


PROTOCOL_FLAGS = {"--pose", "--action", "--condition", "--target-pose", "--speed",
                  "--link", "--planned-at", "--duration", "--operator", "--hand", "--no-hand",
                  "--notes", "--out", "--overwrite", "--realtime", "--viewer", "--save-rrd",
                  "--help"}
"""The options of the protocol itself (the ``capture`` function's own), which no source
or extension may declare."""


CAPTURE_SUMMARY = "Record one session and print the written file's path."
SOURCES_SUMMARY = ("List the data sources (built in or installed by other packages) and "
                   "their options, for recorder capture --source NAME.")
