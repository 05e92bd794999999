"""Importing ROS bags (ROS 1 ``.bag``, ROS 2 sqlite3 and MCAP) as sessions.

Built on ``rosbags`` (pure Python, no ROS installation). A bag's joint stream is one
topic of one of these types:

- ``franka_msgs/FrankaState`` (ROS 1, ``franka_ros``: ``/franka_state_controller/franka_states``);
- ``franka_msgs/msg/FrankaRobotState`` (ROS 2, ``franka_ros2``:
  ``/franka_robot_state_broadcaster/robot_state``);
- ``sensor_msgs/JointState`` (``/joint_states`` and friends), where effort is tau_J.

Message definitions come from the bag where it stores them (ROS 1 always, ROS 2
MCAP usually); otherwise the ROS 1 Noetic or ROS 2 Humble standard types plus the
Franka definitions bundled in ``recorder/data/ros*-franka_msgs`` are used.

Time comes from the message headers; where they are zero or not increasing, from
the time the bag recorded each message. ``source_info.time_source`` says which.
A bag that ends early (a crashed recorder) keeps every message that can be read,
and ``source_info.read_error`` says where reading stopped.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from contactkit.recorder.bag_salvage import SalvageReader
from contactkit.recorder.importer import write_imported_session
from contactkit.recorder.metadata import session_meta
from contactkit.schemas import InputError, SessionMeta, joint_columns
from contactkit.schemas.session import WRENCH_HAT_COLUMNS
from contactkit.schemas.timing import sampling_stats
from contactkit.util.parallel import map_ordered, split_problems
from contactkit.util.progress import ProgressCallback

FRANKA_STATE = "franka_msgs/msg/FrankaState"
FRANKA_ROBOT_STATE = "franka_msgs/msg/FrankaRobotState"
JOINT_STATE = "sensor_msgs/msg/JointState"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
STRING = "std_msgs/msg/String"
BOOL = "std_msgs/msg/Bool"
STATE_TYPES = (FRANKA_ROBOT_STATE, FRANKA_STATE, JOINT_STATE)
DEFAULT_TOPICS = ("/franka_robot_state_broadcaster/robot_state",
                  "/franka_state_controller/franka_states",
                  "/franka_state_controller/joint_states", "/joint_states")
# Written by export-mcap beside /joint_states, read back by the importer.
EXPORT_TOPICS = {"desired": "/joint_states_desired", "tau_ext_hat": "/tau_ext_hat_filtered",
                 "wrench_hat": "/franka_robot_state_broadcaster/external_wrench_in_base_frame",
                 "applied": "/contactkit/applied_force", "contact": "/contactkit/contact",
                 "session": "/contactkit/session"}
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
MEASURED = ("q", "dq", "tau")  # the joint values every message must carry


def _msg_folder(ros1: bool) -> Any:
    return resources.files("contactkit.recorder") / "data" / (
        "ros1-franka_msgs" if ros1 else "ros2-franka_msgs")


@cache
def default_typestore(ros1: bool) -> Any:
    """Return the rosbags typestore for bags without definitions: ROS 1 Noetic or ROS 2
    Humble standard messages plus the bundled ``franka_msgs``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    folder = _msg_folder(ros1)
    types: dict = {}
    for item in folder.iterdir():
        if item.name.endswith(".msg"):
            types.update(get_types_from_msg(item.read_text(), f"franka_msgs/msg/{item.name[:-4]}"))
    store.register(types)
    return store


def bundled_msgdef(msgtype: str, ros1: bool) -> str:
    """Return the bundled ``.msg`` text of a ``franka_msgs`` type (e.g. FrankaRobotState)."""
    return (_msg_folder(ros1) / f"{msgtype.rsplit('/', 1)[-1]}.msg").read_text()


