"""The columns of a session file (format v1): names, Arrow types, the hard bounds on
values and the time rule, checked where data enter and on read.

Columns (flat, so Polars, DuckDB, pandas and PlotJuggler open the file directly;
joints are numbered 1..7 as in the thesis):

=====================  =========  =====================================================
column                 unit       meaning
=====================  =========  =====================================================
``t``                  s          time since session start, strictly increasing
``q_1..q_7``           rad        measured joint positions
``dq_1..dq_7``         rad/s      measured joint velocities
``tau_1..tau_7``       Nm         measured link-side joint torque, gravity included
                                  (libfranka's ``tau_J``)
``q_d_1..q_d_7``       rad        optional: commanded joint positions
``dq_d_1..dq_d_7``     rad/s      optional: commanded joint velocities
``tau_ext_hat_1..7``   Nm         optional: the robot's own external-torque estimate
                                  (libfranka ``tau_ext_hat_filtered``; its sign is
                                  opposite to the momentum-observer residual)
``f_ext_x/y/z``        N          optional: ground-truth applied force, world frame
``contact``            bool       optional: ground truth, a person is touching the arm
``f_ext_hat_x/y/z``    N          optional: the robot's own estimate of the external
``m_ext_hat_x/y/z``    Nm         wrench at the stiffness frame, base frame (libfranka
                                  ``O_F_ext_hat_K``)
``robot_mode``         int8       optional: libfranka ``RobotMode`` (0 other, 1 idle,
                                  2 move, 3 guiding, 4 reflex, 5 user stopped, 6
                                  automatic error recovery)
``command_success_rate`` 1        optional: libfranka ``control_command_success_rate``
=====================  =========  =====================================================

The metadata is :mod:`contactkit.schemas.metadata`; reading and writing files,
:mod:`contactkit.schemas.session`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from contactkit.errors import InputError
from contactkit.robots.spec import N_JOINTS


def joint_columns(prefix: str, n: int = N_JOINTS) -> list[str]:
    """Return the column names ``prefix_1 .. prefix_n`` (joints numbered from 1)."""
    return [f"{prefix}_{i}" for i in range(1, n + 1)]


REQUIRED_JOINT_PREFIXES = ("q", "dq", "tau")
OPTIONAL_JOINT_PREFIXES = ("q_d", "dq_d", "tau_ext_hat")
FORCE_COLUMNS = ("f_ext_x", "f_ext_y", "f_ext_z")
WRENCH_HAT_COLUMNS = ("f_ext_hat_x", "f_ext_hat_y", "f_ext_hat_z", "m_ext_hat_x", "m_ext_hat_y",
                      "m_ext_hat_z")
REQUIRED_COLUMNS = ["t", *[c for p in REQUIRED_JOINT_PREFIXES for c in joint_columns(p)]]
OPTIONAL_FLOAT_COLUMNS = [
    *[c for p in OPTIONAL_JOINT_PREFIXES for c in joint_columns(p)],
    *FORCE_COLUMNS,
    *WRENCH_HAT_COLUMNS,
    "command_success_rate",
]
OPTIONAL_COLUMNS = [*OPTIONAL_FLOAT_COLUMNS, "contact", "robot_mode"]
COLUMN_ORDER = REQUIRED_COLUMNS + OPTIONAL_COLUMNS
ALL_JOINT_PREFIXES = REQUIRED_JOINT_PREFIXES + OPTIONAL_JOINT_PREFIXES


def column_type(name: str) -> pa.DataType:
    """Return the Arrow type of a session column (``contact`` is bool, ``robot_mode`` int8,
    the rest float64)."""
    if name == "contact":
        return pa.bool_()
    return pa.int8() if name == "robot_mode" else pa.float64()



def column_array(column: pa.ChunkedArray) -> np.ndarray:
    """Return a null-free float64 or boolean column as numpy, as ``column.to_numpy()``
    does (zero-copy and read-only for one chunk, a copy for several) but without
    pyarrow's pandas bridge: ``to_numpy`` imports pandas (pyarrow 26; about 60 MB and
    half a second of start-up for ``recorder info``)."""
    chunks = [_chunk_array(chunk) for chunk in column.chunks]
    if len(chunks) == 1:
        return chunks[0]
    if not chunks:
        return np.zeros(0, dtype=bool if pa.types.is_boolean(column.type) else float)
    return np.concatenate(chunks)


def _chunk_array(chunk: pa.Array) -> np.ndarray:
    if pa.types.is_boolean(chunk.type):  # bit-packed, least significant bit first
        if not len(chunk):
            return np.zeros(0, dtype=bool)
        bits = np.unpackbits(np.frombuffer(chunk.buffers()[1], np.uint8), bitorder="little")
        return bits[chunk.offset:chunk.offset + len(chunk)].astype(bool)
    return np.from_dlpack(chunk)



HARD_LIMITS = {"q": 100.0, "q_d": 100.0, "dq": 1000.0, "dq_d": 1000.0, "tau": 1e4,
               "tau_ext_hat": 1e4, "f_ext": 1e5, "f_ext_hat": 1e5, "m_ext_hat": 1e4}
"""Bounds no robot arm's measurement reaches, per column prefix (q [rad], dq [rad/s],
tau [Nm], forces [N], moments [Nm]): a value beyond one is refused where data enter
and on read, naming the column and row. The session robot's own limits (with a
margin) are far lower; values beyond those are flagged by ``recorder stats --deep``
and refused by the simulator."""


def hard_limit(column: str) -> float | None:
    """Return the hard bound on ``|value|`` of a session column (None: no bound)."""
    prefix = column.rsplit("_", 1)[0]
    return HARD_LIMITS.get(prefix)


MAX_STEP_S = 10.0
"""The longest step between two samples [s] a session may hold. Real recordings step
0.35-8.8 ms (host-stamped FR3 logs 0.35-5 ms, the Gaz log 0.7-8.8 ms, MindLab 5 ms); a
longer step is a time jump (a clock switched from sim time to wall time, a log
restarted, a corrupt stamp), refused where data enter rather than read as one
session of years. Steps above 3x the median but within this bound are gaps, counted
by :func:`contactkit.features.timing.sampling_stats`; after a step longer than
:data:`contactkit.features.timing.RESTART_STEP_S` (0.1 s) the feature chain and the
contact detector restart."""
MIN_STEP_S = 1e-6
"""The shortest step between two samples [s] a session may hold (1 us; real recordings
step 0.35 ms or more): shorter steps are corrupt stamps that no viewer or bag can tell
apart (Rerun and MCAP count time in nanoseconds)."""
MAX_ABS_T_S = 1e10
"""The largest time stamp [s] a session may hold (about 300 years; sessions start at
0 s, epoch stamps are 1.7e9 s): larger values overflow time arithmetic."""


def check_times(t: np.ndarray, path: str | Path | None = None, offset: int = 0,
                last_t: float | None = None) -> None:
    """Check the time rule on time stamps ``t`` [s]: finite, within
    :data:`MAX_ABS_T_S`, strictly increasing, no step shorter than :data:`MIN_STEP_S` or
    longer than :data:`MAX_STEP_S`.
    ``last_t`` is the stamp before ``t[0]`` (chunked reading) and ``offset`` the row of
    ``t[0]`` in the file. Raises one :class:`InputError` line naming the row."""
    t = np.asarray(t, dtype=float)
    big = ~(np.abs(t) <= MAX_ABS_T_S)
    if big.any():
        row = int(np.argmax(big))
        raise InputError(f"time stamp {t[row]:.6g} s at row {offset + row} is beyond "
                         f"{MAX_ABS_T_S:.0e} s", path)
    steps = np.diff(t) if last_t is None else np.diff(t, prepend=last_t)
    first = offset if last_t is None else offset - 1
    if (steps <= 0).any():
        row = int(np.argmax(steps <= 0)) + 1
        before = t[row - 1] if last_t is None else np.r_[last_t, t][row - 1]
        here = t[row] if last_t is None else t[row - 1]
        raise InputError(f"t is not strictly increasing at row {first + row} "
                         f"(t={here:.6f} s after {before:.6f} s)", path)
    if (steps < MIN_STEP_S).any():
        row = int(np.argmax(steps < MIN_STEP_S)) + 1
        raise InputError(f"time steps by {steps[row - 1]:.6g} s at row {first + row} (less "
                         f"than {MIN_STEP_S:g} s between samples: corrupt time stamps)", path)
    if (steps > MAX_STEP_S).any():
        row = int(np.argmax(steps > MAX_STEP_S)) + 1
        raise InputError(f"time jumps by {steps[row - 1]:.6g} s at row {first + row} (more "
                         f"than {MAX_STEP_S:g} s between samples: a clock switch or a "
                         "restarted log; split the recording there)", path)


def check_time_range(first: float, last: float, path: str | Path | None = None) -> None:
    """Check a session's first and last time stamps [s] (from its footer or its first
    and last rows) against the time rule's bounds: finite, within :data:`MAX_ABS_T_S`,
    the last after the first. Raises one :class:`InputError` line naming ``path``; a
    reader that needs only the span (an index, a replay's timeline) checks it so."""
    for which, value in (("first", first), ("last", last)):
        if not abs(value) <= MAX_ABS_T_S:
            raise InputError(f"the {which} time stamp {value:.6g} s is not finite or beyond "
                             f"{MAX_ABS_T_S:.0e} s", path)
    if not last >= first:
        raise InputError(f"the last time stamp {last:.6g} s is before the first "
                         f"{first:.6g} s", path)


def check_joint_count(names: list[str], path: str | Path | None) -> None:
    """Raise :class:`InputError` when column ``names`` number a joint prefix's columns
    other than 1..7 (too many, or a contiguous run of another length)."""
    for prefix in ALL_JOINT_PREFIXES:
        found = sorted(int(n[len(prefix) + 1:]) for n in names
                       if n.startswith(prefix + "_") and n[len(prefix) + 1:].isdigit())
        contiguous = found == list(range(1, len(found) + 1))
        if found and (found[-1] > N_JOINTS or (contiguous and len(found) != N_JOINTS)):
            raise InputError(f"wrong joint count: columns {prefix}_{found[0]}..{prefix}_"
                             f"{found[-1]} ({len(found)} joints), expected {prefix}_1.."
                             f"{prefix}_{N_JOINTS}", path)
