"""Replay into Rerun, read back with rerun.chunk.RrdReader."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import rerun.chunk as rc

from contactkit.classify.data import load_features
from contactkit.classify.modelfile import load_model, save_model
from contactkit.classify.registry import get_kind, make_estimator
from contactkit.features.extract import SessionFeatures
from contactkit.features.scalars import scalar_features
from contactkit.features.timeseries import TimeseriesChain, columns_of
from contactkit.replay import cli as replay_cli
from contactkit.replay.session_replay import replay_sessions
from contactkit.schemas import read_session
from contactkit.schemas import rerun_layout as layout
from contactkit.schemas.session import METADATA_KEY
from contactkit.util.cli import run_app
from tests.conftest import make_dataset, make_session, run_cli

ENTITIES = [layout.Q, layout.DQ, layout.TAU, layout.RESIDUAL, layout.FORCE, layout.MOMENT,
            layout.WRENCH_NORM, layout.PROBABILITY, layout.PREDICTED, layout.PLANNED,
            layout.WINDOW, layout.OFFLINE_LABEL, layout.TRUE_FORCE, layout.TRUE_CONTACT,
            layout.TRUE_ACTION, layout.EE_FORCE,
            *[f"{layout.JOINT_TRANSFORMS}/panda_joint{i}" for i in range(1, 8)]]


@pytest.fixture(scope="module")
def model_path(tmp_path_factory) -> Path:
    directory = make_dataset(tmp_path_factory.mktemp("train"))
    extractor = SessionFeatures(window="planned")
    data = load_features([directory], extractor)
    estimator = make_estimator("svm", data.names, c=10.0).fit(data.X, data.labels())
    return save_model(tmp_path_factory.mktemp("model") / "m.skops", estimator,
                      transformer=extractor, feature_names=data.names,
                      classes=list(estimator.classes_), kind=get_kind("svm"), scheme="full",
                      fingerprint=data.fingerprint(), training={})


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    return make_session(tmp_path_factory.mktemp("session"), seed=5, action="shove", link=6,
                        duration_s=4.0, planned_at_s=2.0, rate_hz=500.0)


def read_rrd(path: Path) -> dict[str, list]:
    """Return entity path -> list of non-static record batches."""
    out = defaultdict(list)
    for chunk in rc.RrdReader(path).stream():
        if not chunk.is_static:
            out[chunk.entity_path.lstrip("/")].append(chunk.to_record_batch())
        else:
            out["static:" + chunk.entity_path.lstrip("/")].append(chunk.to_record_batch())
    return out


def series(batches: list, component: str = "Scalars:scalars") -> tuple[np.ndarray, np.ndarray]:
    """Return (time [s], values) of a scalar entity, sorted by time."""
    t = np.concatenate([b.column("time").cast("int64").to_numpy() for b in batches]) / 1e9
    values = np.concatenate([np.array(b.column(component).to_pylist()) for b in batches])
    order = np.argsort(t, kind="stable")
    return t[order], values[order]


@pytest.fixture(scope="module")
def replayed(tmp_path_factory, session, model_path) -> Path:
    out = tmp_path_factory.mktemp("rrd") / "replay.rrd"
    result = run_cli("replay", str(session), "--viewer", "none", "--save", str(out), "--model",
                     str(model_path))
    assert result.returncode == 0, result.stderr
    return out


def test_every_entity_exists_with_one_row_per_sample(replayed, session) -> None:
    data = read_rrd(replayed)
    for entity in ENTITIES:
        assert entity in data, entity
    assert any(k.startswith("static:robot/") and "visual_geometries" in k for k in data)
    assert "static:__properties/session" in data
    n = read_session(session).n_samples
    for entity in (layout.Q, layout.DQ, layout.TAU, layout.RESIDUAL, layout.WRENCH_NORM):
        assert sum(b.num_rows for b in data[entity]) == n, entity


def test_logged_residual_equals_the_feature_chain(replayed, session) -> None:
    s = read_session(session)
    expected = TimeseriesChain(with_hand=True).compute(s.t, s.q, s.dq, s.tau, ["r"])["r"]
    t, logged = series(read_rrd(replayed)[layout.RESIDUAL])
    assert np.allclose(t, s.t, atol=1e-9)
    assert np.abs(logged - expected).max() <= 1e-9


def test_predictions_sit_at_window_ends_without_look_ahead(replayed, session,
                                                           model_path) -> None:
    s = read_session(session)
    model = load_model(model_path)
    t_pred, proba = series(read_rrd(replayed)[layout.PROBABILITY])
    window = model.transformer().window_s
    assert t_pred[0] >= s.t[0] + window - 1e-9
    assert np.all(np.isin(np.round(t_pred, 9), np.round(s.t, 9)))
    assert np.all(np.diff(t_pred) >= 0.02 - 1e-9)
    names = ["dq", "tau", "r"]
    for k in (0, len(t_pred) // 2, len(t_pred) - 1):
        end = int(np.searchsorted(s.t, t_pred[k] + 1e-9))
        past = slice(0, end)
        chain = TimeseriesChain(with_hand=True).compute(s.t[past], s.q[past], s.dq[past],
                                                        s.tau[past], names)
        inside = s.t[past] > t_pred[k] - window
        values = np.column_stack([chain[n] for n in names])[inside]
        row, _ = scalar_features(values, ["range"], [c for n in names for c in columns_of(n)])
        expected = model.estimator.predict_proba(row[None, :])[0]
        assert np.allclose(proba[k], expected, atol=1e-9)


def test_paced_and_max_rate_log_the_same_values(tmp_path, session, model_path,
                                                replayed) -> None:
    paced = tmp_path / "paced.rrd"
    result = run_cli("replay", str(session), "--viewer", "none", "--save", str(paced),
                     "--model", str(model_path), "--rate", "20")
    assert result.returncode == 0, result.stderr
    fast, slow = read_rrd(replayed), read_rrd(paced)
    for entity in (layout.Q, layout.TAU, layout.RESIDUAL, layout.FORCE, layout.PROBABILITY,
                   layout.TRUE_FORCE):
        ta, va = series(fast[entity])
        tb, vb = series(slow[entity])
        assert np.array_equal(ta, tb) and np.array_equal(va, vb), entity
    assert len(slow[layout.PROBABILITY]) > 1 and len(fast[layout.PROBABILITY]) == 1


def test_bad_session_is_reported_and_others_still_replay(tmp_path, session, model_path) -> None:
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"not parquet")
    result = run_cli("replay", str(bad), str(session), "--viewer", "none", "--save",
                     str(tmp_path / "out.rrd"), "--model", str(model_path))
    assert result.returncode == 2
    assert f"replay: error: {bad}: not a readable Parquet file" in result.stderr
    assert (tmp_path / f"out_{session.stem}.rrd").exists()


def test_rerun_viewer_without_display_falls_back_to_save(tmp_path, session, model_path) -> None:
    result = run_cli("replay", str(session), "--model", str(model_path), cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "no display" in result.stderr and (tmp_path / "replay.rrd").exists()
    bad = run_cli("replay", str(session), "--viewer", "vr", "--model", str(model_path))
    assert bad.returncode == 2 and "'vr' is not one of" in bad.stderr
    bad = run_cli("replay", str(session), "--rate", "fast", "--model", str(model_path))
    assert bad.returncode == 2 and "--rate must be" in bad.stderr


def test_capture_logs_live_with_the_same_layout(tmp_path) -> None:
    rrd = tmp_path / "capture.rrd"
    result = run_cli("recorder", "capture", "--pose", "C", "--action", "bump", "--seed", "2",
                     "--duration", "2", "--planned-at", "1", "--rate", "500", "--out",
                     str(tmp_path), "--save-rrd", str(rrd))
    assert result.returncode == 0, result.stderr
    data = read_rrd(rrd)
    n = read_session(result.stdout.strip()).n_samples
    for entity in (layout.Q, layout.DQ, layout.TAU, layout.TRUE_FORCE):
        assert sum(b.num_rows for b in data[entity]) == n
    cues = [str(v) for b in data[layout.CUE] for v in b.column("TextLog:text").to_pylist()]
    assert any("NOW" in c for c in cues) and any("planned interaction" in c for c in cues)


def test_a_refused_session_leaves_no_file_and_no_saved_message(tmp_path, session, model_path,
                                                               capsys) -> None:
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"not parquet")
    out = tmp_path / "out.rrd"
    code = run_app(replay_cli.app, "replay", [str(bad), "--viewer", "none", "--save", str(out),
                                              "--model", str(model_path)])
    err = capsys.readouterr().err
    assert code == 2 and "not a readable Parquet file" in err
    assert "saved" not in err and not out.exists()
    summaries, problems = replay_sessions([bad, session], load_model(model_path), save=out)
    assert [p.path for p in problems] == [str(bad)]
    written = tmp_path / f"out_{session.stem}.rrd"
    assert [s.saved for s in summaries] == [written] and written.exists()
    assert not (tmp_path / "out_bad.rrd").exists()
    summary = summaries[0]
    assert summary.recorded == "shove" and summary.offline.label in load_model(model_path).classes
    assert len(summary.pred_t) == len(summary.pred_label) > 10
    assert summary.line().startswith(f"{session.name}: recorded shove, predicted ")


def test_refused_input_gives_no_saved_message_and_no_file(tmp_path, session, model_path
                                                          ) -> None:
    table = pq.read_table(session)
    doc = json.loads(table.schema.metadata[METADATA_KEY])
    for name, changes in (("overflow", {"planned_at_s": 1e12}),
                          ("late", {"planned_at_s": 60.0})):
        bad = tmp_path / f"{name}.parquet"
        pq.write_table(table.replace_schema_metadata(
            {METADATA_KEY: json.dumps(doc | changes).encode()}), bad)
        out = tmp_path / f"{name}.rrd"
        result = run_cli("replay", str(bad), "--viewer", "none", "--save", str(out),
                         "--model", str(model_path))
        assert result.returncode == 2, result.stderr
        assert "Traceback" not in result.stderr and "saved" not in result.stderr
        assert not out.exists(), name
