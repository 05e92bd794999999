"""The browser check: a replay and a stats report opened in headless Chromium."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import psutil
import pytest

from tests.conftest import make_session, run_cli
from tests.test_replay import model_path  # noqa: F401  (the fixture)

TOOL = Path(__file__).resolve().parents[1] / "tools" / "viewer_check.py"


def _load_tool():
    spec = importlib.util.spec_from_file_location("viewer_check", TOOL)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while defining
    spec.loader.exec_module(module)
    return module


viewer_check = _load_tool()


@pytest.fixture(scope="module")
def browser_ready() -> None:
    if viewer_check.find_chromium() is None:
        pytest.skip("Chromium is not installed (apt-get install chromium); the browser "
                    "check needs it")
    if importlib.util.find_spec("playwright") is None:
        pytest.skip("Playwright is not installed (pip install 'contactkit[browser]')")


def run_check(*args: str, timeout: float) -> subprocess.CompletedProcess:
    """Run the browser check; skip the test, saying why, when the browser stops
    answering (exit code STALLED, or no answer in ``timeout`` s). Seen only inside the
    full suite on a loaded machine: Playwright's driver and the Rerun web server then
    spin on both cores while Chromium draws nothing. A viewer problem (exit code 1)
    still fails."""
    try:
        check = run_cli(sys.executable, str(TOOL), *args, timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.skip(f"the browser stopped answering: no answer in {timeout:.0f} s (a stall "
                    "of Playwright's driver seen on loaded machines; run `make viewer-check`)")
    if check.returncode == viewer_check.STALLED:
        pytest.skip("the browser stopped answering (a stall of Playwright's driver seen on "
                    f"loaded machines; run `make viewer-check`): {check.stderr.strip()}")
    return check


@pytest.mark.browser
def test_replay_and_report_open_without_viewer_errors(browser_ready, tmp_path,
                                                      model_path) -> None:  # noqa: F811
    data = tmp_path / "data"
    data.mkdir()
    session = make_session(data, seed=4, action="bump", link=5, duration_s=2.0,
                           planned_at_s=1.0)
    rrd = tmp_path / "replay.rrd"
    result = run_cli("replay", str(session), "--viewer", "none", "--save", str(rrd),
                     "--model", str(model_path))
    assert result.returncode == 0, result.stderr
    report = run_cli("recorder", "stats", str(data), "--out", str(tmp_path / "report"))
    assert report.returncode == 0, report.stderr
    out = tmp_path / "check"
    check = run_check(str(rrd), "--report", str(tmp_path / "report.html"), "--out", str(out),
                      "--timeout", "150", timeout=360)
    assert check.returncode == 0, check.stdout + check.stderr
    findings = json.loads((out / "viewer_check.json").read_text())
    assert [f["ok"] for f in findings] == [True, True]
    assert (out / "replay.png").stat().st_size > 10_000
    assert (out / "report.png").stat().st_size > 10_000


@pytest.mark.browser
def test_a_broken_report_image_is_found(browser_ready, tmp_path) -> None:
    page = tmp_path / "broken.html"
    page.write_text("<!doctype html><html><body><h1>r</h1>"
                    "<img alt='plot' src='data:image/png;base64,AAAA'></body></html>")
    check = run_check("--report", str(page), "--out", str(tmp_path / "check"), timeout=180)
    assert check.returncode == 1
    assert "broken image: plot" in check.stdout


def test_viewer_messages_keep_the_viewer_s_own_problems() -> None:
    console = [("error", " ERROR re_tf::cache: Two entities define the same child frame"),
               ("warning", " WARN egui_wgpu: Software rasterizer detected"),
               ("warning", " WARN re_viewer::ui::welcome_screen::x: Failed to load examples"),
               ("error", "Failed to load resource: net::ERR_NAME_NOT_RESOLVED"),
               ("warning", " WARN re_data_loader: something odd")]
    errors, warnings = viewer_check.viewer_messages(console)
    assert errors == ["re_tf::cache: Two entities define the same child frame"]
    assert warnings == ["re_data_loader: something odd"]


def test_a_stalled_check_kills_its_children_and_says_so(tmp_path) -> None:
    script = tmp_path / "stall.py"
    script.write_text(
        "import subprocess, sys, time\n"
        f"sys.path.insert(0, {str(TOOL.parent)!r})\n"
        "import viewer_check\n"
        "child = subprocess.Popen(['sleep', '60'])\n"
        "print(child.pid, flush=True)\n"
        "viewer_check.start_watchdog(1.0)\n"
        "time.sleep(60)\n")
    result = run_cli(sys.executable, str(script), timeout=30)
    assert result.returncode == viewer_check.STALLED
    assert "stopped answering" in result.stderr
    assert not psutil.pid_exists(int(result.stdout)) or psutil.Process(
        int(result.stdout)).status() == psutil.STATUS_ZOMBIE


def test_a_timed_out_command_takes_its_children_with_it() -> None:
    with pytest.raises(subprocess.TimeoutExpired):
        run_cli("/bin/sh", "-c", "sleep 60 & sleep 60", timeout=2)


@pytest.mark.browser
def test_catalog_table_lists_every_session_and_a_session_opens(browser_ready, tmp_path,
                                                               model_path) -> None:  # noqa: F811
    data = tmp_path / "data"
    data.mkdir()
    for seed, action in ((4, "bump"), (5, "shove")):
        make_session(data, seed=seed, action=action, link=5, duration_s=2.0, planned_at_s=1.0)
    catalog = tmp_path / "catalog"
    built = run_cli("recorder", "catalog", str(data), "--out", str(catalog), "--model",
                    str(model_path), "--workers", "1")
    assert built.returncode == 0, built.stderr
    out = tmp_path / "check"
    check = run_check("--catalog", str(catalog), "--out", str(out), "--timeout", "150",
                      timeout=480)
    assert check.returncode == 0, check.stdout + check.stderr
    findings = json.loads((out / "viewer_check.json").read_text())
    assert [f["ok"] for f in findings] == [True, True]
    assert (out / "catalog_table.png").stat().st_size > 10_000


def _literal_lz4(data: bytes) -> bytes:
    """Return ``data`` as one LZ4 block of literals only (valid LZ4, no compression)."""
    n = len(data)
    head = bytes([min(n, 15) << 4])
    if n >= 15:
        rest = n - 15
        head += b"\xff" * (rest // 255) + bytes([rest % 255])
    return head + data


def test_catalog_answers_are_decoded_as_the_viewer_reads_them() -> None:
    import pyarrow as pa

    table = pa.table({"rerun_segment_id": ["a1", "b2"], "property:session:action": ["x", "y"]})
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, table.schema) as writer:
        writer.write_table(table)
    payload = _literal_lz4(sink.getvalue().to_pybytes())
    part = b"\x08\x01\x12" + _varint_bytes(len(payload)) + payload
    message = b"\x0a" + _varint_bytes(len(part)) + part
    trailer = b"grpc-status:0\r\n"
    body = (b"\x00" + len(message).to_bytes(4, "big") + message
            + b"\x80" + len(trailer).to_bytes(4, "big") + trailer)
    segments, columns = viewer_check.table_contents([body])
    assert segments == {"a1", "b2"}
    assert "property:session:action" in columns
    assert viewer_check.lz4_block(b"\x1fa\x01\x00\x00") == b"a" * 20  # a match copies back


def _varint_bytes(value: int) -> bytes:
    out = bytearray()
    while True:
        out.append((value & 0x7F) | (0x80 if value > 0x7F else 0))
        value >>= 7
        if not value:
            return bytes(out)
