"""A session as a ROS 2 MCAP bag (``recorder export-mcap``), for Foxglove and Rerun.

Each sample becomes a ``sensor_msgs/JointState`` on ``/joint_states`` (q, dq, tau as
position, velocity, effort; joints named as the session robot names them,
``panda_joint1..7`` or ``fr3_joint1..7``), stamped with the sample's
time. Optional columns go on their own topics, one message per sample:
``/joint_states_desired`` (q_d, dq_d), ``/tau_ext_hat_filtered`` (JointState effort),
``geometry_msgs/WrenchStamped`` on
``/franka_robot_state_broadcaster/external_wrench_in_base_frame`` (the robot's
estimate) and ``/contactkit/applied_force`` (ground truth), ``std_msgs/Bool`` on
``/contactkit/contact`` and ``std_msgs/Int8`` on ``/contactkit/robot_mode`` (libfranka's
robot mode: 2 move, 4 reflex). The session metadata is one ``std_msgs/String`` (JSON) on
``/contactkit/session``. ``recorder import-bag`` reads all of it back.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from contactkit.recorder.importers.bags import (
    BOOL,
    EXPORT_TOPICS,
    INT8,
    JOINT_STATE,
    STRING,
    WRENCH_STAMPED,
)
from contactkit.robots import get_robot
from contactkit.robots.spec import ArmDynamics
from contactkit.schemas import InputError, Session, joint_columns, read_session
from contactkit.schemas.columns import FORCE_COLUMNS, WRENCH_HAT_COLUMNS
from contactkit.util.atomic import atomic_directory, atomic_write, scratch_directory


def _stamps_ns(t: np.ndarray, start_ns: int) -> np.ndarray:
    return start_ns + np.round(np.asarray(t) * 1e9).astype(np.int64)


def export_mcap(session_path: Path, out: Path, *, start_ns: int = 0,
                overwrite: bool = False, dynamics: ArmDynamics | None = None) -> Path:
    """Write the session at ``session_path`` as MCAP; return the MCAP file's path.

    ``out`` ending in ``.mcap`` is that one file; any other ``out`` is a ROS 2 bag
    directory (rosbag2's convention: a folder without suffix, holding ``metadata.yaml``
    and ``<name>.mcap``). Time stamps are ``start_ns`` plus the session time [ns]. The
    output is written aside and moved into place at the end (a failure leaves nothing);
    an existing ``out`` is replaced only with ``overwrite``, and a directory only when it
    is such a bag (:func:`is_mcap_bag`), never another folder named by mistake, and
    never the session file itself (a session named without a suffix). The metadata
    message carries the identified dynamics the session carries, or ``dynamics``
    (``--dynamics``) in their place (InputError for another arm's or hand's), so that
    ``recorder import`` gives them back."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    if os.path.exists(out) and session_path.exists() and os.path.samefile(out, session_path):
        raise InputError("is the session it exports: not replaced, even with --overwrite "
                         "(give --out)", out)
    session = read_session(session_path)
    if dynamics is not None:
        session.meta = session.meta.with_dynamics(dynamics, session_path)
    store = get_typestore(Stores.ROS2_HUMBLE)
    stamps = _stamps_ns(session.t, start_ns)
    if stamps[0] < 0:
        raise InputError(f"the session starts at {session.t[0]:.6g} s: MCAP time stamps "
                         "cannot be negative (shift the session's time to start at 0 s or "
                         "later)", session_path)
    if out.suffix.lower() == ".mcap":
        with atomic_write(out, overwrite=overwrite) as target, \
                scratch_directory(out) as scratch:
            bag = scratch / out.stem
            _write_bag(Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP), session,
                       store, stamps)
            with next(bag.glob("*.mcap")).open("rb") as written:
                shutil.copyfileobj(written, target.file)
        return out
    with atomic_directory(out, overwrite=overwrite, kind=is_mcap_bag,
                          what="ROS 2 bag directory") as bag:
        _write_bag(Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP), session,
                   store, stamps)
    return next(out.glob("*.mcap"))


