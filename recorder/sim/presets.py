"""The presets of ``recorder simulate``: how each draws its sessions (the list is in
:mod:`contactkit.recorder.sim.dataset`).

Apart from the dataset module, which runs the simulator (pinocchio), so that the command
line lists the preset names without importing it.
"""

from __future__ import annotations

from dataclasses import dataclass

from contactkit.recorder.protocol import POSES, START_POSE
from contactkit.schemas import ACTIONS


@dataclass(frozen=True)
class Preset:
    """How a preset draws its sessions. Speeds in rad/s, jitter in rad, rate in Hz."""

    name: str
    sessions: int
    condition: str
    poses: tuple[str, ...]
    pose_jitter_rad: float
    speed_range: tuple[float, float] | None = None
    rate_hz: float = 600.0
    duration_s: float | None = None
    robot_seed: int = 0
    variability: float = 1.0
    links: tuple[int, ...] | None = None
    free_motion: bool = False
    actions: tuple[str, ...] = ACTIONS


PRESETS: dict[str, Preset] = {
    "thesis-static": Preset("thesis-static", 1233, "static", tuple(POSES), 0.1),
    "thesis-dynamic": Preset("thesis-dynamic", 1380, "dynamic",
                             tuple(p for p in POSES if p != START_POSE), 0.1, (0.1, 0.5)),
    "smoke": Preset("smoke", 8, "static", ("A", "B"), 0.0, rate_hz=500.0),
    "default-static": Preset("default-static", 96, "static", tuple(POSES), 0.1, rate_hz=500.0),
    "default-dynamic": Preset("default-dynamic", 56, "dynamic",
                              tuple(p for p in POSES if p != START_POSE), 0.1, (0.2, 0.5),
                              rate_hz=500.0),
    "aug-real": Preset("aug-real", 256, "static", tuple(POSES), 0.1, rate_hz=500.0,
                       robot_seed=7, variability=1.5),
    "aug-sim": Preset("aug-sim", 512, "static", tuple(POSES), 0.1, rate_hz=500.0,
                      robot_seed=0, variability=1.0, links=(5, 6, 7)),
    "free-motion": Preset("free-motion", 96, "dynamic", tuple(POSES), 0.1, rate_hz=500.0,
                          duration_s=8.0, free_motion=True, actions=("none",)),
    "mixed-motion": Preset("mixed-motion", 128, "dynamic", tuple(POSES), 0.1, rate_hz=500.0,
                           duration_s=8.0, free_motion=True),
}
