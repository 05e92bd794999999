"""recorder stats: counts equal the known ones, problems are named, reports render."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import polars as pl
import pytest

from contactkit.recorder.sim.noise import SensorNoise
from contactkit.recorder.stats.summary import index_stats
from tests.conftest import make_dataset, run_command

SCHEMA = Path(__file__).resolve().parents[2] / "schemas" / "stats_report.schema.json"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    directory = make_dataset(tmp_path_factory.mktemp("stats"))
    first = sorted(directory.glob("*.parquet"))[0]
    (directory / "corrupt_a.parquet").write_bytes(b"definitely not parquet")
    (directory / "corrupt_b.parquet").write_bytes(first.read_bytes()[:2000])
    shutil.copy(first, directory / "zz_duplicate.parquet")
    return directory


def _check_required(schema: dict, doc, where: str = "report") -> None:
    if isinstance(doc, dict):
        for key in schema.get("required", []):
            assert key in doc, f"{where} lacks {key}"
        for key, sub in schema.get("properties", {}).items():
            if doc.get(key) is not None:
                _check_required(sub, doc[key], f"{where}.{key}")
    elif isinstance(doc, list) and "items" in schema:
        for item in doc:
            _check_required(schema["items"], item, where + "[]")


def test_index_report_counts_and_problems(dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "report.json"
    result = run_command("recorder", "stats", str(dataset), "--format", "json", "--out", str(out))
    assert result.returncode == 0, result.stderr
    report = json.loads(out.read_text())
    _check_required(json.loads(SCHEMA.read_text()), report)
    assert report["sessions"] == 32
    counts = report["counts"]["by_condition_pose_action"]
    assert len(counts) == 16 and all(row["sessions"] == 2 for row in counts)
    assert {(r["action"], r["sessions"]) for r in report["counts"]["by_action"]} == {
        ("none", 8), ("bump", 8), ("adjust", 8), ("shove", 8)}
    assert report["class_balance_warnings"] == []
    named = {p["file"]: p["problem"] for p in report["problems"]}
    assert "not a readable Parquet file" in named["corrupt_a.parquet"]
    assert "corrupt_b.parquet" in named
    assert "duplicate session id" in named["zz_duplicate.parquet"]
    also = named["zz_duplicate.parquet"].split("(also in ", 1)[1].rstrip(")").split(", ")
    assert also and all((dataset / name).is_file() for name in also)
    assert "zz_duplicate.parquet" not in also
    assert report["deep"] is None and report["fingerprint"]["kind"].startswith("index")
    assert "problems" in result.stderr and "corrupt_a.parquet" in result.stderr


def test_deep_report_markdown_and_noise_file(dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "deep.md"
    result = run_command("recorder", "stats", str(dataset), "--deep", "--format", "md", "--out",
                         str(out), "--workers", "2")
    assert result.returncode == 0, result.stderr
    text = out.read_text()
    for heading in ("## Problems", "## Peaks by class", "## Force profiles", "## Windows",
                    "## Joint limits", "## Torque noise baseline"):
        assert heading in text
    assert "corrupt_a.parquet" in text and "duplicate session id" in text
    plots = sorted(tmp_path.glob("deep_plot*.png"))
    assert len(plots) >= 6 and all(p.stat().st_size > 5000 for p in plots)
    noise = SensorNoise.from_file(tmp_path / "deep_noise.json")
    assert all(0.0 < s < 1.0 for s in noise.tau_sigma_nm)
    assert "files (session ids and file SHA-256)" in result.stderr.replace("\n", "")


def test_markdown_report_refuses_a_foreign_plot_before_writing_any(dataset: Path,
                                                                  tmp_path: Path) -> None:
    """The Markdown report's plots and page are checked together before any is written:
    a user's file at the second plot's name left the first plot written."""
    (tmp_path / "r_plot2.png").write_bytes(b"mine")
    result = run_command("recorder", "stats", str(dataset), "--format", "md", "--out",
                         str(tmp_path / "r.md"))
    assert result.returncode == 2 and "r_plot2.png" in result.stderr, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r_plot2.png"]


def test_deep_json_sections_and_html(dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "deep.json"
    result = run_command("recorder", "stats", str(dataset), "--deep", "--format", "json", "--out",
                         str(out), "--workers", "2")
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == str(out)
    assert (tmp_path / "deep_noise.json").is_file()
    report = json.loads(out.read_text())
    _check_required(json.loads(SCHEMA.read_text()), report)
    deep = report["deep"]
    assert deep["sampling"]["rate_hz"]["median"] == pytest.approx(250.0)
    assert deep["noise_baseline"]["sessions"] == 8
    assert {w["action"] for w in deep["window_detection"]} == {"none", "bump", "adjust", "shove"}
    peaks = {p["action"]: p["peak_residual_norm_nm"]["median"] for p in deep["peaks_by_class"]}
    assert peaks["shove"] > peaks["none"]
    written = run_command("recorder", "stats", str(dataset), "--out", str(tmp_path / "r"))
    html = tmp_path / "r.html"
    assert written.returncode == 0, written.stderr
    assert written.stdout.strip() == str(html)
    page = html.read_text()
    assert page.startswith("<!doctype html>") and "data:image/png;base64," in page
    # plain tables: no Polars repr (shape caption, dtype row, quoted strings); units shown
    assert "shape:" not in page and "<td>str</td>" not in page
    assert "<td>&quot;" not in page and "<td>\"" not in page
    assert "<th>share [%]</th>" in page and "<td class=num>25</td>" in page
    bad = run_command("recorder", "stats", str(dataset), "--format", "pdf")
    assert bad.returncode == 2 and "'pdf' is not one of 'html', 'md', 'json'" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1


def test_under_represented_class_warns() -> None:
    rows = [{"file": f"{i}.parquet", "session_id": str(i), "source": "sim",
             "condition": "static", "pose": "A", "target_pose": None,
             "action": "shove" if i < 2 else ("none", "bump", "adjust")[i % 3], "link": 3,
             "speed_rad_s": None, "planned_at_s": 5.0, "duration_s": 12.0, "t_end_s": 12.0,
             "operator": "x", "robot": "panda", "recovered": False, "file_bytes": 100,
             "n_samples": 12001}
            for i in range(30)]
    stats = index_stats(pl.LazyFrame(rows))
    assert any("'shove' is under-represented" in w for w in stats["class_balance_warnings"])
    assert stats["robots"] == [{"robot": "panda", "sessions": 30}]
    mixed = index_stats(pl.LazyFrame([{**row, "robot": ("panda", "fr3")[i % 2]}
                                      for i, row in enumerate(rows)]))
    assert any("sessions of 2 robots (fr3, panda)" in w
               for w in mixed["class_balance_warnings"])


def test_slow_sessions_are_problems() -> None:
    rows = [{"file": f"{i}.parquet", "session_id": str(i), "source": "ros-bag",
             "condition": "static", "pose": "A", "target_pose": None, "action": "none",
             "link": None, "speed_rad_s": None, "planned_at_s": 5.0, "duration_s": 12.0,
             "t_end_s": 12.0, "operator": "x", "robot": "panda", "recovered": False,
             "file_bytes": 100, "n_samples": n} for i, n in enumerate((361, 12001))]
    problems = index_stats(pl.LazyFrame(rows))["problems"]
    slow = [p for p in problems if "too slow for the feature chain" in p["problem"]]
    assert [p["file"] for p in slow] == ["0.parquet"]
