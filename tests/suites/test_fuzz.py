"""Property-based fuzzing of every reader (Hypothesis).

The property, for every file contactkit reads: a valid result or one
:class:`InputError` (one line, naming the file), never another exception, and
nothing written outside the output directory. The example count comes from the
Hypothesis profile (``ci`` in ``make test``, ``long`` in benchmarks/bench_fuzz.py).
The importers of ROS bags and CSV exports, the CSV map and detector calibrations
are fuzzed in tests/suites/test_fuzz_imports.py.
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import assume, event, given
from hypothesis import strategies as st

from contactkit.classify.modelfile.model_file import load_model
from contactkit.recorder.capture.journal import SessionWriter, journal_path, recover_directory
from contactkit.recorder.importers.arrays import load_joint_arrays
from contactkit.recorder.importers.can_map import default_map_path, load_map
from contactkit.recorder.importers.can_tools import CanLogImporter, bridge_session
from contactkit.recorder.info import session_info
from contactkit.recorder.metadata import session_filename
from contactkit.recorder.stats.summary import build_report
from contactkit.schemas import (
    SessionMeta,
    read_session,
    validate_session,
)
from contactkit.schemas.columns import COLUMN_ORDER
from contactkit.schemas.session import METADATA_KEY
from contactkit.util.paths import inside
from tests.conftest import import_array_files, make_session, write_imported
from tests.fuzz_support import (
    FLOATS,
    JSON_VALUES,
    mutate_document,
    nothing_outside,
    refused_or,
    to_toml,
)


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def valid_session(work: Path) -> Path:
    return make_session(work, seed=2, action="bump", link=5, duration_s=1.0,
                        planned_at_s=0.5, rate_hz=100.0)


# -- session Parquet -----------------------------------------------------------------------

@st.composite
def session_tables(draw) -> pa.Table:
    """A table near the session schema: some columns dropped, renamed, retyped, with
    NaN/inf, unordered time, any length."""
    n = draw(st.integers(0, 40))
    names = [c for c in COLUMN_ORDER if draw(st.booleans()) or c in ("t", "q_1")]
    names += draw(st.lists(st.sampled_from(["q_8", "tau_0", "x", "dq_d_9", "contact"]),
                           max_size=2, unique=True))
    names = list(dict.fromkeys(names))
    arrays = []
    for name in names:
        kind = draw(st.sampled_from(["float", "float", "float", "int", "bool", "str", "f32"]))
        if kind == "float":
            base = np.linspace(0.0, 1.0, n) if name == "t" else np.zeros(n)
            if n and draw(st.booleans()):
                base[draw(st.integers(0, n - 1))] = draw(FLOATS)
            arrays.append(pa.array(base))
        elif kind == "f32":
            arrays.append(pa.array(np.zeros(n, dtype=np.float32)))
        elif kind == "int":
            arrays.append(pa.array(np.arange(n)))
        elif kind == "bool":
            arrays.append(pa.array(np.zeros(n, dtype=bool)))
        else:
            arrays.append(pa.array(["a"] * n))
    return pa.table(arrays, names=names)


def _meta_doc(valid: Path) -> dict:
    return json.loads(pq.read_schema(valid).metadata[METADATA_KEY])


@given(table=session_tables(), data=st.data())
def test_fuzz_session_files(work: Path, valid_session: Path, table: pa.Table, data) -> None:
    doc = _meta_doc(valid_session)
    how = data.draw(st.sampled_from(["keep", "replace", "drop", "raw"]))
    if how == "replace":
        doc[data.draw(st.sampled_from(sorted(doc)))] = data.draw(JSON_VALUES)
    elif how == "drop":
        doc.pop(data.draw(st.sampled_from(sorted(doc))))
    raw = data.draw(st.binary(max_size=40)) if how == "raw" else json.dumps(doc).encode()
    path = work / "fuzzed.parquet"
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: raw}), path)
    session = refused_or(validate_session, path)
    info = refused_or(session_info, path)
    assert (session is None) == (info is None)
    if session is not None:
        name = session_filename(session.meta)
        assert inside(work, name).parent == work.resolve()


@given(cut=st.integers(0, 10_000), flips=st.lists(st.tuples(st.integers(0, 10_000),
                                                               st.integers(1, 255)),
                                                     max_size=4))
def test_fuzz_session_bytes(work: Path, valid_session: Path, cut: int, flips) -> None:
    data = bytearray(valid_session.read_bytes())
    for at, mask in flips:
        data[at % len(data)] ^= mask
    path = work / "bytes.parquet"
    path.write_bytes(bytes(data[:max(cut, len(data) - cut)]))
    refused_or(read_session, path)


@given(doc=st.dictionaries(st.sampled_from(["session_id", "source", "action", "pose",
                                            "target_pose", "link", "planned_at_s",
                                            "pose_q", "speed_rad_s", "nominal_rate_hz",
                                            "with_hand", "source_info", "recovered_samples",
                                            "schema_version", "condition"]),
                           JSON_VALUES, max_size=15))
def test_fuzz_metadata_documents(doc: dict) -> None:
    base = {"session_id": "abc", "source": "sim", "action": "bump", "schema_version": 1}
    meta = refused_or(SessionMeta.from_dict, base | doc)
    if meta is not None:
        assert "/" not in session_filename(meta)
        json.loads(meta.to_json())
        if meta.planned_at_s is not None:
            assert math.isfinite(meta.planned_at_s)


# -- index.parquet -------------------------------------------------------------------------

@given(how=st.sampled_from(["bytes", "table", "columns"]), raw=st.binary(max_size=200),
       names=st.lists(st.sampled_from(["file", "session_id", "action", "duration_s",
                                       "planned_at_s", "x"]), max_size=6, unique=True))
def test_fuzz_index(work: Path, valid_session: Path, how: str, raw: bytes, names) -> None:
    directory = work / "dataset"
    directory.mkdir(exist_ok=True)
    target = directory / valid_session.name
    if not target.exists():
        target.write_bytes(valid_session.read_bytes())
    index = directory / "index.parquet"
    if how == "bytes":
        index.write_bytes(raw)
    else:
        values = {name: [valid_session.name if name == "file" else raw.hex()] for name in names}
        if how == "table":
            values["file"] = [valid_session.name]
        pq.write_table(pa.table(values) if values else pa.table({"x": [1]}), index)
    report = refused_or(build_report, directory, False, 1)
    assert report is not None and report["sessions"] == 1


# -- model files ---------------------------------------------------------------------------

@given(raw=st.binary(max_size=300), suffix=st.sampled_from([".skops", ".onnx"]))
def test_fuzz_model_bytes(work: Path, raw: bytes, suffix: str) -> None:
    path = work / f"model{suffix}"
    path.write_bytes(raw)
    assert refused_or(load_model, path) is None


@given(members=st.dictionaries(st.sampled_from(["contactkit.json", "schema.json",
                                                "a.npy", "x"]),
                               st.binary(max_size=60) | JSON_VALUES.map(
                                   lambda v: json.dumps(v).encode()), max_size=4))
def test_fuzz_model_archives(work: Path, members: dict) -> None:
    import zipfile

    path = work / "archive.skops"
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    assert refused_or(load_model, path) is None


# -- CAN frame maps (TOML) -----------------------------------------------------------------

DEFAULT_MAP = tomllib.loads(default_map_path().read_text())


@given(text=st.text(max_size=200))
def test_fuzz_map_text(work: Path, text: str) -> None:
    path = work / "map.toml"
    path.write_text(text)
    refused_or(load_map, path)


@given(data=st.data())
def test_fuzz_map_documents(work: Path, data) -> None:
    path = work / "doc.toml"
    path.write_text(to_toml(mutate_document(DEFAULT_MAP, data)))
    fmap = refused_or(load_map, path)
    if fmap is not None:
        assert all(math.isfinite(s.scale) and s.start >= 0 for layout in fmap.frames.values()
                   for s in layout.signals)


# -- plain arrays --------------------------------------------------------------------------

ARRAY_TEXT = st.lists(st.lists(st.sampled_from(["0", "1.5", "-2", "nan", "inf", "1e999",
                                                "x", "", ",", "#"]), max_size=8),
                      max_size=12).map(lambda rows: "\n".join(" ".join(r) for r in rows))


@given(t=ARRAY_TEXT, q=ARRAY_TEXT, npy=st.booleans(), meta=st.lists(
    st.sampled_from(["pose=A", "pose=../x", "link=3", "link=12", "planned_at_s=0.001",
                     "planned_at_s=1e12", "action=shove", "with_hand=false", "bad"]),
    max_size=3))
def test_fuzz_plain_arrays(work: Path, t: str, q: str, npy: bool, meta: list) -> None:
    directory = work / "arrays"
    out = directory / "out"
    out.mkdir(parents=True, exist_ok=True)
    (directory / "t.txt").write_text(t)
    (directory / "q.txt").write_text(q)
    q_path = directory / "q.txt"
    if npy:
        q_path = directory / "q.npy"
        q_path.write_bytes(q.encode())
    refused_or(load_joint_arrays, directory / "t.txt", q_path, q_path, q_path)
    written = refused_or(import_array_files, directory / "t.txt", q_path, q_path, q_path, out,
                         meta)
    if written is not None:
        assert written.parent == out.resolve()
        validate_session(written).path.unlink()
    nothing_outside(work / "arrays", out)


# -- CAN logs --------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def can_logs(work: Path, valid_session: Path) -> dict[str, bytes]:
    fmap = load_map()
    logs = {}
    for suffix in (".asc", ".csv", ".log", ".trc", ".blf"):
        path = work / f"valid{suffix}"
        bridge_session(read_session(valid_session), fmap, log=path)
        logs[suffix] = path.read_bytes()
    return logs


@given(suffix=st.sampled_from([".asc", ".csv", ".log", ".trc", ".blf", ".db"]),
       cut=st.integers(0, 100_000), flips=st.lists(st.tuples(st.integers(0, 100_000),
                                                            st.integers(1, 255)), max_size=6),
       raw=st.binary(max_size=100), use_raw=st.booleans())
def test_fuzz_can_logs(work: Path, can_logs: dict, suffix: str, cut: int, flips, raw: bytes,
                       use_raw: bool) -> None:
    assume(use_raw or suffix in can_logs)
    data = bytearray(raw if use_raw else can_logs[suffix])
    for at, mask in flips:
        if data:
            data[at % len(data)] ^= mask
    directory = work / "can"
    out = directory / "out"
    out.mkdir(parents=True, exist_ok=True)
    log = directory / f"fuzzed{suffix}"
    log.write_bytes(bytes(data[:max(cut, len(data) // 2)]))
    meta = SessionMeta(session_id="fuzzcan", source="can-log", action="bump", pose="A")
    def decode_log() -> Path:
        return write_imported(CanLogImporter.read(log, load_map()), meta, out, "fuzzed.parquet")

    written = refused_or(decode_log)
    if written is not None:
        validate_session(written)
        written.unlink()
    nothing_outside(directory, out)


# -- journals ----------------------------------------------------------------------------------

@given(cut=st.integers(0, 50_000), flips=st.lists(st.tuples(st.integers(0, 50_000),
                                                            st.integers(1, 255)), max_size=3))
def test_fuzz_journals(work: Path, cut: int, flips) -> None:
    directory = work / "journal"
    directory.mkdir(exist_ok=True)
    for leftover in directory.iterdir():
        leftover.unlink()
    out = directory / "s.parquet"
    writer = SessionWriter(out, SessionMeta(session_id="j", source="sim", action="none"),
                           ["t", *[f"{p}_{i}" for p in ("q", "dq", "tau")
                                   for i in range(1, 8)]], flush_interval_s=0.02)
    t = 0.001 * np.arange(60)
    writer.append({"t": t, **{f"{p}_{i}": np.cos(t) for p in ("q", "dq", "tau")
                              for i in range(1, 8)}})
    writer.abort()
    data = bytearray(journal_path(out).read_bytes())
    for at, mask in flips:
        data[at % len(data)] ^= mask
    journal_path(out).write_bytes(bytes(data[:cut]))
    (recovery,) = recover_directory(directory)
    event("recovered" if recovery.session is not None else "left in place")
    if recovery.session is not None:
        assert validate_session(recovery.session).n_samples == recovery.samples
