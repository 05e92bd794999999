"""Nothing recorded is lost: the journal, recovery, and a capture killed mid-way."""

from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from contactkit.recorder.capture.journal import (
    SessionWriter,
    journal_path,
    read_journal,
    recover_directory,
)
from contactkit.schemas import InputError, SessionMeta, validate_session
from tests.conftest import BIN, kill_when_journal_holds, run_cli


def _rows(t0: float, n: int, step: float = 0.001) -> dict[str, np.ndarray]:
    t = t0 + step * np.arange(n)
    cols = {"t": t}
    for prefix in ("q", "dq", "tau"):
        for i in range(1, 8):
            cols[f"{prefix}_{i}"] = np.sin(t * i)
    return cols


COLUMNS = list(_rows(0, 1))
META = SessionMeta(session_id="journaltest", source="sim", action="bump")


def test_writer_flushes_every_half_interval_and_closes(tmp_path: Path) -> None:
    out = tmp_path / "s.parquet"
    writer = SessionWriter(out, META, COLUMNS, flush_interval_s=0.1)
    for k in range(30):
        writer.append(_rows(k * 0.01, 10))
        pending = (k + 1) * 10 - writer.samples_written
        assert pending * 0.001 <= 0.1
        if writer.samples_written:
            assert read_journal(journal_path(out)).table.num_rows == writer.samples_written
    path = writer.close()
    assert not journal_path(out).exists()
    assert validate_session(path).n_samples == 300


def test_writer_refuses_existing_output(tmp_path: Path) -> None:
    out = tmp_path / "s.parquet"
    out.write_bytes(b"precious")
    with pytest.raises(InputError, match="already exists"):
        SessionWriter(out, META, COLUMNS)
    assert out.read_bytes() == b"precious" and not journal_path(out).exists()


def test_recover_drops_torn_batch_and_marks_session(tmp_path: Path) -> None:
    out = tmp_path / "s.parquet"
    writer = SessionWriter(out, META, COLUMNS, flush_interval_s=0.02)
    for k in range(5):
        writer.append(_rows(k * 0.02, 20))
    writer.abort()
    journal = journal_path(out)
    journal.write_bytes(journal.read_bytes()[:-500])
    (recovery,) = recover_directory(tmp_path)
    session = validate_session(recovery.session)
    assert session.meta.recovered and session.meta.recovered_samples == 80
    assert "torn" in recovery.note and not journal.exists()
    assert np.allclose(session.t, 0.001 * np.arange(80))


def test_recover_removes_stale_journal_of_complete_session(tmp_path: Path) -> None:
    out = tmp_path / "s.parquet"
    writer = SessionWriter(out, META, COLUMNS)
    writer.append(_rows(0, 100))
    writer.close()
    journal_path(out).write_bytes(b"left over")
    (recovery,) = recover_directory(tmp_path)
    assert "stale" in recovery.note and validate_session(out).n_samples == 100


def test_capture_killed_midway_loses_nothing_older_than_flush(tmp_path: Path) -> None:
    args = ["--pose", "C", "--action", "shove", "--seed", "21", "--duration", "6",
            "--planned-at", "4", "--rate", "1000"]
    live_dir, full_dir = tmp_path / "live", tmp_path / "full"
    live_dir.mkdir()
    returncode, held = kill_when_journal_holds(
        [str(BIN / "recorder"), "capture", *args, "--realtime", "--out", str(live_dir)],
        live_dir, 1000)
    assert returncode == -signal.SIGKILL
    assert not list(live_dir.glob("*.parquet")) and list(live_dir.glob("*.journal"))
    recovered = run_cli("recorder", "recover", str(live_dir))
    assert recovered.returncode == 0, recovered.stderr
    (path,) = live_dir.glob("*.parquet")
    session = validate_session(path)
    assert session.meta.recovered and session.meta.recovered_samples == session.n_samples
    assert session.n_samples >= held >= 1000  # every sample flushed before the kill
    full = run_cli("recorder", "capture", *args, "--out", str(full_dir))
    reference = pq.read_table(full.stdout.strip())
    n = session.n_samples
    for name in session.table.column_names:
        assert np.array_equal(session.column(name), reference.column(name).to_numpy()[:n]), name


def test_recover_keeps_a_journal_whose_session_name_holds_another_file(tmp_path: Path,
                                                                       capsys) -> None:
    """An unrelated file at the session's name is no reason to delete the journal, and
    one journal that cannot be recovered does not stop the others."""
    from contactkit.cli.common import run_app
    from contactkit.cli.recorder import app

    paths = []
    for name in ("a.parquet", "b.parquet", "c.parquet"):
        writer = SessionWriter(tmp_path / name, SessionMeta(
            session_id=name[0] * 8, source="sim", action="bump"), COLUMNS,
            flush_interval_s=0.02)
        for k in range(3):
            writer.append(_rows(k * 0.02, 20))
        writer.abort()
        paths.append(tmp_path / name)
    paths[0].write_bytes(b"mine")
    code = run_app(app, "recorder", ["recover", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == 2
    assert paths[0].read_bytes() == b"mine" and journal_path(paths[0]).exists()
    assert "left in place" in out and "a.parquet" in out
    for path in paths[1:]:
        assert validate_session(path).meta.recovered and not journal_path(path).exists()
    assert run_app(app, "recorder", ["recover", str(tmp_path)]) == 2  # again: the same
    assert paths[0].read_bytes() == b"mine" and journal_path(paths[0]).exists()
