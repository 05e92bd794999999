"""Writing real ROS bags from a session with rosbags' own writers (tests and benchmarks).

The joint stream goes out as ``franka_ros``/``franka_ros2`` publish it: ROS 1
``franka_msgs/FrankaState`` on ``/franka_state_controller/franka_states``, ROS 2
``franka_msgs/msg/FrankaRobotState`` on ``/franka_robot_state_broadcaster/robot_state``
(sqlite3 or MCAP), with the real franka_msgs definitions bundled in contactkit.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

import numpy as np

from contactkit.recorder.importers.bags import default_typestore
from contactkit.schemas import Session

ROS1_TOPIC = "/franka_state_controller/franka_states"
ROS2_TOPIC = "/franka_robot_state_broadcaster/robot_state"
START_NS = 1_700_000_000_000_000_000
NUMPY = {"float64": np.float64, "float32": np.float32, "uint8": np.uint8, "int8": np.int8,
         "uint32": np.uint32, "int32": np.int32, "uint64": np.uint64, "int64": np.int64,
         "uint16": np.uint16, "int16": np.int16, "bool": np.bool_}


def zero_message(store: Any, typename: str, **fields: Any) -> Any:
    """Return a ``typename`` message with every field zero or empty, except ``fields``."""
    values = {}
    for name, (kind, desc) in store.fielddefs[typename][1]:
        if name in fields:
            values[name] = fields[name]
        else:
            values[name] = _zero(store, kind.value, desc)
    return store.types[typename](**values)


def _zero(store: Any, kind: int, desc: Any) -> Any:
    if kind == 1:  # base type
        return "" if desc[0] == "string" else (False if desc[0] == "bool" else 0)
    if kind == 2:  # nested message
        return zero_message(store, desc)
    (inner_kind, inner), size = desc
    if inner_kind == 1 and inner[0] != "string":
        return np.zeros(size, NUMPY[inner[0]])
    return [_zero(store, inner_kind, inner) for _ in range(size)]


def _header(store: Any, stamp_ns: int, ros1: bool) -> Any:
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    stamp = store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    if ros1:
        return store.types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="")
    return store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="")


def _joint_state(store: Any, header: Any, position, velocity, effort) -> Any:
    return store.types["sensor_msgs/msg/JointState"](
        header=header, name=[f"fr3_joint{i}" for i in range(1, 8)], position=position,
        velocity=velocity, effort=effort)


def franka_messages(session: Session, ros1: bool, robot_mode: int = 2,
                    stamps_ns: np.ndarray | None = None):
    """Yield ``(stamp_ns, message)`` for each sample of ``session``: q, dq, tau, q_d, dq_d
    and tau_ext_hat (where the session has them) in FrankaState or FrankaRobotState.
    ``stamps_ns`` replaces the time stamps (default: a fixed start plus session time)."""
    store = default_typestore(ros1)
    stamps = START_NS + np.round(session.t * 1e9).astype(np.int64) if stamps_ns is None \
        else np.asarray(stamps_ns, dtype=np.int64)
    q, dq, tau = session.q, session.dq, session.tau
    n = len(stamps)
    q_d = session.joints("q_d") if session.has("q_d_1") else np.zeros((n, 7))
    dq_d = session.joints("dq_d") if session.has("dq_d_1") else np.zeros((n, 7))
    hat = session.joints("tau_ext_hat") if session.has("tau_ext_hat_1") else np.zeros((n, 7))
    empty = np.zeros(0)
    for i, stamp in enumerate(stamps):
        header = _header(store, int(stamp), ros1)
        if ros1:
            msg = zero_message(store, "franka_msgs/msg/FrankaState", header=header, q=q[i],
                               dq=dq[i], tau_J=tau[i], q_d=q_d[i], dq_d=dq_d[i],
                               tau_ext_hat_filtered=hat[i], robot_mode=robot_mode,
                               control_command_success_rate=1.0, time=float(session.t[i]))
        else:
            msg = zero_message(
                store, "franka_msgs/msg/FrankaRobotState", header=header,
                measured_joint_state=_joint_state(store, header, q[i], dq[i], tau[i]),
                desired_joint_state=_joint_state(store, header, q_d[i], dq_d[i], empty),
                tau_ext_hat_filtered=_joint_state(store, header, empty, empty, hat[i]),
                robot_mode=robot_mode, control_command_success_rate=1.0,
                time=float(session.t[i]))
        yield int(stamp), msg


def write_bag(session: Session, out: Path, kind: str, *, labels: list[tuple[float, Any]] = (),
              label_topic: str = "/labels", strip_definitions: bool = False,
              stamps_ns: np.ndarray | None = None) -> Path:
    """Write ``session`` as a bag of ``kind`` (ros1, sqlite3 or mcap) at ``out`` and return
    the path to open. ``labels`` are ``(session time [s], str or bool)`` on ``label_topic``;
    ``strip_definitions`` removes the message definitions from a sqlite3 bag (as in ROS 2
    bags before Iron). ``stamps_ns`` replaces the messages' time stamps [ns]."""
    ros1 = kind == "ros1"
    store = default_typestore(ros1)
    msgtype = "franka_msgs/msg/FrankaState" if ros1 else "franka_msgs/msg/FrankaRobotState"
    label_type = None
    if labels:
        label_type = "std_msgs/msg/Bool" if isinstance(labels[0][1], bool) else \
            "std_msgs/msg/String"
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    if ros1:
        from rosbags.rosbag1 import Writer
        writer = Writer(out)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer
        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(out, version=9, storage_plugin=plugin)
    pending = sorted(labels, key=lambda x: x[0])
    with writer:
        topic = ROS1_TOPIC if ros1 else ROS2_TOPIC
        conn = writer.add_connection(topic, msgtype, typestore=store)
        label_conn = None if label_type is None else writer.add_connection(
            label_topic, label_type, typestore=store)
        for stamp, msg in franka_messages(session, ros1, stamps_ns=stamps_ns):
            while pending and START_NS + round(pending[0][0] * 1e9) <= stamp:
                _, data = pending.pop(0)
                writer.write(label_conn, stamp, serialize(store.types[label_type](data=data),
                                                          label_type))
            writer.write(conn, stamp, serialize(msg, msgtype))
    if strip_definitions:
        db = next(out.glob("*.db3"))
        with sqlite3.connect(db) as con:
            con.execute("DELETE FROM message_definitions")
    return out
