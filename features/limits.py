"""The session robot's joint limits, and the check that a session stays within them.

:func:`robot_limits` is the one place that says where the limits come from: the
session robot's model (:mod:`contactkit.robots`).
"""

from __future__ import annotations

import numpy as np

from contactkit.errors import InputError
from contactkit.robots import JointLimits, get_robot
from contactkit.robots.dynamics import RobotChoice, override_robot
from contactkit.schemas import Session, SessionMeta

SPEED_MARGIN = 1.5
"""A session is unstable when a joint moves faster than this multiple of its speed limit."""
TORQUE_MARGIN = 1.5
"""... or when a measured torque exceeds this multiple of the joint's torque limit."""
POSITION_SLACK_RAD = 0.5
"""... or when a joint leaves its range by more than this [rad]."""


def robot_limits(meta: SessionMeta, robot: RobotChoice = None) -> JointLimits:
    """Return the joint limits of the robot a session with metadata ``meta`` names (or
    of ``robot``, a model used instead of the session's own)."""
    return get_robot(override_robot(robot) or meta.robot).limits


ROBOT_MODE_REFLEX = 4
"""libfranka's ``RobotMode::kReflex`` in a session's ``robot_mode`` column: the arm
stopped itself and its brakes hold it."""


def limit_violation(t: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray,
                    limits: JointLimits, mode: np.ndarray | None = None) -> str | None:
    """Return one line on the first sample beyond the robot's limits with their margins
    (:data:`SPEED_MARGIN`, :data:`TORQUE_MARGIN`, :data:`POSITION_SLACK_RAD`), or None.

    ``t`` [s] is (N,), ``q`` [rad], ``dq`` [rad/s] and ``tau`` [Nm] are (N, 7); ``mode``
    (N,) the ``robot_mode`` column where the session has one. Such a session is
    physically impossible for the arm: a simulation that blew up, or a corrupt or
    mis-scaled recording. The torque limit is the motors': samples after a reflex stop
    (``mode`` :data:`ROBOT_MODE_REFLEX`) are not held to it, as the brakes hold the arm
    and its torque sensors measure whatever a person still pushes with.
    """
    motors = np.ones(len(t), dtype=bool) if mode is None else mode != ROBOT_MODE_REFLEX
    checks = (
        ("dq", np.abs(dq) / (SPEED_MARGIN * limits.dq_max), "rad/s",
         SPEED_MARGIN * limits.dq_max),
        ("tau", np.abs(tau) / (TORQUE_MARGIN * limits.tau_max) * motors[:, None], "Nm",
         TORQUE_MARGIN * limits.tau_max),
        ("q", np.maximum(limits.q_min - POSITION_SLACK_RAD - q,
                         q - limits.q_max - POSITION_SLACK_RAD) + 1.0, "rad", None),
    )
    first = None
    for name, ratio, unit, bound in checks:
        with np.errstate(invalid="ignore"):
            beyond = ratio > 1.0
        if not beyond.any():
            continue
        row, joint = np.unravel_index(int(np.argmax(beyond)), beyond.shape)
        if first is not None and row >= first[0]:
            continue
        values = {"dq": dq, "tau": tau, "q": q}[name]
        limit = (f"{bound[joint]:.3g} {unit}" if bound is not None else
                 f"range {limits.q_min[joint]:.2f}..{limits.q_max[joint]:.2f} rad")
        first = (row, f"{name}_{joint + 1} = {values[row, joint]:.4g} {unit} at "
                      f"{t[row]:.3f} s (row {row}) is beyond the robot's limit ({limit})")
    return None if first is None else first[1]


def session_limit_violation(session: Session, robot: RobotChoice = None) -> str | None:
    """Return one line naming the column, value, time and row of the first sample of
    ``session`` beyond its robot's limits (``robot`` names the arm's model instead of
    the session's own), or None when every sample is within them or the robot's model is
    not available here (a plugin robot or URDF not installed: nothing to check)."""
    if not session.n_samples:
        return None
    try:
        limits = robot_limits(session.meta, robot)
    except InputError:
        return None
    mode = session.column("robot_mode") if session.has("robot_mode") else None
    return limit_violation(session.t, session.q, session.dq, session.tau, limits, mode)
