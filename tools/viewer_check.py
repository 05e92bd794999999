"""Open Rerun recordings and stats reports in headless Chromium, as a user would, and
report what the viewer complains about.

    python tools/viewer_check.py demo.rrd real.rrd --report report.html --out viewer-check/
    python tools/viewer_check.py --catalog smoke-catalog --out viewer-check/

For each ``.rrd``: serve it with the SDK's own ``rerun --serve-web`` on 127.0.0.1,
open the web viewer in Chromium at 1600x1000 (``&renderer=webgl``: software
rendering has no usable WebGPU), wait until the recording is loaded (the screen stops
changing), then collect

- the viewer's notifications: its log messages at warning and error level (the
  notification panel shows the same messages), minus what only this browser set-up
  causes (software rasteriser, no network for the examples page, viewport commands
  the web backend ignores);
- the error markers that views draw in their title bars (the viewer's error red);
  the tooltip of each is hovered and saved as a screenshot;

and write ``<name>.png`` (the whole window). For a catalog (``recorder catalog``):
start Rerun's catalog server on it (``recorder browse``'s, on 127.0.0.1), open the web
viewer connected to it, check that the dataset's table the viewer received from the
server lists every session of the catalog and the properties' columns (the gRPC
answers the page read, which the canvas does not show as text), screenshot it
(``<catalog>_table.png``), then open the first session and check it as a recording
(``<catalog>_session.png``). For each HTML report: open it, fail on
an image that does not load, and write a full-page screenshot. A summary goes to
``viewer_check.json``. Exit code 0: no problems; 1: problems found; 2: Chromium or
Playwright missing, or bad arguments.

Chromium: Debian/Ubuntu ``apt-get install chromium``; Playwright: ``pip install
'contactkit[browser]'`` (Playwright's own browser download is not needed).
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import os
import re
import shutil
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from io import BytesIO
from pathlib import Path

import numpy as np
import psutil

from contactkit.errors import InputError
from contactkit.util.atomic import write_bytes, write_text
from contactkit.viewer.web import free_port, start_web_viewer, viewer_page_url

VIEWPORT = {"width": 1600, "height": 1000}
CHROMIUM_FLAGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update",
                  "--disable-sync"]
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "chrome")
ERROR_RED = (236, 0, 79)
TOP_BAR_PX = 32
POLL_S = 3.0
TIME_BAR_PX = (267, 1391, 985)  # the time bar at the bottom at 1600x1000: start, end x; y
STABLE_SHOTS = 3
RUST_LOG = re.compile(r"^\s*(ERROR|WARN)\s+(\S+?):?\s(.*)", re.S)
# Messages that come from this headless set-up, not from the recording.
ENVIRONMENT = ("eframe::", "egui_wgpu", "re_renderer::context",
               "re_viewer::ui::welcome_screen")


@dataclass
class Finding:
    """What one file looked like in the browser."""

    source: str
    screenshot: str
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    error_markers: list[str] = field(default_factory=list)
    broken_images: list[str] = field(default_factory=list)
    load_s: float = 0.0

    @property
    def ok(self) -> bool:
        """Return whether nothing was found."""
        return not (self.errors or self.warnings or self.error_markers or self.broken_images)


def find_chromium() -> str | None:
    """Return the path of a system Chromium, or None when there is none."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


def viewer_messages(console: list[tuple[str, str]]) -> tuple[list[str], list[str]]:
    """Return the viewer's own (errors, warnings) from (type, text) console messages."""
    errors, warnings = [], []
    for kind, text in console:
        if kind == "pageerror":
            errors.append(f"page error: {text}")
            continue
        match = RUST_LOG.match(text)
        if not match or match.group(2).startswith(ENVIRONMENT):
            continue
        line = f"{match.group(2)}: {' '.join(match.group(3).split())}"
        (errors if match.group(1) == "ERROR" else warnings).append(line)
    return sorted(set(errors)), sorted(set(warnings))


def error_marker_positions(png: bytes) -> list[tuple[int, int]]:
    """Return (x, y) centres [px] of the viewer's error-red marks below the top bar."""
    from PIL import Image
    from scipy import ndimage

    pixels = np.asarray(Image.open(BytesIO(png)).convert("RGB")).astype(int)
    red = np.abs(pixels - np.array(ERROR_RED)).sum(axis=2) < 40
    red[:TOP_BAR_PX] = False
    labels, n = ndimage.label(ndimage.binary_dilation(red, iterations=3))
    centres = []
    for index in range(1, n + 1):
        ys, xs = np.nonzero((labels == index) & red)
        if len(xs) >= 20:
            centres.append((int(xs.mean()), int(ys.mean())))
    return centres


