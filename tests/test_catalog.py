"""The dataset as a Rerun catalog: `recorder catalog`, `recorder query`, `recorder browse`.

One 8-session ``smoke`` dataset (at 250 Hz) and its catalog, built once with a quick
model: Rerun's own catalog server and client see 8 segments with their properties; a
query's misclassified events are those of ``classify predict --events --json``; a
re-run replays only what changed; bad input is one line, exit 2, and nothing outside
the catalog folder is written or removed.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
from pathlib import Path

import pytest

from contactkit.schemas import read_session_meta
from tests.conftest import BIN, run_command, save_quick_model

SESSIONS = 8


@pytest.fixture(scope="module")
def smoke(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("smoke")
    done = run_command("recorder", "simulate", str(root / "smoke"), "--preset", "smoke",
                       "--rate", "250", "--workers", "1")
    assert done.returncode == 0, done.stderr
    return root / "smoke"


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    return save_quick_model(tmp_path_factory.mktemp("model") / "quick.skops", events=True)


@pytest.fixture(scope="module")
def catalog(tmp_path_factory, smoke, model) -> Path:
    out = tmp_path_factory.mktemp("cat") / "catalog"
    done = run_command("recorder", "catalog", str(smoke), "--out", str(out), "--model",
                       str(model), "--workers", "1")
    assert done.returncode == 0, done.stderr
    assert f"{SESSIONS} replayed" in done.stderr
    return out


def _session_ids(dataset: Path) -> dict[str, str]:
    """Return {session id: file name} of a dataset."""
    return {read_session_meta(p)[0].session_id: p.name for p in sorted(dataset.glob("*.parquet"))
            if p.name != "index.parquet"}


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def _one_line_error(done: subprocess.CompletedProcess) -> str:
    assert done.returncode == 2, done.stderr
    errors = [line for line in _lines(done.stderr) if "error:" in line]
    assert len(errors) == 1, done.stderr
    return errors[0]


def test_rerun_catalog_server_sees_every_session_with_its_properties(catalog, smoke):
    import rerun as rr

    ids = _session_ids(smoke)
    top = sorted(p.name for p in catalog.iterdir())
    assert top == sorted([f"{sid}.rrd" for sid in ids] + ["tables"])
    with rr.server.Server(host="127.0.0.1", port=0, datasets={"smoke": catalog}) as server:
        dataset = server.client().get_dataset("smoke")
        assert sorted(dataset.segment_ids()) == sorted(ids)
        table = dataset.segment_table().to_pylist()
    for row in table:
        sid = row["rerun_segment_id"]
        assert row["property:session:session_id"] == [sid]
        assert row["property:session:file"] == [ids[sid]]  # relative to the dataset
        assert row["property:catalog:model"] == ["quick.skops"]
        assert row["property:result:offline_label"][0] in ("none", "bump", "adjust", "shove")
        n_events = row["property:result:n_events"][0]
        assert len(row.get("property:events:onset_s") or []) == n_events
        if row["property:session:action"] != ["none"]:
            assert row["property:result:contact_start_s"][0] > 0


def test_query_finds_the_events_classify_predict_misclassifies(catalog, smoke, model):
    done = run_command("classify", "predict", str(model), str(smoke), "--events", "--json")
    assert done.returncode == 0, done.stderr
    actions = {p.name: read_session_meta(p)[0].action for p in smoke.glob("*_*.parquet")}
    expected = set()
    for line in _lines(done.stdout):
        found = json.loads(line)
        name = Path(found["session"]).name
        if found["event"]["label"] != actions[name]:
            expected.add((name, round(found["event"]["onset_s"], 6)))
    assert expected, "the quick model should misclassify some events"
    query = run_command("recorder", "query", str(catalog),
                        "SELECT s.file, e.onset_s, e.session_id FROM events e JOIN sessions s "
                        "USING (session_id) WHERE e.label <> s.action", "--json")
    assert query.returncode == 0, query.stderr
    rows = [json.loads(line) for line in _lines(query.stdout)]
    assert {(r["file"], round(r["onset_s"], 6)) for r in rows} == expected
    for row in rows:  # each row opens in the viewer at its event's time
        assert row["open"] == (f"recorder browse {catalog} --session {row['session_id']} "
                               f"--at {row['onset_s']:.3f}")


def test_a_rerun_replays_only_new_sessions_and_removes_gone_ones(tmp_path, smoke, catalog,
                                                                 model):
    dataset, out = tmp_path / "smoke", tmp_path / "catalog"
    shutil.copytree(smoke, dataset)
    shutil.copytree(catalog, out)  # a copied catalog is still the catalog
    notes = out / "notes.txt"
    notes.write_text("mine")
    done = run_command("recorder", "simulate", str(dataset), "--preset", "smoke", "--rate",
                       "250", "--sessions", str(SESSIONS + 2), "--workers", "1")
    assert done.returncode == 0, done.stderr
    gone = sorted(dataset.glob("static_A_none_*.parquet"))[0]
    gone_id = read_session_meta(gone)[0].session_id
    gone.unlink()
    before = {p.name: p.stat().st_mtime_ns for p in out.glob("*.rrd")}
    again = run_command("recorder", "catalog", str(dataset), "--out", str(out), "--model",
                        str(model), "--workers", "1")
    assert again.returncode == 0, again.stderr
    assert "2 replayed, 7 unchanged, 1 removed" in again.stderr
    after = {p.name: p.stat().st_mtime_ns for p in out.glob("*.rrd")}
    assert f"{gone_id}.rrd" not in after
    assert sum(name not in before for name in after) == 2
    assert all(after[name] == before[name] for name in after if name in before)
    assert notes.read_text() == "mine"
    count = run_command("recorder", "query", str(out), "SELECT count(*) AS n FROM sessions",
                        "--json")
    assert json.loads(count.stdout.splitlines()[0])["n"] == SESSIONS + 2 - 1


def test_bad_catalog_input_is_one_line_and_touches_nothing(tmp_path, smoke, model):
    dataset = tmp_path / "two"
    dataset.mkdir()
    for path in sorted(smoke.glob("static_A_[bs]*.parquet")):
        shutil.copy2(path, dataset)
    out = tmp_path / "cat"
    out.mkdir()
    foreign = out / "theirs.rrd"
    foreign.write_bytes(b"someone else's recording")
    refused = run_command("recorder", "catalog", str(dataset), "--out", str(out), "--model",
                          str(model), "--workers", "1")
    assert "theirs.rrd" in _one_line_error(refused)
    assert foreign.read_bytes() == b"someone else's recording"
    assert sorted(p.name for p in out.iterdir()) == ["theirs.rrd"]
    foreign.rename(tmp_path / "theirs.rrd")
    built = run_command("recorder", "catalog", str(dataset), "--out", str(out), "--model",
                        str(model), "--workers", "1")
    assert built.returncode == 0, built.stderr
    ours = sorted(out.glob("*.rrd"))[0]
    kept = ours.read_bytes()
    ours.write_bytes(b"a user's file under the recording's name")
    replaced = run_command("recorder", "catalog", str(dataset), "--out", str(out), "--model",
                           str(model), "--workers", "1")
    assert ours.name in _one_line_error(replaced)
    assert ours.read_bytes() == b"a user's file under the recording's name"
    ours.write_bytes(kept)
    other = save_quick_model(tmp_path / "other.skops", events=True)
    with open(other, "ab") as fh:  # another file, another identity
        fh.write(b"\0")
    mismatch = run_command("recorder", "catalog", str(dataset), "--out", str(out), "--model",
                           str(other), "--workers", "1")
    assert "--overwrite" in _one_line_error(mismatch)
    first = next(dataset.glob("*.parquet"))
    shutil.copy2(first, dataset / "copy_of_it.parquet")
    twice = run_command("recorder", "catalog", str(dataset), "--out", str(out), "--model",
                        str(model), "--workers", "1")
    assert "in two files" in _one_line_error(twice)
    outside = sorted(p.name for p in tmp_path.iterdir())
    assert outside == sorted(["two", "cat", "theirs.rrd", "other.skops"])


@pytest.mark.parametrize("sql", [
    "COPY sessions TO '{dir}/leak.csv'",
    "SELECT 1; SELECT 2",
    "SELECT * FROM '{dir}/leak.parquet'",
    "SELECT * FROM read_parquet('/etc/passwd')",
    "CREATE TABLE x AS SELECT 1",
    "INSERT INTO sessions SELECT * FROM sessions",
    "EXPLAIN SELECT * FROM sessions",
    "SELECT * FROM generate_series(1, 3)",
    "SELECT FROM WHERE",
    "SELECT nope FROM sessions",
])
def test_query_refuses_anything_but_reading_the_two_tables(catalog, tmp_path, sql):
    done = run_command("recorder", "query", str(catalog), sql.format(dir=tmp_path))
    _one_line_error(done)
    assert not list(tmp_path.iterdir())


def test_browse_serves_the_catalog_until_ctrl_c_and_refuses_a_taken_port(catalog, smoke):
    from rerun.catalog import CatalogClient

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        refused = run_command("recorder", "browse", str(catalog), "--port", str(port),
                              "--viewer", "none")
        assert "already in use" in _one_line_error(refused)
    proc = subprocess.Popen([str(BIN / "recorder"), "browse", str(catalog), "--viewer", "none"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, DISPLAY=""))
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("rerun+http://127.0.0.1:"), proc.stderr.read()
        dataset = CatalogClient(url).get_dataset("contactkit")
        assert sorted(dataset.segment_ids()) == sorted(_session_ids(smoke))
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_stats_report_links_each_session_to_its_recording(tmp_path, smoke, catalog):
    (tmp_path / "smoke").symlink_to(smoke)
    (tmp_path / "smoke-catalog").symlink_to(catalog)  # the default place: beside the dataset
    done = run_command("recorder", "stats", str(tmp_path / "smoke"), "--out",
                       str(tmp_path / "report.html"))
    assert done.returncode == 0, done.stderr
    page = (tmp_path / "report.html").read_text()
    for sid in _session_ids(smoke):
        assert f'<a href="smoke-catalog/{sid}.rrd">{sid}</a>' in page
    missing = run_command("recorder", "stats", str(smoke), "--catalog", str(tmp_path / "nope"),
                          "--out", str(tmp_path / "r2.html"))
    assert "catalog folder not found" in _one_line_error(missing)


def test_a_session_that_fails_is_listed_and_the_others_are_written(tmp_path, smoke, model):
    dataset = tmp_path / "data"
    dataset.mkdir()
    for path in sorted(smoke.glob("static_A_[bs]*.parquet")):
        shutil.copy2(path, dataset)
    (dataset / "broken.parquet").write_bytes(b"not parquet")
    out = tmp_path / "cat"
    done = run_command("recorder", "catalog", str(dataset), "--out", str(out), "--model",
                       str(model), "--workers", "2")
    assert done.returncode == 2
    assert "2 replayed" in done.stderr and "1 failed" in done.stderr
    assert "failed broken.parquet:" in " ".join(done.stderr.split())
    assert len(list(out.glob("*.rrd"))) == 2


def test_a_catalog_of_other_dynamics_is_refused_without_overwrite(catalog, model):
    from contactkit.errors import InputError
    from contactkit.replay.catalog import CatalogIdentity, check_catalog, model_identity

    same = CatalogIdentity(model_identity(model, "renamed.skops"))
    assert len(check_catalog(catalog, same)) == SESSIONS  # the same bytes: the same model
    other = CatalogIdentity(same.model, dynamics={"name": "lab.toml", "sha256": "0" * 64})
    with pytest.raises(InputError, match="--overwrite"):
        check_catalog(catalog, other)
    rebuild = check_catalog(catalog, other, overwrite=True)  # every session replayed
    assert all(entry["sha256"] is None for entry in rebuild.values())
