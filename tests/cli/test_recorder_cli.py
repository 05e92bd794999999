"""The recorder command line as a user meets it: outputs, datasets and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from contactkit.schemas import validate_session
from tests.conftest import run_cli


def test_capture_prints_path_and_same_seed_gives_same_file(tmp_path: Path) -> None:
    args = ["capture", "--pose", "B", "--action", "adjust", "--seed", "5", "--duration", "4",
            "--planned-at", "2", "--rate", "500"]
    first = run_cli("recorder", *args, "--out", str(tmp_path / "a"))
    second = run_cli("recorder", *args, "--out", str(tmp_path / "b"))
    assert first.returncode == 0, first.stderr
    a, b = Path(first.stdout.strip()), Path(second.stdout.strip())
    assert a.name == b.name and a.parent.name == "a"
    ta, tb = pq.read_table(a), pq.read_table(b)
    assert ta.drop_columns([]).equals(tb)
    ma, mb = validate_session(a).meta, validate_session(b).meta
    ma.created_utc = mb.created_utc = ""
    assert ma == mb
    assert validate_session(a).meta.action == "adjust"


def test_capture_dynamic_options(tmp_path: Path) -> None:
    result = run_cli("recorder", "capture", "--pose", "A", "--action", "bump", "--condition",
                     "dynamic", "--target-pose", "E", "--speed", "0.5", "--link", "3",
                     "--rate", "250", "--seed", "1", "--operator", "ana", "--out",
                     str(tmp_path))
    assert result.returncode == 0, result.stderr
    meta = validate_session(result.stdout.strip()).meta
    assert (meta.condition, meta.target_pose, meta.link, meta.operator) == ("dynamic", "E", 3,
                                                                            "ana")
    assert meta.speed_rad_s == 0.5 and meta.nominal_rate_hz == 250


BAD = [
    (["--pose", "Z", "--action", "bump"], "'Z' is not one of"),
    (["--pose", "A", "--action", "hug"], "'hug' is not one of"),
    (["--pose", "A", "--action", "bump", "--link", "0"], "unknown link 0"),
    (["--pose", "A", "--action", "bump", "--duration", "-2"], "duration must be positive"),
    (["--pose", "A", "--action", "bump", "--duration", "1e308"], "at most 86400 s"),
    (["--pose", "A", "--action", "bump", "--planned-at", "30"], "outside the session"),
    (["--pose", "A", "--action", "bump", "--rate", "0"], "rate must be between"),
    (["--pose", "A", "--action", "bump", "--source", "ros"], "'ros' is not one of"),
    (["--pose", "A"], "Missing option '--action'"),
]


@pytest.mark.parametrize(("args", "message"), BAD)
def test_capture_bad_input_is_one_line_exit_2_nothing_written(tmp_path: Path, args: list,
                                                              message: str) -> None:
    out = tmp_path / "out"
    result = run_cli("recorder", "capture", *args, "--out", str(out))
    assert result.returncode == 2
    assert message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.stderr
    assert not out.exists() or not any(out.iterdir())


def test_capture_unwritable_directory_and_existing_file(tmp_path: Path) -> None:
    blocked = tmp_path / "file-not-dir"
    blocked.write_text("x")
    result = run_cli("recorder", "capture", "--pose", "A", "--action", "none", "--out",
                     str(blocked / "sub"))
    assert result.returncode == 2 and "cannot create output directory" in result.stderr
    args = ["capture", "--pose", "A", "--action", "none", "--seed", "3", "--duration", "1",
            "--planned-at", "0.5", "--rate", "200", "--out", str(tmp_path / "d")]
    path = Path(run_cli("recorder", *args).stdout.strip())
    before = path.read_bytes()
    again = run_cli("recorder", *args)
    assert again.returncode == 2 and "already exists" in again.stderr
    assert path.read_bytes() == before
    assert run_cli("recorder", *args, "--overwrite").returncode == 0


def test_info_reports_rate_and_contact(session_path: Path) -> None:
    result = run_cli("recorder", "info", str(session_path), "--json")
    info = json.loads(result.stdout)
    assert info["sampling"]["samples"] == 1501
    assert info["sampling"]["rate_hz"] == pytest.approx(500.0)
    lo, hi = info["contact_interval_s"]
    assert 1.5 <= lo < hi < 3.0
    text = run_cli("recorder", "info", str(session_path))
    assert "500.0 Hz" in text.stdout and "contact" in text.stdout
    assert "event 1" not in text.stdout  # a session recorded without live events has none
    bad = session_path.with_name("bad.parquet")
    bad.write_bytes(b"nope")
    result = run_cli("recorder", "info", str(bad))
    assert result.returncode == 2 and result.stderr.startswith(f"recorder: error: {bad}: ")


def test_simulate_smoke_in_parallel_then_skips(tmp_path: Path) -> None:
    result = run_cli("recorder", "simulate", str(tmp_path), "--preset", "smoke", "--workers",
                     "2", "--rate", "250")
    assert result.returncode == 0, result.stderr
    index = pq.read_table(tmp_path / "index.parquet").to_pydict()
    assert len(index["file"]) == 8
    assert sorted(index["action"]) == sorted(["none", "bump", "adjust", "shove"] * 2)
    assert sorted(set(index["pose"])) == ["A", "B"]
    again = run_cli("recorder", "simulate", str(tmp_path), "--preset", "smoke", "--rate", "250")
    assert "0 written, 8 already there" in again.stderr
    (tmp_path / index["file"][0]).unlink()
    (tmp_path / "junk.parquet").write_bytes(b"junk")
    rebuilt = run_cli("recorder", "index", str(tmp_path))
    assert "7 sessions indexed" in rebuilt.stderr and "junk.parquet" in rebuilt.stderr