def _capture(cdp, clip: dict | None = None) -> bytes:
    # The CDP call, not page.screenshot: Playwright waits for web fonts, which the
    # busy viewer page may not report for minutes.
    params: dict = {"format": "png"}
    if clip:
        params["clip"] = {**clip, "scale": 1}
    return base64.b64decode(cdp.send("Page.captureScreenshot", params)["data"])


def check_recording(browser, rrd: Path, out: Path, timeout_s: float,
                    cursor: float | None = None) -> Finding:
    """Serve ``rrd``, open it in ``browser`` and return what the viewer showed; with
    ``cursor`` (0-1), click the time bar there first."""
    grpc_port, web_port = free_port(), free_port()
    server, _, _ = start_web_viewer(grpc_port, web_port, files=[rrd])
    shot = out / f"{rrd.stem}.png"
    finding = Finding(str(rrd), str(shot))
    page = browser.new_page(viewport=VIEWPORT)
    console: list[tuple[str, str]] = []
    page.on("console", lambda m: console.append((m.type, m.text)))
    page.on("pageerror", lambda e: console.append(("pageerror", str(e))))
    try:
        cdp = page.context.new_cdp_session(page)
        started = time.monotonic()
        page.goto(viewer_page_url(grpc_port, web_port, renderer="webgl"))
        shots: list[bytes] = []
        while time.monotonic() - started < timeout_s:
            time.sleep(POLL_S)
            shots.append(_capture(cdp))
            streaming = any("Streaming messages" in text for _, text in console)
            if streaming and len(shots) >= STABLE_SHOTS and len(set(shots[-STABLE_SHOTS:])) == 1:
                break
        else:
            finding.errors.append(f"the viewer did not settle within {timeout_s:.0f} s")
        finding.load_s = round(time.monotonic() - started, 1)
        if cursor is not None:
            page.mouse.click(TIME_BAR_PX[0] + cursor * (TIME_BAR_PX[1] - TIME_BAR_PX[0]),
                             TIME_BAR_PX[2])
            time.sleep(POLL_S)
            shots.append(_capture(cdp))
        write_bytes(shot, shots[-1], overwrite=True)
        errors, warnings = viewer_messages(console)
        finding.errors += errors
        finding.warnings += warnings
        for i, (x, y) in enumerate(error_marker_positions(shots[-1])):
            page.mouse.click(x, y)
            time.sleep(2.0)
            left, top = max(0, x - 500), max(0, y - 40)
            tip = out / f"{rrd.stem}_marker{i + 1}.png"
            write_bytes(tip, _capture(cdp, {"x": left, "y": top, "width": min(1000, 1600 - left),
                                            "height": min(260, 1000 - top)}), overwrite=True)
            page.keyboard.press("Escape")
            finding.error_markers.append(f"error marker at ({x}, {y}) px, its report in {tip}")
    finally:
        page.close()
        server.terminate()
        server.wait()
    return finding


CATALOG_COLUMNS = ("property:session:action", "property:session:file",
                   "property:catalog:model", "property:result:offline_label")
"""Property columns the viewer must receive in a catalog's dataset table."""


def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[i]
        i += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, i


def lz4_block(src: bytes) -> bytes:
    """Return the bytes of one LZ4 block (the raw block format, no frame)."""
    out = bytearray()
    i = 0
    while i < len(src):
        token = src[i]
        i += 1
        literals = token >> 4
        if literals == 15:
            while True:
                literals += src[i]
                i += 1
                if src[i - 1] != 255:
                    break
        out += src[i:i + literals]
        i += literals
        if i >= len(src):
            break
        offset = src[i] | src[i + 1] << 8
        i += 2
        length = token & 15
        if length == 15:
            while True:
                length += src[i]
                i += 1
                if src[i - 1] != 255:
                    break
        start = len(out) - offset
        for k in range(length + 4):
            out.append(out[start + k])
    return bytes(out)


def received_tables(bodies: list[bytes]) -> list:
    """Return the Arrow tables in the catalog server's gRPC-web answers ``bodies``: each
    answer is a run of frames (flag byte, 4-byte length, message); a message carries
    Rerun's ``DataframePart`` (field 1 encoder version 1, field 2 the payload: an Arrow
    IPC stream compressed as one LZ4 block). What the page read, decoded as the viewer
    decodes it: the canvas shows no text to read back."""
    import pyarrow as pa

    tables = []
    for body in bodies:
        i = 0
        while i + 5 <= len(body):
            flag, size = body[i], int.from_bytes(body[i + 1:i + 5], "big")
            message = body[i + 5:i + 5 + size]
            i += 5 + size
            if flag & 0x80:  # the trailer (grpc-status)
                continue
            at = message.find(b"\x08\x01\x12")
            while at >= 0:
                with contextlib.suppress(Exception):
                    length, start = _varint(message, at + 3)
                    raw = lz4_block(message[start:start + length])
                    tables.append(pa.ipc.open_stream(raw).read_all())
                at = message.find(b"\x08\x01\x12", at + 1)
    return tables


