"""The session format v1: round trip, atomic writes, and each validation failure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from contactkit.schemas import (
    InputError,
    SessionMeta,
    read_session,
    validate_session,
    write_session,
)
from contactkit.schemas.dataset import build_index, rebuild_index
from contactkit.schemas.session import METADATA_KEY


def _table_and_meta(path: Path) -> tuple[pa.Table, dict]:
    table = pq.read_table(path)
    return table, json.loads(table.schema.metadata[METADATA_KEY])


def _rewrite(src: Path, dst: Path, table: pa.Table, doc: dict | None) -> Path:
    meta = {} if doc is None else {METADATA_KEY: json.dumps(doc).encode()}
    pq.write_table(table.replace_schema_metadata(meta), dst)
    return dst


def test_round_trip(session_path: Path) -> None:
    session = read_session(session_path)
    assert session.meta.action == "shove"
    assert session.q.shape == (session.n_samples, 7)
    assert session.table.column_names[:22] == ["t", *[f"{p}_{i}" for p in ("q", "dq", "tau")
                                                     for i in range(1, 8)]]
    assert abs(session.duration_s - 3.0) < 1e-9
    assert session.has("contact") and session.column("contact").dtype == bool


def test_file_opens_in_polars(session_path: Path) -> None:
    import polars as pl

    frame = pl.read_parquet(session_path)
    assert frame.columns[0] == "t" and frame["tau_7"].dtype == pl.Float64


def test_write_refuses_to_overwrite_and_leaves_no_temp(session_path: Path) -> None:
    session = read_session(session_path)
    before = session_path.read_bytes()
    with pytest.raises(InputError, match="already exists"):
        write_session(session_path, session.table, session.meta)
    assert session_path.read_bytes() == before
    assert [p.name for p in session_path.parent.iterdir()] == [session_path.name]


def _mutations():
    def drop(col):
        return lambda t, d: (t.drop_columns([col]), d)

    def set_col(col, values):
        return lambda t, d: (t.set_column(t.column_names.index(col), col, values), d)

    def nan_at(col, row, value=np.nan):
        def mutate(t, d):
            v = t.column(col).to_numpy().copy()
            v[row] = value
            return t.set_column(t.column_names.index(col), col, pa.array(v)), d
        return mutate

    def meta(**changes):
        return lambda t, d: (t, {**d, **changes})

    def drop_meta_key(key):
        return lambda t, d: (t, {k: v for k, v in d.items() if k != key})

    def backwards(t, d):
        v = t.column("t").to_numpy().copy()
        v[10] = v[9]
        return t.set_column(0, "t", pa.array(v)), d

    def extra_joint(t, d):
        return t.append_column("q_8", t.column("q_7")), d

    return {
        "missing column 'tau_3'": drop("tau_3"),
        "wrong joint count": drop("q_7"),
        "wrong joint count: columns q_1..q_8": extra_joint,
        "has type int64": set_col("dq_2", pa.array(np.arange(0, 1501, dtype=np.int64))),
        "NaN in column 'tau_4' at row 7": nan_at("tau_4", 7),
        "infinite value in column 'q_1' at row 3": nan_at("q_1", 3, np.inf),
        "t is not strictly increasing at row 10": backwards,
        "unknown schema version 99": meta(schema_version=99),
        "unknown action 'hug'": meta(action="hug"),
        "session metadata lacks 'session_id'": drop_meta_key("session_id"),
        "unexpected column 'foo'": lambda t, d: (t.append_column("foo", t.column("t")), d),
    }


@pytest.mark.parametrize("problem", list(_mutations()))
def test_validator_names_file_and_problem(session_path: Path, tmp_path: Path,
                                          problem: str) -> None:
    table, doc = _table_and_meta(session_path)
    table, doc = _mutations()[problem](table, doc)
    bad = _rewrite(session_path, tmp_path / "bad.parquet", table, doc)
    with pytest.raises(InputError) as err:
        validate_session(bad)
    message = str(err.value)
    assert message.startswith(str(bad) + ": ")
    assert problem in message
    assert "\n" not in message


def test_foreign_and_corrupt_files(session_path: Path, tmp_path: Path) -> None:
    table, _ = _table_and_meta(session_path)
    foreign = _rewrite(session_path, tmp_path / "foreign.parquet", table, None)
    with pytest.raises(InputError, match="no contactkit session metadata"):
        validate_session(foreign)
    junk = tmp_path / "junk.parquet"
    junk.write_bytes(b"this is not parquet at all" * 10)
    with pytest.raises(InputError, match="not a readable Parquet file"):
        validate_session(junk)
    truncated = tmp_path / "truncated.parquet"
    truncated.write_bytes(session_path.read_bytes()[:-100])
    with pytest.raises(InputError, match="not a readable Parquet file"):
        validate_session(truncated)
    bad_json = tmp_path / "badjson.parquet"
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: b"{nope"}), bad_json)
    with pytest.raises(InputError, match="metadata is not JSON"):
        validate_session(bad_json)


def test_metadata_model_round_trip() -> None:
    meta = SessionMeta(session_id="abc", source="sim", action="bump", pose="C", link=4,
                       pose_q=[0.0] * 7)
    again = SessionMeta.from_dict(json.loads(meta.to_json()))
    assert again == meta
    with pytest.raises(InputError, match="pose_q is not 7 finite joint angles"):
        SessionMeta(session_id="x", source="sim", action="none", pose_q=[0, 0, 0]).check()


def test_index_is_rebuilt_from_files(tmp_path: Path) -> None:
    from tests.conftest import make_session

    for seed, action in enumerate(("none", "bump", "adjust")):
        make_session(tmp_path, seed=seed, action=action, duration_s=2.0, planned_at_s=1.0)
    (tmp_path / "broken.parquet").write_bytes(b"garbage")
    result = rebuild_index(tmp_path)
    assert sorted(result.table.column("action").to_pylist()) == ["adjust", "bump", "none"]
    assert result.problems and result.problems[0][0] == "broken.parquet"
    index = pq.read_table(tmp_path / "index.parquet")
    assert index.num_rows == 3
    durations = index.column("duration_s").to_numpy()
    assert np.allclose(durations, 2.0)
    assert build_index(tmp_path).table.column("session_id") == result.table.column("session_id")
