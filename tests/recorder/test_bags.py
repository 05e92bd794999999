"""ROS bags in and out: import-bag on real bags written by rosbags, export-mcap round trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from bag_writers import ROS2_TOPIC, START_NS, write_bag
from conftest import make_session, run_command

from contactkit.features.timing import rate_warning
from contactkit.recorder.importers.bags import BagImporter
from contactkit.recorder.importers.jobs import import_files, import_jobs
from contactkit.recorder.importers.mcap_export import export_mcap
from contactkit.recorder.metadata import session_meta
from contactkit.schemas import InputError, read_session, validate_session
from tests.conftest import write_imported

COMPARED = ["q", "dq", "tau", "q_d", "dq_d"]
PROTOCOL = {"action": "shove", "condition": "static", "pose": "B", "target_pose": None,
            "speed_rad_s": None, "link": 7, "planned_at_s": None, "operator": "",
            "with_hand": True}


def meta():
    return session_meta(source="ros-bag", **PROTOCOL)


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    """A 3 s simulated shove at 500 Hz."""
    return make_session(tmp_path_factory.mktemp("source"))


def assert_same_joints(a, b) -> None:
    np.testing.assert_allclose(b.t, a.t, rtol=0, atol=1e-9)
    for prefix in COMPARED:
        assert np.array_equal(a.joints(prefix), b.joints(prefix)), prefix


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_franka_bags_import_bit_equal(source, tmp_path, kind):
    session = read_session(source)
    bag = write_bag(session, tmp_path / ("bag.bag" if kind == "ros1" else "bag"), kind)
    out = write_imported(BagImporter.read(bag), meta(), tmp_path)
    imported = validate_session(out)
    assert_same_joints(session, imported)
    assert (imported.column("robot_mode") == 2).all()
    info = imported.meta.source_info
    assert info["time_source"] == "header"
    assert info["lost_messages"] == 0 and "read_error" not in info
    assert info["rate_hz"] == pytest.approx(500.0)
    assert imported.meta.nominal_rate_hz == pytest.approx(500.0)


def test_bag_without_definitions_uses_bundled_ones(source, tmp_path):
    bag = write_bag(read_session(source), tmp_path / "bag", "sqlite3", strip_definitions=True)
    imported = validate_session(write_imported(BagImporter.read(bag), meta(), tmp_path))
    assert_same_joints(read_session(source), imported)


def test_wrong_topic_lists_the_topics(source, tmp_path):
    bag = write_bag(read_session(source), tmp_path / "bag", "mcap")
    with pytest.raises(InputError) as err:
        write_imported(BagImporter.read(bag, "/joint_states"), meta(), tmp_path)
    message = str(err.value)
    assert "\n" not in message and ROS2_TOPIC in message and "FrankaRobotState" in message


def test_label_topics_give_planned_time_and_contact(source, tmp_path):
    session = read_session(source)
    bag = write_bag(session, tmp_path / "s", "mcap", labels=[(1.5, "cue shove"),
                                                             (2.0, "done")])
    imported = validate_session(write_imported(BagImporter.read(bag, label_topic="/labels"),
                                               meta(), tmp_path))
    assert imported.meta.planned_at_s == pytest.approx(1.5, abs=2e-3)
    assert [e["text"] for e in imported.meta.source_info["label_events"]] == ["cue shove",
                                                                               "done"]
    bag = write_bag(session, tmp_path / "b", "mcap", labels=[(1.0, True), (2.0, False)])
    contact = validate_session(write_imported(BagImporter.read(bag, label_topic="/labels"),
                                              meta(), tmp_path / "b", "b.parquet"))
    touching = contact.t[contact.column("contact")]
    assert touching[0] == pytest.approx(1.0, abs=2e-3)
    assert touching[-1] == pytest.approx(2.0, abs=2e-3)


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_truncated_bag_keeps_what_is_readable(source, tmp_path, kind):
    session = read_session(source)
    bag = write_bag(session, tmp_path / ("bag.bag" if kind == "ros1" else "bag"), kind)
    file = bag if kind == "ros1" else next(bag.glob("*.mcap"))
    data = file.read_bytes()
    broken = tmp_path / f"broken{file.suffix}"
    broken.write_bytes(data[:len(data) // 2])
    imported = validate_session(write_imported(BagImporter.read(broken), meta(), tmp_path))
    info = imported.meta.source_info
    assert 0 < imported.n_samples < session.n_samples
    assert info["salvaged"] and "lost" in info["read_error"]
    assert np.array_equal(imported.q, session.q[:imported.n_samples])


def test_directory_with_one_bad_bag(source, tmp_path):
    bags = tmp_path / "bags"
    bags.mkdir()
    session = read_session(source)
    write_bag(session, bags / "one.bag", "ros1")
    write_bag(session, bags / "two", "mcap")
    (bags / "bad.bag").write_bytes(b"#ROSBAG V2.0\nnot a bag")
    out = tmp_path / "sessions"
    out.mkdir()
    jobs = import_jobs([bags], "bag", out, protocol=PROTOCOL)
    assert [job.path for job in jobs] == [bags / "bad.bag", bags / "one.bag", bags / "two"]
    sessions, problems = import_files(jobs, workers=2)
    assert [s.recording for s in sessions] == [bags / "one.bag", bags / "two"]
    assert [name for name, _ in problems] == [str(bags / "bad.bag")]


def test_export_mcap_round_trip(source, tmp_path):
    mcap = export_mcap(source, tmp_path / "exported")
    assert mcap.suffix == ".mcap"
    back = validate_session(write_imported(BagImporter.read(mcap), meta(), tmp_path))
    original = read_session(source)
    assert back.table.column_names == original.table.column_names
    np.testing.assert_allclose(back.t, original.t, rtol=0, atol=1e-9)
    for name in original.table.column_names[1:]:
        assert np.array_equal(back.column(name), original.column(name)), name
    assert back.meta.session_id == original.meta.session_id
    assert back.meta.simulator == original.meta.simulator


def test_export_mcap_out_is_a_file_with_mcap_suffix_else_a_bag_directory(source, tmp_path):
    """`--out run.mcap` writes exactly that file (once a directory run.mcap/ holding
    run.mcap.mcap); `--out run` is a rosbag2 directory, as before. Both read back."""
    result = run_command("recorder", "export-mcap", str(source), "--out",
                         str(tmp_path / "run.mcap"))
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "run.mcap").is_file() and result.stdout.strip() == str(tmp_path /
                                                                               "run.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]  # no scratch left
    (tmp_path / "in").mkdir()
    back = validate_session(write_imported(BagImporter.read(tmp_path / "run.mcap"), meta(),
                                          tmp_path / "in"))
    assert np.array_equal(back.q, read_session(source).q)
    again = run_command("recorder", "export-mcap", str(source), "--out", str(tmp_path / "run.mcap"))
    assert again.returncode == 2 and "--overwrite" in again.stderr
    bag = export_mcap(source, tmp_path / "run")
    assert bag == tmp_path / "run" / "run.mcap" and (tmp_path / "run" / "metadata.yaml").is_file()


def test_rate_warning_flags_franka_ros_default_rate():
    assert rate_warning(30.0) and "30.0 Hz" in rate_warning(30.0)
    assert rate_warning(600.0) is None


def test_cli_import_export_and_slow_rate(source, tmp_path):
    out = tmp_path / "sessions"
    result = run_command("recorder", "export-mcap", str(source), "--out", str(tmp_path / "x"))
    assert result.returncode == 0, result.stderr
    result = run_command("recorder", "import-bag", str(tmp_path / "x"), "--pose", "B", "--action",
                         "shove", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "500.0 Hz" in result.stderr
    slow = make_session(tmp_path, rate_hz=30.0, seed=4)
    result = run_command("recorder", "info", str(slow))
    assert "too slow for the feature chain" in result.stdout
    result = run_command("recorder", "import-bag", str(tmp_path / "missing"), "--pose", "B",
                         "--action", "shove", "--out", str(out))
    assert result.returncode == 2 and "Traceback" not in result.stderr


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_streamed_import_does_not_depend_on_the_chunk(source, tmp_path, kind, monkeypatch):
    """The bag is spilled and written a chunk at a time: 7-message chunks give the table
    and metadata of one chunk for the whole bag (labels, contact and export topics)."""
    from contactkit.recorder.importers import bags

    session = read_session(source)
    bag = write_bag(session, tmp_path / ("bag.bag" if kind == "ros1" else "bag"), kind,
                    labels=[(1.0, True), (2.0, False)])
    exported = export_mcap(source, tmp_path / "exported")
    written = {}
    for chunk in (7, 100_000):
        monkeypatch.setattr(bags, "CHUNK_MESSAGES", chunk)
        out = tmp_path / f"out{chunk}"
        out.mkdir()
        written[chunk] = [validate_session(write_imported(
                              BagImporter.read(bag, label_topic="/labels"), meta(), out)),
                          validate_session(write_imported(BagImporter.read(exported), meta(),
                                                          out))]
    for small, whole in zip(written[7], written[100_000], strict=True):
        assert small.table.equals(whole.table)
        assert {**small.meta.__dict__, "session_id": "", "created_utc": ""} == \
            {**whole.meta.__dict__, "session_id": "", "created_utc": ""}
    assert written[7][0].column("contact").any()


@pytest.mark.timeout(120)
def test_a_clock_switch_in_a_bag_is_refused_not_read_as_years(source, tmp_path):
    """Header stamps in sim time (near 0 s), then wall time (1.7e9 s): a time jump."""
    session = read_session(source)
    stamps = START_NS + np.round(session.t * 1e9).astype(np.int64)
    stamps[:50] = np.round(session.t[:50] * 1e9).astype(np.int64) + 1
    bag = write_bag(session, tmp_path / "bag", "mcap", stamps_ns=stamps)
    with pytest.raises(InputError, match=r"time jumps by 1\.7e\+09 s at row 50"):
        write_imported(BagImporter.read(bag), meta(), tmp_path)
    assert not list(tmp_path.glob("*.parquet"))


def test_export_mcap_overwrites_a_bag_but_never_another_directory(source, tmp_path):
    """`--overwrite` replaces a bag directory the exporter wrote; a folder of other files
    named by mistake is refused in one line and left as it was."""
    bag = export_mcap(source, tmp_path / "run")
    assert export_mcap(source, tmp_path / "run", overwrite=True) == bag
    keep = tmp_path / "keep"
    keep.mkdir()
    (keep / "notes.txt").write_text("precious")
    with pytest.raises(InputError, match="is not a ROS 2 bag directory: not replaced, even "
                                         "with --overwrite"):
        export_mcap(source, keep, overwrite=True)
    assert [p.name for p in keep.iterdir()] == ["notes.txt"]


def test_export_mcap_never_replaces_the_session_it_reads(source, tmp_path):
    """The default output is the session's name without suffix: for a session file
    without one that is the session itself, which --overwrite (as the refusal
    suggested) replaced by a bag directory. Refused in one line, the session kept."""
    session = tmp_path / "run"
    session.write_bytes(source.read_bytes())
    for overwrite in (False, True):
        done = run_command("recorder", "export-mcap", str(session),
                           *(["--overwrite"] if overwrite else []))
        assert done.returncode == 2 and "the session it exports" in done.stderr, done.stderr
        assert session.is_file() and session.read_bytes() == source.read_bytes()
    link = tmp_path / "link.parquet"
    link.symlink_to(session)
    with pytest.raises(InputError, match="the session it exports"):
        export_mcap(link, session, overwrite=True)
    assert session.read_bytes() == source.read_bytes()
    dangling = tmp_path / "dangling"  # a link to nothing is not the session: the usual refusal
    dangling.symlink_to(tmp_path / "nothing")
    done = run_command("recorder", "export-mcap", str(session), "--out", str(dangling))
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert "--overwrite" in done.stderr and dangling.is_symlink(), done.stderr
