"""Starting Rerun viewers for capture and replay."""

from __future__ import annotations

import importlib.util
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Sequence
from pathlib import Path
from urllib.parse import quote

from contactkit.errors import InputError

WEB_PORT = 9090
GRPC_PORT = 9876
HOST = "127.0.0.1"
START_TIMEOUT_S = 30.0


def has_display() -> bool:
    """Return whether a native viewer window can open (on Linux: a display is set)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def port_is_free(port: int, host: str = HOST) -> bool:
    """Return whether a TCP server could listen on ``host:port`` now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        try:
            probe.bind((host, port))
        except OSError:
            return False
    return True


def free_port(host: str = HOST) -> int:
    """Return a TCP port on ``host`` that nothing listens on (chosen by the OS)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])


def rerun_executable() -> str:
    """Return the path of the ``rerun`` viewer binary that ships with the installed SDK.

    The binary itself, not the ``rerun`` script in front of it: the script runs the
    binary as a child process, which would outlive a terminated script.
    """
    if os.environ.get("RERUN_CLI_PATH"):
        return os.environ["RERUN_CLI_PATH"]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        binary = Path(spec.origin).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
        if binary.is_file():
            return str(binary)
    return shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")


def viewer_page_url(grpc_port: int, web_port: int, renderer: str | None = None) -> str:
    """Return the web viewer's page URL that opens the gRPC proxy on ``grpc_port``
    (``renderer="webgl"`` for browsers without a GPU)."""
    grpc_url = f"rerun+http://{HOST}:{grpc_port}/proxy"
    page = f"http://{HOST}:{web_port}/?url={quote(grpc_url, safe='')}"
    return page + (f"&renderer={renderer}" if renderer else "")


def _serves_viewer(web_port: int) -> bool:
    try:
        with urllib.request.urlopen(f"http://{HOST}:{web_port}/", timeout=2) as answer:
            return answer.status == 200 and b"re_viewer" in answer.read()
    except OSError:
        return False


def start_web_viewer(grpc_port: int = GRPC_PORT, web_port: int = WEB_PORT,
                     files: Sequence[str | Path] = ()) -> tuple[subprocess.Popen, str, str]:
    """Start Rerun's web viewer and gRPC server bound to 127.0.0.1, optionally serving
    ``files`` (.rrd).

    Returns the server process, the gRPC URL to send recordings to, and the page URL
    to open in a browser. Raises :class:`InputError` when a port is already taken by
    another program or when the server does not come up (its own message included):
    the page URL is only returned once our own, running process serves it. (The SDK's
    own ``serve_grpc`` binds every interface; the ``rerun`` command takes ``--bind``.)
    """
    for port in (grpc_port, web_port):
        if not port_is_free(port):
            raise InputError(f"port {port} on {HOST} is already in use by another program; "
                             "the Rerun web viewer was not started")
    with tempfile.TemporaryFile() as log:  # the server's output, for a failed start
        process = subprocess.Popen([rerun_executable(), "--serve-web", "--bind", HOST,
                                    "--port", str(grpc_port), "--web-viewer-port",
                                    str(web_port), *map(str, files)],
                                   stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + START_TIMEOUT_S
        while process.poll() is None and time.monotonic() < deadline:
            if _serves_viewer(web_port):
                break
            time.sleep(0.2)
        if process.poll() is not None or not _serves_viewer(web_port):
            process.kill()
            process.wait()
            log.seek(0)
            lines = [x for x in log.read().decode(errors="replace").splitlines() if x.strip()]
            reason = lines[-1].strip() if lines else f"no answer in {START_TIMEOUT_S:.0f} s"
            raise InputError(f"the Rerun web viewer did not start on {HOST}:{web_port}: "
                             f"{reason}")
    return process, f"rerun+http://{HOST}:{grpc_port}/proxy", viewer_page_url(grpc_port,
                                                                               web_port)
