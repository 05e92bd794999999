"""Replay into Rerun, read back with rerun.chunk.RrdReader."""

from __future__ import annotations

import json
import socket
from collections import defaultdict
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import rerun as rr
import rerun.chunk as rc

from contactkit.classify.data import load_features
from contactkit.classify.events.contact_events import ContactEvent
from contactkit.classify.kinds.registry import get_kind, make_estimator
from contactkit.classify.modelfile.model_file import load_model, save_model
from contactkit.cli import replay as replay_cli
from contactkit.cli.common import run_app
from contactkit.errors import InputError
from contactkit.features.extract import SessionFeatures
from contactkit.features.scalars import scalar_features
from contactkit.features.timeseries import TimeseriesChain, columns_of
from contactkit.replay import recording
from contactkit.replay.engine import next_hop_after
from contactkit.replay.recording import log_contact_events
from contactkit.replay.session_replay import ReplaySummary, replay_sessions
from contactkit.robots import RobotSetup
from contactkit.robots.surfaces import viewer_urdf_file
from contactkit.schemas import read_session
from contactkit.schemas.session import METADATA_KEY
from contactkit.viewer import layout
from contactkit.viewer.web import WEB_PORT, free_port, start_web_viewer
from tests.conftest import make_dataset, make_session, run_cli, run_command
from tests.rrd_frames import assert_frames_ok, frame_problems

