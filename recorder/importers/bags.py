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

Hour-long bags import in bounded memory: the time source, the samples dropped as out
of order and the optional columns every message carries are known only at the bag's
end, so the messages are read once into temporary files (:class:`BagSpill`, about the
session's size on disk) and the session is written from them a row group at a time.
Only the label topic's messages stay in memory.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from contactkit.features.timing import streamed_sampling_stats
from contactkit.recorder.importers.bag_salvage import SalvageReader
from contactkit.recorder.importers.base import Importer
from contactkit.recorder.importers.spill import RowSpill
from contactkit.schemas import InputError, SessionMeta, joint_columns
from contactkit.schemas.columns import WRENCH_HAT_COLUMNS
from contactkit.util.safe_open import parse_json

FRANKA_STATE = "franka_msgs/msg/FrankaState"
FRANKA_ROBOT_STATE = "franka_msgs/msg/FrankaRobotState"
JOINT_STATE = "sensor_msgs/msg/JointState"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
STRING = "std_msgs/msg/String"
BOOL = "std_msgs/msg/Bool"
INT8 = "std_msgs/msg/Int8"
STATE_TYPES = (FRANKA_ROBOT_STATE, FRANKA_STATE, JOINT_STATE)
DEFAULT_TOPICS = ("/franka_robot_state_broadcaster/robot_state",
                  "/franka_state_controller/franka_states",
                  "/franka_state_controller/joint_states", "/joint_states")
# Written by export-mcap beside /joint_states, read back by the importer.
EXPORT_TOPICS = {"desired": "/joint_states_desired", "tau_ext_hat": "/tau_ext_hat_filtered",
                 "wrench_hat": "/franka_robot_state_broadcaster/external_wrench_in_base_frame",
                 "applied": "/contactkit/applied_force", "contact": "/contactkit/contact",
                 "robot_mode": "/contactkit/robot_mode", "session": "/contactkit/session"}
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


CHUNK_MESSAGES = 8192
"""Messages gathered before they are stacked and spilled, and rows handled at a time
while writing: the importer's memory, whatever the bag's length."""


class _Stacked:
    """One kind of per-message values, stacked a chunk at a time into a temporary file;
    ``usable`` turns false (and the file goes) once the messages disagree in shape."""

    def __init__(self) -> None:
        self.pending: list = []
        self.shape: tuple[int, ...] = ()
        self.finite = True
        self.usable = True
        self.spill: RowSpill | None = None

    @property
    def rows(self) -> int:
        """The messages spilled."""
        return 0 if self.spill is None else self.spill.rows

    def flush(self) -> None:
        """Stack the pending values and spill them."""
        values, self.pending = self.pending, []
        if not values or not self.usable:
            return
        array = _stacked(values)
        if array is None or (self.spill is not None and array.shape[1:] != self.shape):
            self.usable = False
            self.close()
            return
        if self.spill is None:
            self.shape = array.shape[1:]
            self.spill = RowSpill(int(np.prod(self.shape, dtype=np.int64)))
        self.finite = self.finite and bool(np.isfinite(array).all())
        self.spill.append(array.reshape(len(array), -1))

    def read(self, start: int, stop: int) -> np.ndarray:
        """Return the values of messages ``start`` up to ``stop``, each of ``shape``."""
        assert self.spill is not None  # read after the messages came
        rows = self.spill.read(start, stop)
        return rows.reshape(len(rows), *self.shape)

    def close(self) -> None:
        """Remove the temporary file."""
        if self.spill is not None:
            self.spill.close()
            self.spill = None


class BagSpill:
    """What the importer read from a bag, spilled to temporary files as it was read: per
    message of the joint topic its recording time and header stamp [ns] (0 where
    absent) and its values by kind (``q``, ``dq``, ``tau``, ``wrench_hat``, ...), the
    label messages (recording time [ns], data; these stay in memory), the values of the
    export-mcap topics, the first stored session metadata message, and statistics. Use
    it as a context manager: the files go when it closes."""

    def __init__(self) -> None:
        self.recorded = RowSpill(1, np.int64)
        self.header = RowSpill(1, np.int64)
        self.values: dict[str, _Stacked] = {}
        self.extras: dict[str, _Stacked] = {}
        self.labels: list[tuple[int, Any]] = []
        self.session_text: Any = None
        self.info: dict[str, Any] = {}
        self._times: list[tuple[int, int]] = []
        self._header_any = False
        self._header_rising = True
        self._last_header: int | None = None

    def __enter__(self) -> BagSpill:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Remove the temporary files."""
        for kind in (*self.values.values(), *self.extras.values()):
            kind.close()
        self.recorded.close()
        self.header.close()

    @property
    def messages(self) -> int:
        """The joint-topic messages read."""
        return self.recorded.rows + len(self._times)

    def add_sample(self, recorded_ns: int, header_ns: int, values: dict[str, Any]) -> None:
        """Take one joint-topic message: its recording time, header stamp and values."""
        self._times.append((recorded_ns, header_ns))
        for key, value in values.items():
            self.values.setdefault(key, _Stacked()).pending.append(value)

    def add_extra(self, topic: str, row: Any) -> None:
        """Take one message of an export-mcap topic, as its numbers."""
        self.extras.setdefault(topic, _Stacked()).pending.append(row)

    def flush(self, *, when_full: bool = False) -> None:
        """Spill what is pending (with ``when_full``, only once a chunk has gathered)."""
        if when_full and len(self._times) < CHUNK_MESSAGES:
            return
        if self._times:
            recorded, header = np.array(self._times, dtype=np.int64).T
            self._times = []
            before = [] if self._last_header is None else [self._last_header]
            stamps = np.concatenate([np.array(before, dtype=np.int64), header])
            self._header_rising = self._header_rising and bool((np.diff(stamps) > 0).all())
            self._header_any = self._header_any or bool(header.any())
            self._last_header = int(header[-1])
            self.recorded.append(recorded)
            self.header.append(header)
        for kind in (*self.values.values(), *self.extras.values()):
            kind.flush()

    def time_source(self) -> str:
        """Return "header" when the header stamps are set and increase, else "recording"."""
        return "header" if self._header_any and self._header_rising else "recording"


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
    of a ROS 1 or MCAP file (:class:`contactkit.recorder.importers.bag_salvage.SalvageReader`)."""
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


def read_bag(path: Path, topic: str | None = None, label_topic: str | None = None) -> BagSpill:
    """Read the joint stream (and label topic) of one bag into a :class:`BagSpill`.

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
                   wanted: set[str], topics: dict[str, str]) -> BagSpill:
    rows_of = ROWS[topics[chosen]]
    out = BagSpill()
    connections = [c for c in reader.connections if c.topic in wanted]
    expected = sum(c.msgcount for c in connections if c.topic == chosen)
    error = None
    messages = _lazily(lambda: reader.messages(connections=connections))
    try:
        while error is None:
            try:
                item = next(messages, None)
                if item is None:
                    break
                connection, timestamp, raw = item
                msg = reader.deserialize(raw, connection.msgtype)
                if connection.topic == chosen:
                    header = getattr(msg, "header", None)
                    out.add_sample(timestamp, 0 if header is None else _stamp_ns(header),
                                   rows_of(msg))
                elif connection.topic == label_topic:
                    out.labels.append((timestamp, msg.data))
                elif connection.topic == EXPORT_TOPICS["session"]:
                    out.session_text = msg.data if out.session_text is None else \
                        out.session_text
                else:
                    out.add_extra(connection.topic, _export_row(connection.topic, msg))
            except InputError:
                raise
            except Exception as err:  # a truncated or corrupt bag: keep what came before
                error = _first_line(err)
            out.flush(when_full=True)
        out.flush()
    except BaseException:
        out.close()
        raise
    out.info = {"bag": str(path), "topic": chosen, "msgtype": topics[chosen],
                "messages": out.messages, "messages_in_index": expected,
                "lost_messages": max(expected - out.messages, 0)}
    if isinstance(reader, SalvageReader):
        out.info["salvaged"] = True
        error = error or reader.lost()
    if error is not None:
        out.info["read_error"] = error
    return out


def _lazily(start: Any) -> Iterator[Any]:
    """Yield from ``start()``, called at the first ``next``: its errors come from there,
    where the reading loop catches them."""
    yield from start()


def _export_row(topic: str, msg: Any) -> Any:
    """Return the numbers export-mcap put into one message of its topics."""
    if topic == EXPORT_TOPICS["desired"]:
        return (*msg.position, *msg.velocity)
    if topic == EXPORT_TOPICS["tau_ext_hat"]:
        return msg.effort
    if topic in (EXPORT_TOPICS["contact"], EXPORT_TOPICS["robot_mode"]):
        return float(msg.data)
    w = msg.wrench
    return (w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z)


class BagSession:
    """A :class:`BagSpill` as session columns, streamed: time from the headers where
    usable, else from the recording; samples whose time does not pass every earlier one
    dropped; the optional kinds that every message carries, finite, with their names;
    the export-mcap topics where they line up one message per sample; label events and
    the contact they hold. ``info`` is the ``source_info`` statistics."""

    def __init__(self, bag: BagSpill, path: Path) -> None:
        if bag.messages == 0:
            detail = f" ({bag.info['read_error']})" if "read_error" in bag.info else ""
            raise InputError(f"no readable messages on {bag.info['topic']}{detail}", path)
        for key, kind in bag.values.items():
            if key in MEASURED and not (kind.usable and kind.shape == (7,) and kind.finite):
                raise InputError(f"the {key} values on {bag.info['topic']} are not 7 finite "
                                 "numbers in every message", path)
        self.bag = bag
        self.time_source = bag.time_source()
        stamps = np.array([stamp for stamp, _ in bag.labels], dtype=np.int64)
        counts = np.zeros(stamps.size, dtype=np.int64)
        self.samples = 0
        for _, t, recorded in self._kept():
            counts += np.searchsorted(recorded, stamps, side="right")
            self.samples += t.size
        label_t = self._times_at(np.maximum(counts - 1, 0))
        self.events = [{"t": float(t), "text": str(data)}
                       for t, (_, data) in zip(label_t, bag.labels, strict=True)]
        self.flags = [e for e in self.events if e["text"] in ("True", "False")]
        self.info = {**bag.info, "time_source": self.time_source,
                     "dropped_out_of_order": bag.messages - self.samples,
                     "rate_hz": streamed_sampling_stats(self.times).rate_hz}
        if self.events:
            self.info["label_events"] = self.events

    def _kept(self) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Yield, a chunk of messages at a time: which are kept (their time passes every
        earlier one), their session times t [s] (from the first message) and recording
        times [ns]."""
        times = self.bag.header if self.time_source == "header" else self.bag.recorded
        first = highest = None
        for start in range(0, self.bag.messages, CHUNK_MESSAGES):
            stamps = times.read(start, start + CHUNK_MESSAGES)[:, 0]
            recorded = self.bag.recorded.read(start, start + CHUNK_MESSAGES)[:, 0]
            if first is None:
                first = stamps[0]
                keep = np.ones(stamps.size, dtype=bool)
                keep[1:] = stamps[1:] > np.maximum.accumulate(stamps)[:-1]
            else:
                keep = stamps > np.maximum.accumulate(np.concatenate([[highest], stamps]))[:-1]
            highest = stamps.max() if highest is None else max(highest, stamps.max())
            yield keep, (stamps[keep] - first) * 1e-9, recorded[keep]

    def _times_at(self, index: np.ndarray) -> np.ndarray:
        """Return the session times [s] of the kept samples at ``index``."""
        out = np.zeros(index.size)
        offset = 0
        for _, t, _ in self._kept():
            inside = (index >= offset) & (index < offset + t.size)
            out[inside] = t[index[inside] - offset]
            offset += t.size
        return out

    def times(self) -> Iterator[np.ndarray]:
        """Yield the session times [s] of the kept samples, a chunk at a time."""
        return (t for _, t, _ in self._kept())

    def chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield the session columns of the kept samples, a chunk at a time."""
        start = offset = 0
        for keep, t, _ in self._kept():
            columns: dict[str, np.ndarray] = {"t": t}
            for key, kind in self.bag.values.items():
                if kind.usable:
                    _add_kind(columns, key, kind.read(start, start + keep.size)[keep])
            _add_export_topics(columns, self.bag.extras, self.samples, offset)
            if self.flags:
                columns["contact"] = _hold(self.flags, t)
            start, offset = start + keep.size, offset + t.size
            yield columns


def _add_kind(columns: dict[str, np.ndarray], key: str, array: np.ndarray) -> None:
    """Add one kind of values as session columns where it has them all, finite: a
    scalar per message as one column, else one per joint (or wrench component)."""
    if key == "wrench_hat":
        names = list(WRENCH_HAT_COLUMNS)
    elif array.ndim == 2:
        names = joint_columns(key)
    elif array.ndim == 1:
        columns[key] = array.astype(np.int8 if key == "robot_mode" else np.float64)
        return
    else:
        return
    if array.shape[1] == len(names) and np.isfinite(array).all():
        columns.update({n: array[:, i] for i, n in enumerate(names)})

def _stacked(values: list) -> np.ndarray | None:
    """Return per-message values as one float64 array (a row per message), or None when
    the messages disagree in their number of values or hold something else."""
    try:
        return np.asarray(values, dtype=np.float64)
    except (ValueError, TypeError):
        return None


def _hold(flags: list[dict], t: np.ndarray) -> np.ndarray:
    """A bool column that holds each True/False label from its time on."""
    values = np.zeros(t.size, bool)
    for event in flags:
        values[t >= event["t"]] = event["text"] == "True"
    return values


EXPORT_COLUMNS = {"desired": (14, [*joint_columns("q_d"), *joint_columns("dq_d")]),
                  "tau_ext_hat": (7, joint_columns("tau_ext_hat")),
                  "wrench_hat": (6, list(WRENCH_HAT_COLUMNS)),
                  "applied": (6, ["f_ext_x", "f_ext_y", "f_ext_z"])}
"""The export-mcap topics' values per message and the session columns they fill."""


def _add_export_topics(columns: dict[str, np.ndarray], extras: dict[str, _Stacked],
                       samples: int, offset: int) -> None:
    """Add the columns export-mcap writes on its own topics, where they line up one
    message per sample (``samples`` of them), for the kept samples from ``offset`` on."""
    n = columns["t"].size

    def lined_up(topic: str, shape: tuple[int, ...]) -> np.ndarray | None:
        kind = extras.get(topic)
        if kind is None or not kind.usable or kind.rows != samples or kind.shape != shape:
            return None
        return kind.read(offset, offset + n)

    for key, (width, names) in EXPORT_COLUMNS.items():
        if (values := lined_up(EXPORT_TOPICS[key], (width,))) is not None:
            columns.update({name: values[:, i] for i, name in enumerate(names)})
    if (contact := lined_up(EXPORT_TOPICS["contact"], ())) is not None:
        columns["contact"] = contact.astype(bool)
    if "robot_mode" not in columns and (
            mode := lined_up(EXPORT_TOPICS["robot_mode"], ())) is not None:
        columns["robot_mode"] = mode.astype(np.int8)


def exported_meta(bag: BagSpill, path: Path) -> dict | None:
    """Return the session metadata export-mcap stored in the bag, or None; InputError
    naming the bag when that topic holds something other than a JSON metadata object."""
    if bag.session_text is None:
        return None
    try:
        doc = parse_json(bag.session_text, "session metadata", path)
    except (InputError, TypeError) as err:
        raise InputError(f"{EXPORT_TOPICS['session']} holds no JSON session metadata "
                         f"({getattr(err, 'problem', err)})", path) from err
    if not isinstance(doc, dict) or not isinstance(doc.get("source_info", {}), dict):
        raise InputError(f"{EXPORT_TOPICS['session']} holds no session metadata object", path)
    return doc


class BagImporter(Importer):
    """A ROS bag's joint stream (:func:`read_bag`, :class:`BagSession`): ROS 1 ``.bag``,
    ROS 2 bag folders and bare ``.mcap`` or ``.db3`` files."""

    name = "bag"
    source = "ros-bag"
    suffixes = BAG_SUFFIXES
    description = "ROS 1 .bag, ROS 2 bag folders, .mcap and .db3 (franka_ros, franka_ros2, " \
                  "JointState)."

    @dataclass(frozen=True)
    class Config:
        """The bag format's options."""

        topic: str | None = field(default=None, metadata={
            "help": "Joint-state topic (FrankaState, FrankaRobotState or JointState; "
                    "default: the usual franka_ros/franka_ros2 topics)."})
        label_topic: str | None = field(default=None, metadata={
            "help": "std_msgs/String or Bool topic of labels or cue events: String events "
                    "are stored with their times (the first is the planned time), Bool is "
                    "the ground-truth contact."})

    def __init__(self, path: Path, bag: BagSpill, session: BagSession,
                 stored: dict | None) -> None:
        self.path, self.bag, self.session, self.stored = path, bag, session, stored

    @classmethod
    def open(cls, path: Path, config: Config) -> BagImporter:
        """Read the bag at ``path`` (options ``topic``, ``label_topic``; see :meth:`read`)."""
        return cls.read(path, config.topic, config.label_topic)

    @classmethod
    def read(cls, path: Path, topic: str | None = None, label_topic: str | None = None
             ) -> BagImporter:
        """Read the joint stream (and label topic) of the bag at ``path`` into temporary
        files; raise InputError naming the bag when it holds no usable stream."""
        bag = read_bag(path, topic, label_topic)
        try:
            stored = exported_meta(bag, path)
            return cls(path, bag, BagSession(bag, path), stored)
        except BaseException:
            bag.close()
            raise

    def times(self) -> Iterator[np.ndarray]:
        """Yield the kept samples' session times [s], a chunk at a time."""
        return self.session.times()

    def chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield the kept samples' session columns, a chunk at a time."""
        return self.session.chunks()

    def source_info(self) -> dict[str, Any]:
        """Return the bag's statistics (topic, messages, time source, rate [Hz]...)."""
        return self.session.info

    def metadata(self, meta: SessionMeta) -> SessionMeta:
        """Return the metadata export-mcap stored in the bag, with the import under
        ``source_info.imported_from_bag``; else ``meta`` with the bag's statistics, the
        first label's time as the planned time and the measured rate, where ``meta``
        has none."""
        info = self.session.info
        if self.stored is not None:
            return SessionMeta.from_dict({**self.stored, "source_info": {
                **self.stored.get("source_info", {}), "imported_from_bag": info}})
        meta.source_info = info
        events = info.get("label_events", [])
        if meta.planned_at_s is None and events:
            meta.planned_at_s = events[0]["t"]
        if meta.nominal_rate_hz is None:
            meta.nominal_rate_hz = float(round(info["rate_hz"], 3))
        return meta

    def summary(self) -> str:
        """Return the messages, topic, rate and time source in a line, and one more for
        a bag that ends early."""
        info = self.session.info
        lost = f", {info['lost_messages']} lost" if info["lost_messages"] else ""
        text = (f"{info['messages']} messages from {info['topic']} ({info['msgtype']}"
                f"{lost}), {info['rate_hz']:.1f} Hz, time from the {info['time_source']} "
                "stamps")
        if "read_error" in info:
            text += f"\nbag ends early: {info['read_error']}; what was readable is kept"
        return text

    def close(self) -> None:
        """Remove the temporary files."""
        self.bag.close()

    @classmethod
    def claims(cls, path: Path) -> bool:
        """Return whether ``path`` is a bag: a file with a bag suffix or a ROS 2 bag
        folder (with ``metadata.yaml``)."""
        return super().claims(path) or (path.is_dir() and (path / "metadata.yaml").is_file())

    @classmethod
    def find(cls, directory: Path) -> list[Path]:
        """Return the bags in ``directory`` (:func:`find_bags`)."""
        return find_bags(directory)


def find_bags(directory: Path) -> list[Path]:
    """Return the bags in ``directory`` (recursively): ROS 1 ``.bag`` files, ROS 2 bag
    directories (with ``metadata.yaml``) and bare ``.mcap``/``.db3`` files outside them."""
    bag_dirs = sorted(p.parent for p in directory.rglob("metadata.yaml"))
    files = [p for p in sorted(directory.rglob("*")) if p.suffix in BAG_SUFFIXES and p.is_file()
             and not any(d in p.parents for d in bag_dirs)]
    return sorted(bag_dirs + files)
