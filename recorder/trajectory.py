"""Joint trajectories as CSV files: what ``recorder excite`` writes and what the simulated
source (``recorder capture --source sim --trajectory FILE``) and a lab's own controller
follow.

The file is text, one sample a row, comma-separated, with a header row::

    # contactkit trajectory; robot: panda
    t,q_1,...,q_7,dq_1,...,dq_7,ddq_1,...,ddq_7

``t`` [s] from 0, strictly increasing (1 kHz as written); ``q`` [rad], ``dq`` [rad/s],
``ddq`` [rad/s^2] joint 1 first. The first line, a comment naming the arm the
trajectory was made for, is optional; ``numpy.loadtxt(path, delimiter=",",
skiprows=2)`` reads the samples.

A trajectory file is untrusted input: :func:`read_trajectory` is its one reader and
refuses, in one :class:`~contactkit.errors.InputError` line naming the file, a file that
is too large, a wrong header or column count, a value that is not finite, times that
do not increase, a trajectory made for another arm, one that leaves the arm's position,
velocity, acceleration or jerk limits, or one not at rest at both ends.
"""

from __future__ import annotations

import hashlib
import io
import os
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contactkit.errors import InputError
from contactkit.robots import N_JOINTS, JointLimits, canonical_robot_name, get_robot
from contactkit.util.atomic import atomic_write

COLUMNS = ("t", *(f"{kind}_{j}" for kind in ("q", "dq", "ddq")
                  for j in range(1, N_JOINTS + 1)))
"""The 22 columns of a trajectory file, in order."""
COMMENT = "# contactkit trajectory; robot: "
MAX_DURATION_S = 600.0
"""The longest trajectory a file may hold [s]: ten minutes."""
MAX_ROWS = round(MAX_DURATION_S * 1000.0) + 1
MAX_BYTES = 256 * 1024 * 1024
"""The largest trajectory file read [bytes] (ten minutes at 1 kHz take about 160 MB)."""
REST_TOLERANCE = 1e-6
"""How close to zero dq [rad/s] and ddq [rad/s^2] must be at both ends."""
LIMIT_TOLERANCE = 1e-9
"""Relative slack on the limits, for values rounded when they were written."""


@dataclass(frozen=True)
class Trajectory:
    """Joint samples: ``t`` (N,) [s], ``q`` [rad], ``dq`` [rad/s], ``ddq`` [rad/s^2],
    each (N, 7); ``robot`` the arm it was made for (None when the file does not say)."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    robot: str | None = None

    @property
    def duration_s(self) -> float:
        """The time of the last sample [s]."""
        return float(self.t[-1])

    def sha256(self) -> str:
        """Return the SHA-256 (hex) of the samples (t, q, dq, ddq as float64 rows)."""
        table = np.column_stack([self.t, self.q, self.dq, self.ddq])
        return hashlib.sha256(np.ascontiguousarray(table).tobytes()).hexdigest()

    def jerk(self) -> np.ndarray:
        """Return the jerk [rad/s^3] (N - 1, 7): ddq's finite differences between
        successive samples."""
        return np.diff(self.ddq, axis=0) / np.diff(self.t)[:, None]


def write_trajectory(path: Path, trajectory: Trajectory, *, overwrite: bool = False) -> Path:
    """Write ``trajectory`` as a CSV file at ``path`` atomically (the comment line
    names its robot when it has one); return the path. An existing file is replaced only
    with ``overwrite``."""
    table = np.column_stack([trajectory.t, trajectory.q, trajectory.dq, trajectory.ddq])
    buffer = io.StringIO()
    if trajectory.robot is not None:
        buffer.write(COMMENT + trajectory.robot + "\n")
    buffer.write(",".join(COLUMNS) + "\n")
    np.savetxt(buffer, table, fmt="%.10g", delimiter=",")
    with atomic_write(path, overwrite=overwrite) as tmp:
        tmp.file.write(buffer.getvalue().encode())
    return Path(path)


def _read_text(path: Path) -> str:
    """Return the text of regular file ``path``, at most :data:`MAX_BYTES`; raise
    InputError otherwise."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as err:
        raise InputError(f"cannot read the trajectory: {err.strerror or err}", path) from err
    with os.fdopen(fd, "rb") as handle:
        info = os.fstat(handle.fileno())
        if not stat.S_ISREG(info.st_mode):
            raise InputError("the trajectory is not a regular file", path)
        if info.st_size > MAX_BYTES:
            raise InputError(f"the trajectory file has {info.st_size} bytes, more than "
                             f"{MAX_BYTES} ({MAX_DURATION_S:g} s at 1 kHz)", path)
        data = handle.read(MAX_BYTES + 1)
    if len(data) > MAX_BYTES:
        raise InputError(f"the trajectory file has more than {MAX_BYTES} bytes", path)
    try:
        return data.decode("ascii")
    except UnicodeDecodeError as err:
        raise InputError("the trajectory is not a text CSV file (a byte that is not "
                         f"ASCII at offset {err.start})", path) from err