@dataclass
class BagColumns:
    """What the importer read from a bag: per-sample values by kind, the bag's recording
    time of each sample [ns], header stamps [ns] (0 where absent), label messages
    (recording time [ns], data), messages of the export-mcap topics, and statistics."""

    columns: dict[str, list] = field(default_factory=dict)
    recorded_ns: list[int] = field(default_factory=list)
    header_ns: list[int] = field(default_factory=list)
    labels: list[tuple[int, Any]] = field(default_factory=list)
    extras: dict[str, list] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _arm_indices(names: list[str]) -> list[int] | None:
    """Indices of the arm's joints 1..7 in a JointState's names (fingers excluded), or None
    when the names do not say (then the first seven values are the arm)."""
    if not names:
        return None
    found = {}
    for i, name in enumerate(names):
        if "finger" in name:
            continue
        for j in range(1, 8):
            if name.endswith(f"joint{j}"):
                found[j] = i
    return [found[j] for j in range(1, 8)] if len(found) == 7 else None


def _joint_state_values(msg: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    index = _arm_indices(list(msg.name))
    pick = slice(0, 7) if index is None else index
    return (np.asarray(msg.position)[pick], np.asarray(msg.velocity)[pick],
            np.asarray(msg.effort)[pick])


def _franka_state_rows(msg: Any) -> dict[str, Any]:
    return {"q": msg.q, "dq": msg.dq, "tau": msg.tau_J, "q_d": msg.q_d, "dq_d": msg.dq_d,
            "tau_ext_hat": msg.tau_ext_hat_filtered, "wrench_hat": msg.O_F_ext_hat_K,
            "robot_mode": msg.robot_mode,
            "command_success_rate": msg.control_command_success_rate}


def _franka_robot_state_rows(msg: Any) -> dict[str, Any]:
    measured, desired = msg.measured_joint_state, msg.desired_joint_state
    w = msg.o_f_ext_hat_k.wrench
    return {"q": measured.position, "dq": measured.velocity, "tau": measured.effort,
            "q_d": desired.position, "dq_d": desired.velocity,
            "tau_ext_hat": msg.tau_ext_hat_filtered.effort,
            "wrench_hat": (w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z),
            "robot_mode": msg.robot_mode,
            "command_success_rate": msg.control_command_success_rate}


def _joint_state_rows(msg: Any) -> dict[str, Any]:
    q, dq, tau = _joint_state_values(msg)
    return {"q": q, "dq": dq, "tau": tau}


ROWS = {FRANKA_STATE: _franka_state_rows, FRANKA_ROBOT_STATE: _franka_robot_state_rows,
        JOINT_STATE: _joint_state_rows}


def _open_reader(path: Path) -> Any:
    """Open a bag with rosbags, or, when its end (and index) is missing, scan what is left
    of a ROS 1 or MCAP file (:class:`contactkit.recorder.bag_salvage.SalvageReader`)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    ros1 = path.suffix == ".bag"
    try:
        reader = AnyReader([path], default_typestore=default_typestore(ros1))
        reader.open()
        return reader
    except Exception as err:  # rosbags raises several error types for unreadable bags
        problem = _first_line(err)
    mcaps = sorted(path.glob("*.mcap")) if path.is_dir() else [path]
    if len(mcaps) == 1 and mcaps[0].suffix in (".bag", ".mcap"):
        store = get_typestore(Stores.EMPTY)
        store.register(default_typestore(ros1).fielddefs)
        try:
            salvage = SalvageReader(mcaps[0], store)
        except (OSError, ValueError):
            salvage = None
        if salvage is not None and salvage.connections:
            return salvage
    raise InputError(f"cannot read bag ({problem})", path)


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def bag_topics(reader: Any) -> dict[str, str]:
    """Return ``{topic: message type}`` of an open rosbags reader."""
    return {c.topic: c.msgtype for c in reader.connections}


def choose_topic(topics: dict[str, str], wanted: str | None, path: Path) -> str:
    """Return the joint-state topic to import: ``wanted``, else the first of the usual
    Franka topics in the bag, else the only topic of a joint-state type. Raises InputError
    listing the bag's topics when there is none."""
    listing = ", ".join(f"{t} ({m})" for t, m in sorted(topics.items())) or "none"
    if wanted is not None:
        if wanted not in topics:
            raise InputError(f"no topic {wanted} in the bag; it has: {listing}", path)
        if topics[wanted] not in STATE_TYPES:
            raise InputError(f"topic {wanted} has type {topics[wanted]}, expected one of "
                             f"{', '.join(STATE_TYPES)}; the bag has: {listing}", path)
        return wanted
    for topic in DEFAULT_TOPICS:
        if topics.get(topic) in STATE_TYPES:
            return topic
    usable = [t for t, m in sorted(topics.items()) if m in STATE_TYPES]
    if len(usable) == 1:
        return usable[0]
    reason = "several joint-state topics, choose one" if usable else "no joint-state topic"
    raise InputError(f"{reason}; the bag has: {listing}", path)


def read_bag(path: Path, topic: str | None = None, label_topic: str | None = None) -> BagColumns:
    """Read the joint stream (and label topic) of one bag into :class:`BagColumns`.

    Messages that cannot be read (a truncated file, a corrupt chunk) end the reading;
    what came before is kept and ``info['read_error']`` says what happened.
    """
    reader = _open_reader(path)
    try:
        topics = bag_topics(reader)
        chosen = choose_topic(topics, topic, path)
        wanted = {chosen}
        if label_topic is not None:
            if label_topic not in topics or topics[label_topic] not in (STRING, BOOL):
                listing = ", ".join(f"{t} ({m})" for t, m in sorted(topics.items()))
                raise InputError(f"label topic {label_topic} must be a std_msgs/String or "
                                 f"Bool topic; the bag has: {listing}", path)
            wanted.add(label_topic)
        extra = {t for t in EXPORT_TOPICS.values() if t in topics}
        return _read_messages(reader, path, chosen, label_topic, wanted | extra, topics)
    finally:
        reader.close()


def _read_messages(reader: Any, path: Path, chosen: str, label_topic: str | None,
                   wanted: set[str], topics: dict[str, str]) -> BagColumns:
    rows_of = ROWS[topics[chosen]]
    out = BagColumns()
    rows: dict[str, list] = {}
    connections = [c for c in reader.connections if c.topic in wanted]
    expected = sum(c.msgcount for c in connections if c.topic == chosen)
    error = None
    try:
        for connection, timestamp, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, connection.msgtype)
            if connection.topic == chosen:
                for key, value in rows_of(msg).items():
                    rows.setdefault(key, []).append(value)
                out.recorded_ns.append(timestamp)
                header = getattr(msg, "header", None)
                out.header_ns.append(0 if header is None else _stamp_ns(header))
            elif connection.topic == label_topic:
                out.labels.append((timestamp, msg.data))
            else:
                out.extras.setdefault(connection.topic, []).append(msg)
    except InputError:
        raise
    except Exception as err:  # a truncated or corrupt bag: keep what came before
        error = _first_line(err)
    out.columns = rows
    out.info = {"bag": str(path), "topic": chosen, "msgtype": topics[chosen],
                "messages": len(out.recorded_ns), "messages_in_index": expected,
                "lost_messages": max(expected - len(out.recorded_ns), 0)}
    if isinstance(reader, SalvageReader):
        out.info["salvaged"] = True
        error = error or reader.lost()
    if error is not None:
        out.info["read_error"] = error
    return out


