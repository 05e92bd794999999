"""Property-based fuzzing of the importers' inputs and the smaller files (Hypothesis): ROS
bags, CSV exports, CSV column maps, detector calibrations, simulator noise files and
scalar feature tables.

The same property as tests/test_fuzz.py: a valid result or one :class:`InputError`
(one line, naming the file; exit 2 through the CLI), never another exception, and
nothing written outside the output directory. Bags are written by rosbags' own
writers (ROS 1, ROS 2 sqlite3 and MCAP) and then broken: bytes cut or flipped, or
messages of the wrong type, with bad headers, stamps, array lengths or NaN.
"""

from __future__ import annotations

import json
import math
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from contactkit.features.detector import (
    DetectorConfig,
    detect,
    load_calibration,
    save_calibration,
)
from contactkit.recorder.importers.bags import default_typestore, import_bag
from contactkit.recorder.importers.csv_import import import_csv
from contactkit.recorder.importers.csv_map import load_csv_map, mindlab_map_path
from contactkit.recorder.metadata import session_meta
from contactkit.recorder.sim.noise import SensorNoise, default_noise
from contactkit.schemas import InputError, read_session, validate_session
from contactkit.schemas.features import (
    FEATURES_KEY,
    feature_table,
    read_feature_table,
    write_feature_table,
)
from tests.bag_writers import write_bag
from tests.conftest import make_session
from tests.fuzz_support import (
    FLOATS,
    JSON_VALUES,
    mutate_document,
    nothing_outside,
    refused_or,
    to_toml,
)

BAG_KINDS = ("ros1", "sqlite3", "mcap")


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz_imports")


@pytest.fixture(scope="module")
def short_session(work: Path) -> Path:
    return make_session(work, seed=4, action="bump", link=3, duration_s=0.2,
                        planned_at_s=0.1, rate_hz=100.0)


def fresh_directory(path: Path) -> Path:
    """Return ``path`` as a new empty directory (removing what a previous example left)."""
    shutil.rmtree(path, ignore_errors=True)
    path.mkdir(parents=True)
    return path


def bag_meta():
    return session_meta(source="ros-bag", action="bump", condition="static", pose="A")


def check_bag_import(bag: Path, root: Path, **topics) -> None:
    """The property for one bag: a valid session inside ``root/out`` or an InputError."""
    out = fresh_directory(root / "out")
    written = refused_or(import_bag, bag, bag_meta(), out, **topics)
    if written is not None:
        assert written.parent == out.resolve()
        validate_session(written)
    nothing_outside(root, out)


# -- ROS bags: bytes -------------------------------------------------------------------------

@pytest.fixture(scope="module")
def valid_bags(work: Path, short_session: Path) -> dict[str, Path]:
    """One valid bag of each kind (the path of its single file)."""
    session = read_session(short_session)
    bags = {}
    (work / "valid_bags").mkdir()
    for kind in BAG_KINDS:
        bag = write_bag(session, work / "valid_bags" / (f"{kind}.bag" if kind == "ros1"
                                                        else kind), kind,
                        labels=[(0.05, "cue"), (0.1, "touch")])
        bags[kind] = bag if kind == "ros1" else next(p for p in bag.iterdir()
                                                     if p.suffix in (".db3", ".mcap"))
    return bags


@given(kind=st.sampled_from(BAG_KINDS), cut=st.integers(0, 1_000_000),
       flips=st.lists(st.tuples(st.integers(0, 1_000_000), st.integers(1, 255)), max_size=6),
       label=st.booleans())
