"""The capture protocol of the thesis (section 3.2): poses, conditions and timing.

Poses A-H are Table 3.1 of the thesis [rad]. In the static condition the robot
holds a pose and the person touches a named link; in the dynamic condition it
moves from pose A to a target pose and the person touches it mid-motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactkit.schemas import ACTIONS, CONDITIONS, InputError

POSES: dict[str, tuple[float, ...]] = {
    "A": (0.0, -0.78, 0.0, -2.36, 0.0, 1.57, 0.78),
    "B": (-1.92, -0.26, 2.72, -1.71, 0.46, 2.8, -1.0),
    "C": (0.24, 1.0, 0.37, -0.63, -0.34, 2.90, 0.84),
    "D": (-0.8, 1.4, 1.0, -1.5, -1.5, 3.75, 2.0),
    "E": (-1.0, 0.0, 1.8, -2.8, -0.1, 3.0, 0.75),
    "F": (-0.4, 1.6, 1.3, -1.9, -0.4, 1.8, -0.8),
    "G": (0.05, 0.32, 0.34, -0.89, -1.52, 3.2, 2.3),
    "H": (0.0, 1.0, 0.85, -0.8, -1.83, 2.5, 1.0),
}
START_POSE = "A"
HOLD_BEFORE_S = 3.0
STATIC_PHASE_S = 4.0
HOLD_AFTER_S = 5.0
MAX_ONSET_DELAY_S = 0.25
MAX_DURATION_S = 24 * 3600.0
"""The longest session a capture or simulation may be asked for [s]: a day (hour-long
sessions are supported; a longer one is a typo or a unit error)."""


def pose_q(name: str) -> np.ndarray:
    """Return the joint positions [rad] of pose ``name`` (A-H), or raise InputError."""
    key = name.upper()
    if key not in POSES:
        raise InputError(f"unknown pose {name!r} (expected one of {', '.join(POSES)})")
    return np.array(POSES[key])


def check_duration(duration_s: float) -> float:
    """Return ``duration_s`` [s] when it is a usable session length (more than 0, at
    most :data:`MAX_DURATION_S`); raise one InputError line otherwise (NaN included)."""
    if not 0.0 < duration_s <= MAX_DURATION_S:
        raise InputError(f"duration must be positive and at most {MAX_DURATION_S:g} s "
                         f"(a day), got {duration_s} s")
    return float(duration_s)


def check_action(action: str) -> str:
    """Return ``action`` if it is a known class, else raise InputError."""
    if action not in ACTIONS:
        raise InputError(f"unknown action {action!r} (expected one of {', '.join(ACTIONS)})")
    return action


def check_condition(condition: str) -> str:
    """Return ``condition`` if it is static or dynamic, else raise InputError."""
    if condition not in CONDITIONS:
        raise InputError(f"unknown condition {condition!r} (expected static or dynamic)")
    return condition


def motion_duration_s(q_start: np.ndarray, q_end: np.ndarray, speed_rad_s: float) -> float:
    """Return the duration [s] of a move so that the joint that travels furthest does so
    at an average speed of ``speed_rad_s`` [rad/s] (no joint is faster on average)."""
    if speed_rad_s <= 0:
        raise InputError(f"speed must be positive, got {speed_rad_s} rad/s")
    return float(np.max(np.abs(q_end - q_start)) / speed_rad_s)


@dataclass(frozen=True)
class Timing:
    """Session timing [s]: total duration, planned interaction time and motion phase."""

    duration_s: float
    planned_at_s: float
    motion_start_s: float
    motion_duration_s: float


def default_timing(condition: str, motion_s: float = 0.0) -> Timing:
    """Return the thesis timing (section 5.3.3): 3 s hold, a 4 s phase (static) or the
    motion (dynamic) with the interaction planned at its midpoint, then a 5 s hold."""
    phase = STATIC_PHASE_S if condition == "static" else motion_s
    return Timing(duration_s=HOLD_BEFORE_S + phase + HOLD_AFTER_S,
                  planned_at_s=HOLD_BEFORE_S + phase / 2.0,
                  motion_start_s=HOLD_BEFORE_S,
                  motion_duration_s=0.0 if condition == "static" else motion_s)