ENTITIES = [layout.Q, layout.DQ, layout.TAU, layout.RESIDUAL, layout.FORCE, layout.MOMENT,
            layout.FORCE_NORM, layout.MOMENT_NORM, layout.PROBABILITY, layout.PREDICTED,
            layout.PLANNED, layout.WINDOW, layout.OFFLINE_LABEL, layout.TRUE_FORCE,
            layout.TRUE_CONTACT, layout.TRUE_ACTION, layout.EE_FORCE,
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
    assert_frames_ok(out)
    return out


def test_every_entity_exists_with_one_row_per_sample(replayed, session) -> None:
    data = read_rrd(replayed)
    for entity in ENTITIES:
        assert entity in data, entity
    assert any(k.startswith("static:robot/") and "visual_geometries" in k for k in data)
    assert "static:__properties/session" in data
    n = read_session(session).n_samples
    for entity in (layout.Q, layout.DQ, layout.TAU, layout.RESIDUAL, layout.FORCE_NORM,
                   layout.MOMENT_NORM):
        assert sum(b.num_rows for b in data[entity]) == n, entity


def test_joint_transforms_pose_the_arm_at_each_robot_sample(replayed, session) -> None:
    """Every row of a joint's column is its whole transform at that sample's q (Rerun
    resolves Transform3D atomically: a row without the translation or the frames would
    move the joint to the origin of an implicit frame)."""
    q = read_session(session).q
    tree = rr.urdf.UrdfTree.from_file_path(viewer_urdf_file(RobotSetup()))
    data = read_rrd(replayed)
    for i in range(1, 8):
        joint = tree.get_joint_by_name(f"panda_joint{i}")
        batch = pa.Table.from_batches(data[f"{layout.JOINT_TRANSFORMS}/panda_joint{i}"])
        rows = {c: batch.column(f"Transform3D:{c}").to_pylist()
                for c in ("translation", "quaternion", "parent_frame", "child_frame")}
        for k, sample in enumerate(batch.column("sample").to_pylist()):
            expected = joint.compute_transform(float(q[sample, i - 1]), clamp=False)
            for component, logged in rows.items():
                value = getattr(expected, component).as_arrow_array().to_pylist()
                assert logged[k] == value, (i, sample, component)


def test_logged_residual_equals_the_feature_chain(replayed, session) -> None:
    s = read_session(session)
    expected = TimeseriesChain().compute(s.t, s.q, s.dq, s.tau, ["r"])["r"]
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
        chain = TimeseriesChain().compute(s.t[past], s.q[past], s.dq[past],
                                                        s.tau[past], names)
        inside = s.t[past] > t_pred[k] - window
        values = np.column_stack([chain[n] for n in names])[inside]
        row, _ = scalar_features(values, ["range"], [c for n in names for c in columns_of(n)])
        expected = model.estimator.predict_proba(row[None, :])[0]
        assert np.allclose(proba[k], expected, atol=1e-9)


def test_paced_and_max_rate_log_the_same_values(tmp_path, session, model_path,
                                                replayed) -> None:
    paced = tmp_path / "paced.rrd"
    result = run_command("replay", str(session), "--viewer", "none", "--save", str(paced),
                         "--model", str(model_path), "--rate", "20")
    assert result.returncode == 0, result.stderr
    assert_frames_ok(paced)
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
    result = run_command("replay", str(bad), str(session), "--viewer", "none", "--save",
                         str(tmp_path / "out.rrd"), "--model", str(model_path))
    assert result.returncode == 2
    assert f"replay: error: {bad}: not a readable Parquet file" in result.stderr
    assert_frames_ok(tmp_path / f"out_{session.stem}.rrd")


def test_rerun_viewer_without_display_falls_back_to_save(tmp_path, session, model_path) -> None:
    result = run_cli("replay", str(session), "--model", str(model_path), cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "no display" in result.stderr
    assert_frames_ok(tmp_path / "replay.rrd")
    bad = run_command("replay", str(session), "--viewer", "vr", "--model", str(model_path))
    assert bad.returncode == 2 and "'vr' is not one of" in bad.stderr
    bad = run_command("replay", str(session), "--rate", "fast", "--model", str(model_path))
    assert bad.returncode == 2 and "--rate must be" in bad.stderr


def test_capture_logs_live_with_the_same_layout(tmp_path) -> None:
    rrd = tmp_path / "capture.rrd"
    result = run_cli("recorder", "capture", "--pose", "C", "--action", "bump", "--seed", "2",
                     "--duration", "2", "--planned-at", "1", "--rate", "500", "--out",
                     str(tmp_path), "--save-rrd", str(rrd))
    assert result.returncode == 0, result.stderr
    assert_frames_ok(rrd)
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
    line = summary.line()
    assert line.startswith(f"{session.name}: recorded shove, ")
    assert "; predicted " in line and "(per-hop diagnostic: " in line


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
        result = run_command("replay", str(bad), "--viewer", "none", "--save", str(out),
                             "--model", str(model_path))
        assert result.returncode == 2, result.stderr
        assert "Traceback" not in result.stderr and "saved" not in result.stderr
        assert not out.exists(), name


def test_window_lane_ends_in_a_gap_not_a_state(replayed) -> None:
    states = [v for b in read_rrd(replayed)[layout.WINDOW] if "StateChange:state" in
              b.schema.names for v in b.column("StateChange:state").to_pylist()]
    assert states == [["window"], []]  # an empty state: rerun rrd verify rejects nulls


def test_directory_replay_without_hand_has_sound_frames(tmp_path, model_path) -> None:
    data = tmp_path / "data"
    data.mkdir()
    make_session(data, seed=8, action="bump", duration_s=2.0, planned_at_s=1.0, with_hand=False)
    make_session(data, seed=9, action="none", duration_s=2.0, planned_at_s=1.0)
    result = run_command("replay", str(data), "--viewer", "none", "--save",
                         str(tmp_path / "dir.rrd"), "--model", str(model_path))
    assert result.returncode == 0, result.stderr
    written = sorted(tmp_path.glob("dir_*.rrd"))
    assert len(written) == 2
    for path in written:
        assert_frames_ok(path)


def test_frame_check_finds_what_the_viewer_reports(tmp_path) -> None:
    rec = rr.RecordingStream("frames-test")
    rec.save(tmp_path / "bad.rrd")
    tree = layout.log_robot_model(rec, viewer_urdf_file(RobotSetup()))
    finger = tree.get_joint_by_name("panda_finger_joint1")
    rec.log(f"{layout.JOINT_TRANSFORMS}/panda_finger_joint1", finger.compute_transform(0.02),
            static=True)
    rec.log("loose_arrow", rr.Arrows3D(vectors=[[0, 0, 1]]))
    rec.flush()
    rec.disconnect()
    problems = frame_problems(tmp_path / "bad.rrd")
    assert len(problems) == 2
    assert "frame 'panda_leftfinger' is defined statically by 2 entities" in problems[0]
    assert "/loose_arrow: no transform path from 'tf#/loose_arrow'" in problems[1]


def test_contact_events_are_bars_and_thresholds_lines(tmp_path) -> None:
    rec = rr.RecordingStream("events-test")
    rec.save(tmp_path / "events.rrd")
    layout.log_series_styles(rec, ["none", "bump", "adjust", "shove"])
    t = np.linspace(0.0, 4.0, 401)
    events = [ContactEvent(1.0, 1.2, 1.5, "bump"), ContactEvent(2.5, 2.8, 3.5, "shove")]
    log_contact_events(rec, t, events, {"onset": 2.0, "release": 1.0})
    rec.flush()
    rec.disconnect()
    data = read_rrd(tmp_path / "events.rrd")
    lanes = [b for b in data[layout.CONTACT_EVENTS] if "StateChange:state" in b.schema.names]
    times = np.concatenate([b.column("time").cast("int64").to_numpy() for b in lanes]) / 1e9
    states = [s for b in lanes for s in b.column("StateChange:state").to_pylist()]
    order = np.argsort(times, kind="stable")
    assert np.allclose(times[order], [1.0, 1.5, 2.5, 3.5])
    # each bar ends in an empty state (a gap): rerun rrd verify rejects null states
    assert [states[i] for i in order] == [["bump"], [], ["shove"], []]
    texts = [v for b in data[layout.CONTACT_EVENTS] if "TextLog:text" in b.schema.names
             for v in b.column("TextLog:text").to_pylist()]
    assert any("shove (decided at 2.80 s)" in str(x) for x in texts)
    times, values = series(data[layout.THRESHOLD])
    assert np.allclose(times, [0.0, 4.0]) and np.allclose(values, [[2.0, 1.0], [2.0, 1.0]])


def test_events_table_times_are_rounded_to_ms(tmp_path) -> None:
    rec = rr.RecordingStream("events-ms-test")
    rec.save(tmp_path / "events.rrd")
    t = np.linspace(0.0, 12.0, 12001)
    log_contact_events(rec, t, [ContactEvent(10.8, 10.950015, 11.5, "adjust")])
    rec.flush()
    rec.disconnect()
    texts = [b for b in read_rrd(tmp_path / "events.rrd")[layout.CONTACT_EVENTS]
             if "TextLog:text" in b.schema.names]
    ns = [v for b in texts for v in b.column("time").cast("int64").to_pylist()]
    assert ns == [10_950_000_000]


def test_summary_line_puts_the_events_first(tmp_path) -> None:
    summary = ReplaySummary(tmp_path / "s.parquet", "adjust", None, [5.0, 5.3], ["bump", "bump"],
                            None, [ContactEvent(5.32, 5.47, 6.0, "adjust")])
    line = summary.line()
    assert line.startswith("s.parquet: recorded adjust, 1 contact event: adjust at 5.32 s; ")
    assert line.index("contact event") < line.index("per-hop diagnostic: first contact hop bump")
    assert ReplaySummary(tmp_path / "s.parquet", "none", None, [], [], None,
                         []).events_text() == "no contact event"
    assert ReplaySummary(tmp_path / "s.parquet", "none", None, [], [], None,
                         None).events_text() == "no event pipeline"


def test_web_viewer_refuses_a_port_another_program_holds(tmp_path, session,
                                                         model_path) -> None:
    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        port = other.getsockname()[1]
        with pytest.raises(InputError, match=f"port {port} on 127.0.0.1 is already in use"):
            start_web_viewer(free_port(), port)
        holder = socket.socket()
        try:
            holder.bind(("127.0.0.1", WEB_PORT))
            holder.listen()
        except OSError:
            pass  # another program holds it already: the same situation
        try:
            result = run_cli("replay", str(session), "--viewer", "web", "--model",
                             str(model_path), timeout=120)
        finally:
            holder.close()
    assert result.returncode == 2
    assert "http://" not in result.stderr + result.stdout
    assert result.stderr.strip().splitlines() == [
        f"replay: error: port {WEB_PORT} on 127.0.0.1 is already in use by another program; "
        "the Rerun web viewer was not started"]


def _with_gap(session: Path, out: Path, gap_s: float) -> Path:
    """The session with its last fifth shifted by ``gap_s`` [s], written without the
    writer's checks (as a foreign tool or a corrupt copy would)."""
    table = pq.read_table(session)
    t = table.column("t").to_numpy().copy()
    t[4 * len(t) // 5:] += gap_s
    index = table.column_names.index("t")
    pq.write_table(table.set_column(index, "t", pa.array(t)), out)
    return out


def test_next_hop_jumps_over_any_gap() -> None:
    assert next_hop_after(0.5, 0.52, 0.1) == pytest.approx(0.6)
    assert next_hop_after(0.5, 1.7e9, 0.1) > 1.7e9
    assert next_hop_after(1e16, 1e16, 1e-3) > 1e16  # hop below the resolution of t


@pytest.mark.timeout(300)
def test_replay_jumps_over_a_gap_and_refuses_a_time_jump(model_path, session, tmp_path,
                                                         capsys) -> None:
    model = load_model(model_path)
    gapped = _with_gap(session, tmp_path / "gapped.parquet", 9.0)
    summaries, problems = replay_sessions([gapped], model, save=tmp_path / "g.rrd",
                                          hop_s=1e-7)
    assert not problems and summaries[0].pred_t
    jumped = _with_gap(session, tmp_path / "jumped.parquet", 1e6)
    code = run_app(replay_cli.app, "replay", [str(jumped), "--model", str(model_path),
                                              "--viewer", "none", "--save",
                                              str(tmp_path / "j.rrd")])
    err = capsys.readouterr().err
    assert code == 2 and "time jumps by 1e+06 s" in err, err
    assert not (tmp_path / "j.rrd").exists()
    assert not [p for p in tmp_path.iterdir() if ".contactkit-" in p.name]


def test_a_zero_run_column_keeps_the_same_rows_however_it_is_split(monkeypatch) -> None:
    """The applied force goes out sparse: its non-zero rows, the zero rows beside them
    and the first and last row, the same rows whatever blocks the replay streams."""
    sent = []
    monkeypatch.setattr(recording.layout, "log_scalar_columns",
                        lambda rec, path, t, sample, values: sent.append((t, values)))
    rng = np.random.default_rng(1)
    values = np.zeros((200, 3))
    values[40:60] = rng.normal(size=(20, 3))
    values[120:121, 2] = 1.0
    values[199] = 0.0
    t, sample = np.arange(200) / 100.0, np.arange(200)
    expected = [0, *range(39, 61), 119, 120, 121, 199]
    for cuts in ([], [1, 39, 40, 61, 120, 121, 198], list(range(1, 200, 7))):
        sent.clear()
        runs = recording.ZeroRuns(layout.TRUE_FORCE)
        for part in np.split(np.arange(200), cuts):
            runs.log(None, t[part], sample[part], values[part])
        runs.finish(None)
        logged = np.concatenate([s[0] for s in sent])
        assert np.array_equal(np.round(logged * 100).astype(int), expected), cuts
        assert np.array_equal(np.concatenate([s[1] for s in sent]), values[expected])


def test_a_labelled_contact_column_is_shown_without_a_simulated_force(session, model_path,
                                                                      tmp_path) -> None:
    """An imported session (a MindLab CSV with its label column) has ``contact`` but no
    applied force: the view still shows the labelled contact lane."""
    import pyarrow.parquet as pq

    from contactkit.schemas.columns import FORCE_COLUMNS

    table = pq.read_table(session)
    imported = tmp_path / "imported.parquet"
    pq.write_table(table.drop_columns(list(FORCE_COLUMNS)), imported)
    assert read_session(imported).has("contact")
    summaries, problems = replay_sessions([imported], load_model(model_path),
                                          save=tmp_path / "i.rrd")
    assert not problems
    entities = read_rrd(summaries[0].saved)
    assert layout.TRUE_CONTACT in entities and layout.TRUE_FORCE not in entities
    assert_frames_ok(summaries[0].saved)


def test_sessions_of_one_name_never_save_over_each_other(tmp_path, session, model_path,
                                                         capsys, monkeypatch) -> None:
    """Two sessions named alike in different directories would both be saved as
    ``<save>_<name>.rrd``: the second replaced the first (silently with the default
    replay.rrd). Refused before any work, as one line naming both."""
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "s.parquet").write_bytes(session.read_bytes())
    pair = [str(tmp_path / "a" / "s.parquet"), str(tmp_path / "b" / "s.parquet")]
    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.chdir(out)
    for save in ([], ["--save", str(out / "r.rrd")], ["--save", str(out / "r.rrd"),
                                                     "--overwrite"]):
        code = run_app(replay_cli.app, "replay", [*pair, "--viewer", "none", *save,
                                                  "--model", str(model_path)])
        err = capsys.readouterr().err
        assert code == 2 and "would both be saved as" in err, err
        assert "rerun " not in err and list(out.iterdir()) == []
    with pytest.raises(InputError, match="would both be saved"):
        replay_sessions([Path(p) for p in pair], load_model(model_path), save=out / "r.rrd")
    assert list(out.iterdir()) == []