def table_contents(bodies: list[bytes]) -> tuple[set[str], set[str]]:
    """Return the segment ids and the column names of the dataset tables in
    ``bodies`` (:func:`received_tables`)."""
    segments: set[str] = set()
    columns: set[str] = set()
    for table in received_tables(bodies):
        columns.update(table.column_names)
        if "rerun_segment_id" in table.column_names:
            segments.update(table.column("rerun_segment_id").to_pylist())
    return segments, columns


def _settle(page, cdp, console: list[tuple[str, str]], timeout_s: float,
            ready=lambda: True) -> tuple[list[bytes], bool]:
    """Screenshot ``page`` every :data:`POLL_S` until ``ready()`` and the screen stops
    changing; return the screenshots and whether it settled within ``timeout_s`` [s]."""
    started = time.monotonic()
    shots: list[bytes] = []
    while time.monotonic() - started < timeout_s:
        time.sleep(POLL_S)
        shots.append(_capture(cdp))
        if ready() and len(shots) >= STABLE_SHOTS and len(set(shots[-STABLE_SHOTS:])) == 1:
            return shots, True
    return shots, False


def check_catalog(browser, catalog: Path, out: Path, timeout_s: float) -> list[Finding]:
    """Serve a catalog, open its dataset table and its first session in the web viewer;
    return the findings of both (see the module docstring)."""
    import pyarrow.parquet as pq

    from contactkit.replay.browse import (
        dataset_url,
        open_viewer,
        segment_url,
        start_catalog_server,
    )
    from contactkit.replay.catalog import catalog_tables

    table = pq.read_table(catalog_tables(catalog)["sessions"])
    sessions = table.column("session_id").to_pylist()
    planned = table.column("planned_at_s").to_pylist()[0]
    server = start_catalog_server(catalog)
    findings = []
    try:
        targets = [("table", dataset_url(server)),
                   ("session", segment_url(server, sessions[0], planned))]
        for kind, target in targets:
            viewer, page_url = open_viewer(target, web=True)
            shot = out / f"{catalog.name}_{kind}.png"
            finding = Finding(f"{catalog} ({kind})", str(shot))
            page = browser.new_page(viewport=VIEWPORT)
            console: list[tuple[str, str]] = []
            received: list[bytes] = []  # what the page read from the catalog server
            server_http = server.url().replace("rerun+http", "http")

            def keep(response, received=received, server_http=server_http) -> None:
                if response.url.startswith(server_http):
                    with contextlib.suppress(Exception):
                        received.append(response.body())

            def listed(received=received, kind=kind) -> bool:
                return kind != "table" or set(sessions) <= table_contents(received)[0]

            page.on("console", lambda m, console=console: console.append((m.type, m.text)))
            page.on("pageerror", lambda e, console=console: console.append(("pageerror",
                                                                            str(e))))
            page.on("response", keep)
            try:
                cdp = page.context.new_cdp_session(page)
                started = time.monotonic()
                page.goto(page_url + "&renderer=webgl")
                shots, settled = _settle(page, cdp, console, timeout_s, listed)
                if not settled:
                    finding.errors.append(f"the viewer did not settle within {timeout_s:.0f} s")
                finding.load_s = round(time.monotonic() - started, 1)
                if kind == "table":
                    listed_ids, columns = table_contents(received)
                    finding.errors += [f"the dataset table lacks session {s}" for s in sessions
                                       if s not in listed_ids]
                    finding.errors += [f"the dataset table lacks the column {c}"
                                       for c in CATALOG_COLUMNS if c not in columns]
                if shots:
                    write_bytes(shot, shots[-1], overwrite=True)
                errors, warnings = viewer_messages(console)
                finding.errors += errors
                finding.warnings += warnings
            finally:
                page.close()
                viewer.terminate()
                viewer.wait()
            findings.append(finding)
    finally:
        server.shutdown()
    return findings


def check_report(browser, report: Path, out: Path) -> Finding:
    """Open an HTML report and return its broken images; write a full-page screenshot."""
    shot = out / f"{report.stem}.png"
    finding = Finding(str(report), str(shot))
    page = browser.new_page(viewport=VIEWPORT)
    page.on("pageerror", lambda e: finding.errors.append(f"page error: {e}"))
    try:
        page.goto(report.resolve().as_uri())
        page.wait_for_load_state("load")
        finding.broken_images = page.evaluate(
            "Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0))"
            ".map(i => i.alt || i.src.slice(0, 80))")
        page.screenshot(path=str(shot), full_page=True)
    finally:
        page.close()
    return finding