def test_fuzz_bag_bytes(work: Path, valid_bags: dict, kind: str, cut: int, flips,
                        label: bool) -> None:
    data = bytearray(valid_bags[kind].read_bytes())
    for at, mask in flips:
        data[at % len(data)] ^= mask
    root = fresh_directory(work / "bag_bytes")
    bag = root / f"fuzzed{valid_bags[kind].suffix}"
    bag.write_bytes(bytes(data[:max(cut % (len(data) + 1), len(data) // 3)]))
    check_bag_import(bag, root, label_topic="/labels" if label else None)


# -- ROS bags: messages ----------------------------------------------------------------------

STATE_TOPICS = {"sensor_msgs/msg/JointState": "/joint_states",
                "franka_msgs/msg/FrankaState": "/franka_state_controller/franka_states",
                "franka_msgs/msg/FrankaRobotState": "/franka_robot_state_broadcaster/robot_state",
                "std_msgs/msg/String": "/joint_states",
                "geometry_msgs/msg/WrenchStamped": "/franka_state_controller/franka_states"}
JOINT_NAMES = st.lists(st.sampled_from([f"fr3_joint{j}" for j in range(1, 8)]
                                       + ["fr3_finger_joint1", "", "joint9"]), max_size=9)
VALUES = st.lists(FLOATS | st.floats(-4, 4), max_size=9)
STAMPS = st.tuples(st.integers(0, 2**31 - 1), st.integers(0, 2**32 - 1))
# ROS 1 bags store recording times as uint32 seconds, and a header stamp copied from
# the recording time must fit ROS 2's int32 seconds too
MAX_RECORDED_NS = (2**31 - 1) * 1_000_000_000


@st.composite
def bag_messages(draw) -> dict:
    """A bag's content: the joint-state type, per message a header stamp, a recording
    time, values and names, and extra label, session and export messages."""
    msgtype = draw(st.sampled_from(sorted(STATE_TOPICS)))
    n = draw(st.integers(0, 12))
    start = 1_700_000_000_000_000_000
    regular = draw(st.booleans())
    clean = draw(st.booleans())  # 7 finite values per joint quantity
    number = st.floats(-4, 4) if clean else FLOATS | st.floats(-4, 4)
    values = st.lists(number, min_size=7, max_size=7) if clean else VALUES
    messages = []
    for i in range(n):
        recorded = start + i * 10_000_000 if regular else draw(st.integers(1, MAX_RECORDED_NS))
        stamp = draw(st.sampled_from(["same", "zero", "drawn"]))
        header = {"same": divmod(recorded, 1_000_000_000), "zero": (0, 0),
                  "drawn": draw(STAMPS)}[stamp]
        messages.append({"recorded": recorded, "header": header, "names": draw(JOINT_NAMES),
                         "values": [draw(values) for _ in range(3)],
                         "seven": np.array(draw(st.lists(number, min_size=7,
                                                         max_size=7)))})
    extras = draw(st.lists(st.tuples(
        st.sampled_from(["/labels", "/contactkit/session", "/joint_states_desired",
                         "/contactkit/contact"]),
        st.text(max_size=30) | JSON_VALUES.map(json.dumps) | st.sampled_from(
            ["True", "False", '{"session_id": "x", "action": "shove", "pose": "../.."}'])),
        max_size=4))
    return {"msgtype": msgtype, "messages": messages, "extras": extras}


def write_messages(out: Path, kind: str, content: dict) -> Path:
    """Write ``content`` (from :func:`bag_messages`) as a bag of ``kind``; return its path."""
    from tests.bag_writers import zero_message

    ros1 = kind == "ros1"
    store = default_typestore(ros1)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    if ros1:
        from rosbags.rosbag1 import Writer
        writer = Writer(out)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer
        writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap"
                        else StoragePlugin.SQLITE3)
    types = store.types

    def header(sec_nsec) -> object:
        stamp = types["builtin_interfaces/msg/Time"](sec=sec_nsec[0], nanosec=sec_nsec[1])
        extra = {"seq": 0} if ros1 else {}
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id="", **extra)

    def joint_state(m: dict) -> object:
        position, velocity, effort = (np.array(v, dtype=np.float64) for v in m["values"])
        return types["sensor_msgs/msg/JointState"](
            header=header(m["header"]), name=m["names"], position=position,
            velocity=velocity, effort=effort)

    def state(m: dict) -> object:
        msgtype = content["msgtype"]
        if msgtype.endswith("JointState"):
            return joint_state(m)
        if msgtype.endswith("/FrankaState"):
            return zero_message(store, msgtype, header=header(m["header"]), q=m["seven"],
                                dq=m["seven"], tau_J=m["seven"])
        if msgtype.endswith("FrankaRobotState"):
            return zero_message(store, msgtype, header=header(m["header"]),
                                measured_joint_state=joint_state(m),
                                tau_ext_hat_filtered=joint_state(m))
        if msgtype.endswith("String"):
            return types[msgtype](data=str(m["values"]))
        return zero_message(store, msgtype, header=header(m["header"]))

    msgtype = content["msgtype"]
    if ros1 and msgtype.endswith("FrankaRobotState"):
        msgtype = "franka_msgs/msg/FrankaState"
        content = {**content, "msgtype": msgtype}
    elif not ros1 and msgtype.endswith("/FrankaState"):
        msgtype = "franka_msgs/msg/FrankaRobotState"
        content = {**content, "msgtype": msgtype}
    with writer:
        connections = {}
        state_conn = writer.add_connection(STATE_TOPICS[msgtype], msgtype, typestore=store)
        last = 1_700_000_000_000_000_000
        for m in content["messages"]:
            writer.write(state_conn, m["recorded"], serialize(state(m), msgtype))
            last = m["recorded"]
        for topic, text in content["extras"]:
            if topic == "/joint_states_desired":
                extra_type = "sensor_msgs/msg/JointState"
                msg = joint_state({"header": (0, 0), "names": [], "values": [[0.0] * 7] * 3})
            elif topic == "/contactkit/contact":
                extra_type, msg = "std_msgs/msg/Bool", types["std_msgs/msg/Bool"](
                    data=text == "True")
            else:
                extra_type, msg = "std_msgs/msg/String", types["std_msgs/msg/String"](
                    data=text)
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, extra_type, typestore=store)
            writer.write(connections[topic], last, serialize(msg, extra_type))
    return out


@given(kind=st.sampled_from(BAG_KINDS), content=bag_messages(),
       label=st.sampled_from([None, "/labels", "/joint_states"]))
def test_fuzz_bag_messages(work: Path, kind: str, content: dict, label: str | None) -> None:
    root = fresh_directory(work / "bag_messages")
    bag = write_messages(root / ("fuzzed.bag" if kind == "ros1" else "fuzzed"), kind, content)
    check_bag_import(bag, root, label_topic=label)


# -- CSV exports (MindLab-style map) ---------------------------------------------------------

MINDLAB_MAP = tomllib.loads(mindlab_map_path().read_text())
CSV_HEADER = ["index", "time", *[f"{p}{j}" for p in ("tau_J", "tau_ext", "q", "q_d", "dq",
                                                      "dq_d") for j in range(7)], "label"]
BAD_CELLS = ["x", "", " ", "nan", "NaN", "inf", "-inf", "1e999", "1e308", "-1e308", "0x10",
             " 1 ", "1,5", '"2"', "1e-320", "2", "-1", "\u00a0", "é"]


@st.composite
def csv_texts(draw) -> str:
    """A MindLab-style CSV export, then broken: cells, columns, rows, header or encoding."""
    n = draw(st.integers(0, 12))
    header = list(CSV_HEADER)
    rows = [[str(i), f"{0.005 * i:.3f}", *[f"{0.01 * (i + j):.4f}" for j in range(42)],
             str(int(draw(st.booleans())))] for i in range(n)]
    for what in draw(st.lists(st.sampled_from(["cell", "cell", "drop", "duplicate", "ragged",
                                               "huge", "time"]), max_size=4)):
        if what == "drop":
            k = draw(st.integers(0, len(header) - 1))
            header.pop(k)
            rows = [r[:k] + r[k + 1:] for r in rows]
        elif what == "duplicate":
            header[draw(st.integers(0, len(header) - 1))] = draw(st.sampled_from(header))
        elif rows and what == "ragged":
            row = rows[draw(st.integers(0, len(rows) - 1))]
            del row[draw(st.integers(0, len(row))):]
            row.extend(draw(st.lists(st.sampled_from(["1", ""]), max_size=3)))
        elif rows and all(len(r) > 1 for r in rows):
            row = rows[draw(st.integers(0, len(rows) - 1))]
            k = draw(st.integers(0, len(row) - 1)) if what != "time" else 1
            row[k] = draw(st.sampled_from(BAD_CELLS) | st.floats().map(repr)
                          if what != "huge" else st.sampled_from(["1e300", "-1e300", "1e18"]))
    lines = [",".join(header), *[",".join(r) for r in rows]]
    if draw(st.booleans()) and lines:
        lines = lines[:draw(st.integers(0, len(lines)))]
    text = draw(st.sampled_from(["\n", "\r\n"])).join(lines)
    return draw(st.sampled_from(["", "\ufeff"])) + text


def csv_meta():
    return session_meta(source="csv", action="none", condition="static", pose="A")


def check_csv_import(csv: Path, map_path: Path, root: Path) -> None:
    """The property for one CSV file and map: a valid session in ``root/out`` or an
    InputError, from the map's loading to the written file."""
    out = fresh_directory(root / "out")
    cmap = refused_or(load_csv_map, map_path)
    if cmap is None:
        return
    written = refused_or(import_csv, csv, cmap, csv_meta(), out)
    if written is not None:
        assert written.parent == out.resolve()
        validate_session(written)
    nothing_outside(root, out)


@given(text=csv_texts(), raw=st.booleans())
def test_fuzz_csv_files(work: Path, text: str, raw: bool) -> None:
    root = fresh_directory(work / "csv")
    csv = root / "export.csv"
    csv.write_bytes(text.encode("utf-8") if not raw else text.encode("utf-8")[::-1])
    check_csv_import(csv, mindlab_map_path(), root)


# -- CSV column maps (TOML) ------------------------------------------------------------------

@pytest.fixture(scope="module")
def valid_csv(work: Path) -> Path:
    path = work / "valid.csv"
    rows = [",".join(CSV_HEADER)] + [",".join([str(i), f"{0.005 * i:.3f}",
                                               *[f"{0.01 * (i + j):.4f}" for j in range(42)],
                                               "0"]) for i in range(10)]
    path.write_text("\n".join(rows) + "\n")
    return path


@given(text=st.text(max_size=200))
def test_fuzz_csv_map_text(work: Path, text: str) -> None:
    path = work / "csv_map.toml"
    path.write_text(text)
    refused_or(load_csv_map, path)


@given(data=st.data())
def test_fuzz_csv_map_documents(work: Path, valid_csv: Path, data) -> None:
    root = fresh_directory(work / "csv_map")
    path = root / "map.toml"
    path.write_text(to_toml(mutate_document(MINDLAB_MAP, data)))
    check_csv_import(valid_csv, path, root)


# -- detector calibrations (JSON) ------------------------------------------------------------

DEFAULT_CALIBRATION = DetectorConfig().to_dict()


@given(data=st.data(), how=st.sampled_from(["document", "document", "text", "bytes"]))
def test_fuzz_calibrations(work: Path, data, how: str) -> None:
    path = work / "calibration.json"
    if how == "document":
        path.write_text(json.dumps(mutate_document(DEFAULT_CALIBRATION, data)))
    elif how == "text":
        path.write_text(data.draw(st.text(max_size=100)))
    else:
        path.write_bytes(data.draw(st.binary(max_size=100)))
    config = refused_or(load_calibration, path)
    if config is not None:
        assert all(math.isfinite(v) and v > 0 for v in config.noise)
        assert all(math.isfinite(v) and v >= 0 for v in (*config.speed, *config.accel))
        t = np.arange(50) * 0.01
        detect(t, np.ones((50, 7)), np.zeros((50, 7)), config)
        assert load_calibration(save_calibration(work / "again.json", config,
                                                 overwrite=True)) == config


# -- simulator noise files (JSON, `recorder capture --noise-file`) ---------------------------

DEFAULT_NOISE = json.loads(default_noise().to_json())


@given(data=st.data(), how=st.sampled_from(["document", "document", "text"]))
def test_fuzz_noise_files(work: Path, data, how: str) -> None:
    path = work / "noise.json"
    if how == "document":
        path.write_text(json.dumps(mutate_document(DEFAULT_NOISE, data)))
    else:
        path.write_text(data.draw(st.text(max_size=100)))
    noise = refused_or(SensorNoise.from_file, path)
    if noise is not None:
        assert np.isfinite(noise.dq_sigma(np.ones(7))).all()
        assert all(np.isfinite(np.asarray(getattr(noise, name), dtype=float)).all()
                   for name in ("tau_sigma_nm", "q_sigma_rad", "tau_bias_nm"))


# -- scalar feature tables (Parquet) ---------------------------------------------------------

@pytest.fixture(scope="module")
def valid_features(work: Path) -> Path:
    info = {"file": "a.parquet", "session_id": "a", "action": "bump", "condition": "static",
            "pose": "A", "target_pose": None, "link": 3, "operator": "", "speed_rad_s": None,
            "window_start_s": 0.1, "window_end_s": 0.2, "window_method": "planned",
            "window_found": True, "planned_at_s": 0.1}
    table = feature_table([info], np.array([[1.5, 0.5]]), ["range(tau_3)", "max(r_2)"],
                          {"window_s": 0.1})
    return write_feature_table(work / "features.parquet", table)


@given(data=st.data(), how=st.sampled_from(["metadata", "document", "columns"]))
def test_fuzz_feature_tables(work: Path, valid_features: Path, data, how: str) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(valid_features)
    doc = json.loads(table.schema.metadata[FEATURES_KEY])
    raw = json.dumps(doc).encode()
    if how == "metadata":
        raw = data.draw(st.binary(max_size=60))
    elif how == "document":
        raw = json.dumps(mutate_document(doc, data)).encode()
    else:
        name = data.draw(st.sampled_from(table.column_names))
        kind = data.draw(st.sampled_from(["drop", "string", "int", "duplicate"]))
        if kind == "drop":
            table = table.drop_columns([name])
        elif kind == "duplicate":
            table = table.append_column(name, table.column(name))
        else:
            values = pa.array(["x"] if kind == "string" else [1])
            table = table.set_column(table.column_names.index(name), name, values)
    path = work / "fuzzed_features.parquet"
    pq.write_table(table.replace_schema_metadata({FEATURES_KEY: raw}), path)
    read = refused_or(read_feature_table, path)
    if read is not None:
        table, doc = read
        assert all(pa.types.is_floating(table.schema.field(n).type) for n in doc["features"])


# -- regressions found by the fuzzers above ----------------------------------------------------

def test_bag_with_ragged_joint_values_is_refused(work: Path) -> None:
    root = fresh_directory(work / "ragged")
    seven = np.zeros(7)
    messages = [{"recorded": 1_700_000_000_000_000_000 + i * 10_000_000, "header": (0, 0),
                 "names": [], "seven": seven,
                 "values": [[0.0] * (7 if i else 2), [0.0] * 7, [0.0] * 7]} for i in range(3)]
    content = {"msgtype": "sensor_msgs/msg/JointState", "messages": messages, "extras": []}
    bag = write_messages(root / "ragged", "mcap", content)
    with pytest.raises(InputError, match="q values on /joint_states are not 7 finite"):
        import_bag(bag, bag_meta(), root)


def test_bag_with_foreign_session_topic_is_refused(work: Path, short_session: Path) -> None:
    root = fresh_directory(work / "foreign")
    messages = [{"recorded": 1_700_000_000_000_000_000 + i * 10_000_000, "header": (0, 0),
                 "names": [], "seven": np.zeros(7), "values": [[0.0] * 7] * 3}
                for i in range(3)]
    for text, problem in (("not json", "holds no JSON session metadata"),
                          ("[1, 2]", "holds no session metadata object")):
        content = {"msgtype": "sensor_msgs/msg/JointState", "messages": messages,
                   "extras": [("/contactkit/session", text)]}
        bag = write_messages(fresh_directory(root / "bag") / "b", "sqlite3", content)
        with pytest.raises(InputError, match=problem):
            import_bag(bag, bag_meta(), root)


@pytest.mark.parametrize("key, value, problem", [
    ("min_on_s", 10**400, "a number of 401 characters"),
    ("noise", [10**400] * 7, "a number of 401 characters"),
    ("source", [1], "'source' must be an object"),
])
def test_calibration_with_huge_numbers_is_refused(work: Path, key, value, problem) -> None:
    path = work / "huge.json"
    path.write_text(json.dumps(DEFAULT_CALIBRATION | {key: value}))
    with pytest.raises(InputError, match=problem) as err:
        load_calibration(path)
    assert len(str(err.value)) < 300


@pytest.mark.parametrize("key, value", [("tau_sigma_nm", [float("nan")] * 7),
                                        ("q_sigma_rad", ["a"] * 7), ("tau_bias_nm", 3),
                                        ("dq_sigma_rad_s", [-1.0] * 7), ("source", 5)])
def test_noise_file_with_bad_values_is_refused(work: Path, key, value) -> None:
    path = work / "bad_noise.json"
    path.write_text(json.dumps(DEFAULT_NOISE | {key: value}))
    with pytest.raises(InputError, match=key.split("_")[0]):
        SensorNoise.from_file(path)


def test_feature_table_with_foreign_metadata_is_refused(work: Path,
                                                        valid_features: Path) -> None:
    import pyarrow.parquet as pq

    table = pq.read_table(valid_features)
    for raw in (b"not json", b"[]", b'{"features": "x"}'):
        path = work / "foreign_features.parquet"
        pq.write_table(table.replace_schema_metadata({FEATURES_KEY: raw}), path)
        with pytest.raises(InputError, match="feature"):
            read_feature_table(path)


def test_csv_with_a_repeated_mapped_column_is_refused(work: Path, valid_csv: Path) -> None:
    lines = valid_csv.read_text().splitlines()
    path = work / "repeated.csv"
    path.write_text("\n".join([lines[0].replace("q1,", "q0,", 1), *lines[1:]]) + "\n")
    with pytest.raises(InputError, match=r"column .q0. .* appears more than once"):
        import_csv(path, load_csv_map(mindlab_map_path()), csv_meta(), work)