def read_trajectory(path: Path, robot: str) -> Trajectory:
    """Return the trajectory in CSV file ``path`` for arm ``robot`` (a registry name),
    checked: see the module docstring. Raises one InputError line naming the file."""
    robot = canonical_robot_name(robot)
    lines = _read_text(path).splitlines()
    named = None
    if lines and lines[0].startswith("#"):
        first = lines.pop(0)
        if first.startswith(COMMENT):
            named = first[len(COMMENT):].strip()
    if not lines or [c.strip() for c in lines[0].split(",")] != list(COLUMNS):
        raise InputError(f"the trajectory's header must be the {len(COLUMNS)} columns "
                         f"{','.join(COLUMNS[:2])},...,{COLUMNS[-1]}", path)
    if named is not None and _same_robot(named) != robot:
        raise InputError(f"the trajectory was made for robot {named!r}, not {robot!r}", path)
    rows = lines[1:]
    if len(rows) < 2:
        raise InputError("the trajectory needs at least 2 samples", path)
    if len(rows) > MAX_ROWS:
        raise InputError(f"the trajectory has {len(rows)} samples, more than {MAX_ROWS}",
                         path)
    for number, row in enumerate(rows, start=2 + (named is not None)):
        if row.count(",") != len(COLUMNS) - 1:
            raise InputError(f"line {number} of the trajectory has {row.count(',') + 1} "
                             f"columns, not {len(COLUMNS)}", path)
    try:
        table = np.loadtxt(io.StringIO("\n".join(rows)), delimiter=",", ndmin=2,
                           dtype=float)
    except ValueError as err:
        raise InputError(f"the trajectory holds a value that is not a number "
                         f"({str(err).splitlines()[-1][:80]})", path) from err
    if not np.isfinite(table).all():
        raise InputError("the trajectory holds a value that is not finite", path)
    n = N_JOINTS
    trajectory = Trajectory(t=table[:, 0], q=table[:, 1:1 + n], dq=table[:, 1 + n:1 + 2 * n],
                            ddq=table[:, 1 + 2 * n:], robot=named)
    problem = trajectory_problem(trajectory, get_robot(robot).limits)
    if problem:
        raise InputError(f"{problem} (robot {robot})", path)
    return trajectory


def _same_robot(named: str) -> str | None:
    """Return the registry name of the robot a file names, None for one unknown here."""
    try:
        return canonical_robot_name(named)
    except InputError:
        return None


def trajectory_problem(trajectory: Trajectory, limits: JointLimits) -> str | None:
    """Return what makes ``trajectory`` unusable on an arm with ``limits`` (times that
    do not start at 0 or do not increase, a duration over :data:`MAX_DURATION_S`, a
    sample outside the position, velocity, acceleration or jerk limits, not at rest at
    either end), or None when it is usable."""
    t = trajectory.t
    if t[0] != 0.0:
        return f"the trajectory's time starts at {t[0]:g} s, not 0"
    steps = np.diff(t)
    if not (steps > 0).all():
        return f"the trajectory's time does not increase at sample {int(np.argmin(steps > 0)) + 1}"
    if t[-1] > MAX_DURATION_S:
        return f"the trajectory lasts {t[-1]:g} s, more than {MAX_DURATION_S:g} s"
    checks = (
        ("position", trajectory.q, limits.q_min, limits.q_max, "rad"),
        ("velocity", trajectory.dq, -limits.dq_max, limits.dq_max, "rad/s"),
        ("acceleration", trajectory.ddq, -limits.ddq_max, limits.ddq_max, "rad/s^2"),
        ("jerk", trajectory.jerk(), -limits.jerk_max, limits.jerk_max, "rad/s^3"),
    )
    for what, values, low, high, unit in checks:
        slack = LIMIT_TOLERANCE * np.maximum(np.abs(low), np.abs(high))
        outside = (values < low - slack) | (values > high + slack)
        if outside.any():
            row, joint = np.argwhere(outside)[0]
            return (f"the trajectory leaves joint {joint + 1}'s {what} limits at "
                    f"t = {t[row]:.3f} s ({values[row, joint]:.4g} {unit}, limits "
                    f"{low[joint]:.4g} to {high[joint]:.4g})")
    for end, row in (("start", 0), ("end", -1)):
        moving = max(np.abs(trajectory.dq[row]).max(), np.abs(trajectory.ddq[row]).max())
        if moving > REST_TOLERANCE:
            return (f"the trajectory is not at rest at its {end} (dq and ddq must be 0, "
                    f"found {moving:.3g})")
    return None
