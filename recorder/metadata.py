"""Session metadata: the one place a session's metadata document is assembled.

Every way of making a session (capture from any source, simulated datasets, array,
CAN-log, CSV and bag imports) calls :func:`session_meta` with the protocol's choices
and the fields its source contributes; the provenance (creation time, URDF hash,
tool version, a fresh session id unless one is given) is added here.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from contactkit.recorder.protocol import POSES, check_action, check_condition, pose_q
from contactkit.robots import DEFAULT_ROBOT, canonical_robot_name, get_robot
from contactkit.robots.spec import ArmDynamics
from contactkit.schemas import InputError, SessionMeta, new_session_id
from contactkit.schemas.session import (
    iter_session_batches,
    read_session_meta,
    write_session_batches,
)
from contactkit.util.paths import safe_name

N_LINKS = 7


def tool_version() -> str:
    """Return the installed contactkit version ("0+unknown" when not installed)."""
    import contactkit

    return contactkit.__version__


def utc_now() -> str:
    """Return the current UTC time in ISO 8601 with a Z suffix."""
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def session_meta(*, source: str, action: str, condition: str = "static",
                 pose: str | None = None, target_pose: str | None = None,
                 pose_q_rad: Sequence[float] | np.ndarray | None = None,
                 target_q_rad: Sequence[float] | np.ndarray | None = None,
                 speed_rad_s: float | None = None, link: int | None = None,
                 planned_at_s: float | None = None, nominal_rate_hz: float | None = None,
                 operator: str = "", notes: str = "", with_hand: bool = True,
                 robot: str = DEFAULT_ROBOT, session_id: str | None = None,
                 **source_fields: Any) -> SessionMeta:
    """Return checked session metadata with its provenance filled in.

    ``action``, ``condition`` and ``link`` (1-7) are checked (InputError otherwise).
    Thesis pose names (A-H) are upper-cased and their joint values [rad] come from
    thesis Table 3.1 unless ``pose_q_rad``/``target_q_rad`` give the values actually
    used (a simulated session's jittered pose). ``robot`` is the arm's registry name
    (:mod:`contactkit.robots`; InputError listing the known ones otherwise), whose URDF's
    hash is stored. ``session_id`` defaults to a fresh random id.
    ``source_fields`` are the fields a source contributes (``simulator``,
    ``source_info``, ``recovered``...), passed to :class:`SessionMeta` as they are.
    """
    check_action(action)
    check_condition(condition)
    robot = canonical_robot_name(robot)
    if link is not None and not 1 <= link <= N_LINKS:
        raise InputError(f"unknown link {link} (expected 1..{N_LINKS})")
    pose, target_pose = _pose_name(pose), _pose_name(target_pose)
    if pose_q_rad is None and pose in POSES:
        pose_q_rad = pose_q(pose)
    if target_q_rad is None and target_pose in POSES:
        target_q_rad = pose_q(target_pose)
    return SessionMeta(
        session_id=session_id or new_session_id(), source=source, action=action,
        condition=condition, pose=pose,
        pose_q=None if pose_q_rad is None else [float(v) for v in pose_q_rad],
        target_pose=target_pose,
        target_q=None if target_q_rad is None else [float(v) for v in target_q_rad],
        speed_rad_s=speed_rad_s, link=link, planned_at_s=planned_at_s,
        nominal_rate_hz=nominal_rate_hz, operator=operator, notes=notes,
        created_utc=utc_now(), robot=robot, with_hand=with_hand,
        urdf_sha256=get_robot(robot).urdf_sha256(with_hand),
        tool_version=tool_version(), **source_fields)


def _pose_name(name: str | None) -> str | None:
    """Return a thesis pose name (A-H, any case) upper-cased; any other name (a lab's own
    pose, checked as a safe name with the rest of the metadata) as it is."""
    if name is None or not isinstance(name, str):
        return name
    return name.upper() if name.upper() in POSES else name


def session_filename(meta: SessionMeta) -> str:
    """Return the file name of a session: condition, pose(s), action and short id.

    The metadata is checked first, so every part is within its domain; the name is a
    safe file-name component (raises :class:`InputError` otherwise).
    """
    meta.check()
    poses = meta.pose or "x"
    if meta.target_pose:
        poses += "to" + meta.target_pose
    return safe_name(f"{meta.condition}_{poses}_{meta.action}_{meta.session_id[:12]}.parquet",
                     "session file name")


def set_session_robot(path: str | Path, robot: str | None = None, *,
                      dynamics: ArmDynamics | None = None,
                      clear_dynamics: bool = False) -> SessionMeta:
    """Rewrite the session file at ``path`` so that its metadata names ``robot`` (with that
    robot's URDF hash; None: the arm it names) and carries the identified ``dynamics`` as
    values (checked for that arm and hand; InputError naming ``path`` otherwise), or, with
    ``clear_dynamics``, none (the nominal model); return the new metadata. Naming another
    arm drops the dynamics stored for the old one. The file is rewritten row group by row
    group into a temporary file that replaces it atomically, so a reader sees the old or
    the new session, never a mix; the samples are unchanged. This is how a session
    recorded before its arm was named (an FR3 captured as ``franka_panda``) is corrected,
    and how an identification is stored with it. A symbolic link is followed: its target
    is rewritten (the link stays a link) and keeps its permissions; a read-only file, and
    a link to nothing or to something that is not a regular file, are refused.
    """
    path = Path(path)
    meta, _ = read_session_meta(path)  # a regular file (through links), else InputError
    target = path.resolve()  # a link's target is edited, the link stays
    mode = stat.S_IMODE(target.stat().st_mode)
    if not mode & stat.S_IWUSR:
        raise InputError("is read-only: not changed (make it writable to correct it)", path)
    updated = meta.with_robot(robot)
    if clear_dynamics or dynamics is not None:
        updated = updated.with_dynamics(dynamics, path)
    write_session_batches(target, iter_session_batches(target), updated, overwrite=True)
    try:
        os.chmod(target, mode)  # the file keeps its permissions
    except OSError as err:
        raise InputError(f"corrected, but its permissions could not be restored "
                         f"({err.strerror})", path) from err
    return updated