def is_mcap_bag(path: Path) -> bool:
    """Return whether ``path`` is a ROS 2 bag directory as this exporter writes one: a
    folder holding ``metadata.yaml`` and ``.mcap`` files and nothing else."""
    try:
        entries = list(path.iterdir())
    except OSError:
        return False
    names = {e.name for e in entries}
    return "metadata.yaml" in names and all(
        e.is_file() and not e.is_symlink() and (e.name == "metadata.yaml" or e.suffix == ".mcap")
        for e in entries)


def _write_bag(bag: Any, session: Session, store: Any, stamps: np.ndarray) -> None:
    """Write the session's messages through the rosbags writer ``bag``."""
    with bag as writer:
        streams = _message_streams(session, store)
        connections = {topic: writer.add_connection(topic, msgtype, typestore=store)
                       for topic, (msgtype, _) in streams.items()}
        meta_conn = writer.add_connection(EXPORT_TOPICS["session"], STRING, typestore=store)
        writer.write(meta_conn, int(stamps[0]), store.serialize_cdr(
            store.types[STRING](data=session.meta.to_json()), STRING))
        for i, stamp in enumerate(stamps):
            header = _header(store, int(stamp))
            for topic, (msgtype, make) in streams.items():
                writer.write(connections[topic], int(stamp),
                             store.serialize_cdr(make(i, header), msgtype))


def _header(store: Any, stamp_ns: int) -> Any:
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return store.types["std_msgs/msg/Header"](
        stamp=store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id="")


def _block(session: Session, prefix: str) -> np.ndarray | None:
    names = joint_columns(prefix)
    return session.joints(prefix) if all(session.has(n) for n in names) else None


def _message_streams(session: Session, store: Any) -> dict[str, tuple[str, Any]]:
    """Return ``{topic: (msgtype, make(i, header))}`` for the columns the session has."""
    joint_state = store.types[JOINT_STATE]
    names = list(get_robot(session.meta.robot_setup(session.path).robot).joint_names)
    empty = np.zeros(0)
    q, dq, tau = session.q, session.dq, session.tau
    streams = {"/joint_states": (JOINT_STATE, lambda i, h: joint_state(
        header=h, name=names, position=q[i], velocity=dq[i], effort=tau[i]))}
    q_d, dq_d = _block(session, "q_d"), _block(session, "dq_d")
    if q_d is not None and dq_d is not None:
        streams[EXPORT_TOPICS["desired"]] = (JOINT_STATE, lambda i, h: joint_state(
            header=h, name=names, position=q_d[i], velocity=dq_d[i], effort=empty))
    hat = _block(session, "tau_ext_hat")
    if hat is not None:
        streams[EXPORT_TOPICS["tau_ext_hat"]] = (JOINT_STATE, lambda i, h: joint_state(
            header=h, name=names, position=empty, velocity=empty, effort=hat[i]))
    # not ``names``: the joint states' lambdas above read that name when called
    for key, columns in (("wrench_hat", WRENCH_HAT_COLUMNS), ("applied", FORCE_COLUMNS)):
        if all(session.has(n) for n in columns):
            values = np.column_stack([session.column(n) for n in columns])
            if values.shape[1] == 3:
                values = np.column_stack([values, np.zeros((len(values), 3))])
            streams[EXPORT_TOPICS[key]] = (WRENCH_STAMPED, _wrench_maker(store, values))
    if session.has("contact"):
        contact = session.column("contact")
        streams[EXPORT_TOPICS["contact"]] = (BOOL, lambda i, h: store.types[BOOL](
            data=bool(contact[i])))
    if session.has("robot_mode"):
        mode = session.column("robot_mode")
        streams[EXPORT_TOPICS["robot_mode"]] = (INT8, lambda i, h: store.types[INT8](
            data=int(mode[i])))
    return streams


def _wrench_maker(store: Any, values: np.ndarray) -> Any:
    vector, wrench = store.types["geometry_msgs/msg/Vector3"], store.types[
        "geometry_msgs/msg/Wrench"]
    stamped = store.types[WRENCH_STAMPED]

    def make(i: int, header: Any) -> Any:
        f = values[i]
        return stamped(header=header, wrench=wrench(force=vector(x=f[0], y=f[1], z=f[2]),
                                                    torque=vector(x=f[3], y=f[4], z=f[5])))

    return make