def _times(bag: BagColumns) -> tuple[np.ndarray, str]:
    """Return sample times [ns] and their source: headers where usable, else recording."""
    header = np.asarray(bag.header_ns, dtype=np.int64)
    if header.size and header.any() and (np.diff(header) > 0).all():
        return header, "header"
    return np.asarray(bag.recorded_ns, dtype=np.int64), "recording"


def bag_session_columns(bag: BagColumns, path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """Turn :class:`BagColumns` into session columns (``t`` in s from the first sample) and
    the ``source_info`` statistics: time source, measured rate, messages read and lost,
    dropped out-of-order samples and label events."""
    if not bag.recorded_ns:
        detail = f" ({bag.info['read_error']})" if "read_error" in bag.info else ""
        raise InputError(f"no readable messages on {bag.info['topic']}{detail}", path)
    times_ns, time_source = _times(bag)
    keep = np.ones(times_ns.size, bool)
    keep[1:] = times_ns[1:] > np.maximum.accumulate(times_ns)[:-1]
    columns: dict[str, np.ndarray] = {"t": (times_ns[keep] - times_ns[0]) * 1e-9}
    for key, values in bag.columns.items():
        array = _stacked(values)
        if array is None or (key in MEASURED and (array.shape[1:] != (7,)
                                                  or not np.isfinite(array).all())):
            if key in MEASURED:
                raise InputError(f"the {key} values on {bag.info['topic']} are not 7 finite "
                                 "numbers in every message", path)
            continue
        array = array[keep]
        if key == "wrench_hat":
            names = list(WRENCH_HAT_COLUMNS)
        elif array.ndim == 2:
            names = joint_columns(key)
        else:
            columns[key] = array.astype(np.int8 if key == "robot_mode" else np.float64)
            continue
        if array.shape[1] == len(names) and np.isfinite(array).all():
            columns.update({n: array[:, i] for i, n in enumerate(names)})
    recorded = np.asarray(bag.recorded_ns, dtype=np.int64)[keep]
    _add_export_topics(columns, bag.extras)
    events = [{"t": float(_session_time(stamp, recorded, columns["t"])), "text": str(data)}
              for stamp, data in bag.labels]
    info = {**bag.info, "time_source": time_source, "dropped_out_of_order": int((~keep).sum()),
            "rate_hz": sampling_stats(columns["t"]).rate_hz}
    if events:
        info["label_events"] = events
        flags = [e for e in events if e["text"] in ("True", "False")]
        if flags:
            columns["contact"] = _hold(flags, columns["t"])
    return columns, info


def _stacked(values: list) -> np.ndarray | None:
    """Return per-message values as one float64 array (a row per message), or None when
    the messages disagree in their number of values or hold something else."""
    try:
        return np.asarray(values, dtype=np.float64)
    except (ValueError, TypeError):
        return None


def _session_time(stamp_ns: int, recorded: np.ndarray, t: np.ndarray) -> float:
    """Session time [s] of a message recorded at ``stamp_ns``: the time of the sample
    recorded at or just before it (labels carry no header, samples may)."""
    i = int(np.searchsorted(recorded, stamp_ns, side="right")) - 1
    return float(t[max(i, 0)])


def _hold(flags: list[dict], t: np.ndarray) -> np.ndarray:
    """A bool column that holds each True/False label from its time on."""
    values = np.zeros(t.size, bool)
    for event in flags:
        values[t >= event["t"]] = event["text"] == "True"
    return values


def _add_export_topics(columns: dict[str, np.ndarray], extras: dict[str, list]) -> None:
    """Add the columns export-mcap writes on its own topics, where they line up one
    message per sample."""
    n = columns["t"].size

    def lined_up(topic: str) -> list | None:
        messages = extras.get(topic)
        return messages if messages is not None and len(messages) == n else None

    if (desired := lined_up(EXPORT_TOPICS["desired"])) is not None:
        columns.update(_joint_block("q_d", [m.position for m in desired]))
        columns.update(_joint_block("dq_d", [m.velocity for m in desired]))
    if (hat := lined_up(EXPORT_TOPICS["tau_ext_hat"])) is not None:
        columns.update(_joint_block("tau_ext_hat", [m.effort for m in hat]))
    for key, names in (("wrench_hat", WRENCH_HAT_COLUMNS),
                       ("applied", ("f_ext_x", "f_ext_y", "f_ext_z"))):
        if (wrenches := lined_up(EXPORT_TOPICS[key])) is not None:
            w = [m.wrench for m in wrenches]
            values = np.array([(x.force.x, x.force.y, x.force.z, x.torque.x, x.torque.y,
                                x.torque.z) for x in w])
            columns.update({name: values[:, i] for i, name in enumerate(names)})
    if (contact := lined_up(EXPORT_TOPICS["contact"])) is not None:
        columns["contact"] = np.array([m.data for m in contact], bool)


def _joint_block(prefix: str, rows: list) -> dict[str, np.ndarray]:
    array = np.asarray(rows, dtype=np.float64)
    return {name: array[:, i] for i, name in enumerate(joint_columns(prefix))}


def exported_meta(bag: BagColumns, path: Path) -> dict | None:
    """Return the session metadata export-mcap stored in the bag, or None; InputError
    naming the bag when that topic holds something other than a JSON metadata object."""
    messages = bag.extras.get(EXPORT_TOPICS["session"])
    if not messages:
        return None
    try:
        doc = json.loads(messages[0].data)
    except (json.JSONDecodeError, TypeError) as err:
        raise InputError(f"{EXPORT_TOPICS['session']} holds no JSON session metadata ({err})",
                         path) from err
    if not isinstance(doc, dict) or not isinstance(doc.get("source_info", {}), dict):
        raise InputError(f"{EXPORT_TOPICS['session']} holds no session metadata object", path)
    return doc


def import_bag(path: Path, meta: SessionMeta, out_dir: Path, *, topic: str | None = None,
               label_topic: str | None = None, name: str | None = None) -> Path:
    """Write one bag's joint stream as a validated session in ``out_dir``; return its path.

    ``meta`` holds the protocol choices; the bag's statistics go into
    ``meta.source_info``. A session export-mcap wrote gets its stored metadata back
    (session id, protocol, source), with the import recorded in ``source_info``. With a
    label topic, the first label's time is the planned interaction time unless
    ``meta`` has one.
    """
    bag = read_bag(path, topic, label_topic)
    stored = exported_meta(bag, path)
    columns, info = bag_session_columns(bag, path)
    if stored is not None:
        meta = SessionMeta.from_dict({**stored, "source_info": {**stored.get("source_info", {}),
                                                                "imported_from_bag": info}})
    else:
        meta.source_info = info
        events = info.get("label_events", [])
        if meta.planned_at_s is None and events:
            meta.planned_at_s = events[0]["t"]
        if meta.nominal_rate_hz is None:
            meta.nominal_rate_hz = float(round(info["rate_hz"], 3))
    return write_imported_session(columns, meta, out_dir, name)


def find_bags(directory: Path) -> list[Path]:
    """Return the bags in ``directory`` (recursively): ROS 1 ``.bag`` files, ROS 2 bag
    directories (with ``metadata.yaml``) and bare ``.mcap``/``.db3`` files outside them."""
    bag_dirs = sorted(p.parent for p in directory.rglob("metadata.yaml"))
    files = [p for p in sorted(directory.rglob("*")) if p.suffix in BAG_SUFFIXES and p.is_file()
             and not any(d in p.parents for d in bag_dirs)]
    return sorted(bag_dirs + files)


@dataclass(frozen=True)
class BagJob:
    """One bag to import: where it is, where the session goes, the protocol choices
    (keyword arguments of :func:`contactkit.recorder.metadata.session_meta`) and topics."""

    path: Path
    out_dir: Path
    protocol: dict
    topic: str | None = None
    label_topic: str | None = None


def import_bag_job(job: BagJob) -> tuple[str, Path | None, str | None]:
    """Import one bag; return ``(bag, session path, None)`` or ``(bag, None, problem)``."""
    try:
        meta = session_meta(source="ros-bag", **job.protocol)
        return str(job.path), import_bag(job.path, meta, job.out_dir, topic=job.topic,
                                         label_topic=job.label_topic), None
    except InputError as err:
        return str(job.path), None, str(err)


def import_bags(jobs: list[BagJob], workers: int = 1, progress: ProgressCallback | None = None
                ) -> tuple[list[Path], list[tuple[str, str]]]:
    """Import bags in parallel; return the written sessions and ``(bag, problem)`` pairs
    for the bags that could not be imported (one bad bag never stops the others)."""
    return split_problems(map_ordered(import_bag_job, jobs, workers=workers, progress=progress))