def run(recordings: list[Path], reports: list[Path], out: Path, timeout_s: float,
        chromium: str, cursor: float | None = None,
        catalogs: list[Path] | None = None) -> list[Finding]:
    """Check every recording, catalog and report in one browser; return the findings."""
    from playwright.sync_api import sync_playwright

    out.mkdir(parents=True, exist_ok=True)
    findings = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, args=CHROMIUM_FLAGS)
        try:
            for rrd in recordings:
                findings.append(check_recording(browser, rrd, out, timeout_s, cursor))
                print(_line(findings[-1]), flush=True)
            for catalog in catalogs or []:
                for finding in check_catalog(browser, catalog, out, timeout_s):
                    findings.append(finding)
                    print(_line(finding), flush=True)
            for report in reports:
                findings.append(check_report(browser, report, out))
                print(_line(findings[-1]), flush=True)
        finally:
            browser.close()
    write_text(out / "viewer_check.json", json.dumps(
        [asdict(f) | {"ok": f.ok} for f in findings], indent=2), overwrite=True)
    return findings


def _line(finding: Finding) -> str:
    problems = (finding.errors + finding.warnings + finding.error_markers
                + [f"broken image: {x}" for x in finding.broken_images])
    head = f"{finding.source}: {'ok' if finding.ok else f'{len(problems)} problems'}"
    head += f" (loaded in {finding.load_s} s)" if finding.load_s else ""
    return "\n  ".join([f"{head}; screenshot {finding.screenshot}", *problems])


STALLED = 3  # exit code: the browser or the viewer's server stopped answering
REPORT_BUDGET_S = 60.0  # s allowed for opening one HTML report


def start_watchdog(budget_s: float) -> threading.Timer:
    """Start a timer that, after ``budget_s`` [s], kills this program's child processes
    (Chromium, Playwright's driver, the Rerun web server) and exits with
    :data:`STALLED`: a browser that stops answering (a CDP call never returns, seen on
    an overloaded machine) must end the check, not hang it and its caller."""
    def give_up() -> None:
        print(f"viewer_check: error: the browser stopped answering; gave up after "
              f"{budget_s:.0f} s", file=sys.stderr, flush=True)
        children = psutil.Process().children(recursive=True)
        for child in children:
            with contextlib.suppress(psutil.Error):
                child.kill()
        # SIGKILL lands asynchronously: wait (bounded) until they are gone, so that a
        # caller that sees the exit code sees no child left behind
        psutil.wait_procs(children, timeout=10.0)
        os._exit(STALLED)

    timer = threading.Timer(budget_s, give_up)
    timer.daemon = True
    timer.start()
    return timer


def main(argv: list[str] | None = None) -> int:
    """Run the check from the command line; return the exit code (0 clean, 1 problems,
    2 no browser or bad arguments, 3 the browser stopped answering)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recordings", nargs="*", type=Path, help=".rrd files to open")
    parser.add_argument("--report", action="append", default=[], type=Path,
                        help="an HTML report to open (repeatable)")
    parser.add_argument("--catalog", action="append", default=[], type=Path,
                        help="a catalog folder (recorder catalog) to serve and open "
                             "(repeatable)")
    parser.add_argument("--out", type=Path, default=Path("viewer-check"),
                        help="directory for screenshots and viewer_check.json")
    parser.add_argument("--timeout", type=float, default=240.0,
                        help="seconds to wait for one recording to load")
    parser.add_argument("--cursor", type=float, default=None,
                        help="move the time cursor to this fraction (0-1) of the recording "
                             "before the screenshot (default: the end)")
    args = parser.parse_args(argv)
    missing = [p for p in [*args.recordings, *args.report] if not p.is_file()]
    missing += [p for p in args.catalog if not p.is_dir()]
    if missing or not (args.recordings or args.report or args.catalog):
        print(f"viewer_check: error: {missing[0] if missing else 'nothing'} to check"
              + (": no such file" if missing else ""), file=sys.stderr)
        return 2
    chromium = find_chromium()
    if chromium is None:
        print("viewer_check: error: no Chromium found (Debian/Ubuntu: apt-get install "
              "chromium)", file=sys.stderr)
        return 2
    try:
        import playwright  # noqa: F401
    except ImportError:
        print("viewer_check: error: Playwright is not installed (pip install "
              "'contactkit[browser]')", file=sys.stderr)
        return 2
    watchdog = start_watchdog((len(args.recordings) + 2 * len(args.catalog))
                              * (args.timeout + REPORT_BUDGET_S)
                              + len(args.report) * REPORT_BUDGET_S + REPORT_BUDGET_S)
    try:
        findings = run(args.recordings, args.report, args.out, args.timeout, chromium,
                       args.cursor, args.catalog)
    except InputError as err:
        print(f"viewer_check: error: {err}", file=sys.stderr)
        return 2
    finally:
        watchdog.cancel()
    bad = [f for f in findings if not f.ok]
    print(f"{len(findings) - len(bad)} of {len(findings)} clean; screenshots in {args.out}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
