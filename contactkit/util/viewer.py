"""Starting Rerun viewers for capture and replay."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import quote

WEB_PORT = 9090
GRPC_PORT = 9876


def has_display() -> bool:
    """Return whether a native viewer window can open (on Linux: a display is set)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def start_web_viewer(grpc_port: int = GRPC_PORT, web_port: int = WEB_PORT
                     ) -> tuple[subprocess.Popen, str, str]:
    """Start Rerun's web viewer and gRPC server bound to 127.0.0.1.

    Returns the server process, the gRPC URL to send recordings to, and the page URL
    to open in a browser. (The SDK's own ``serve_grpc`` binds every interface; the
    ``rerun`` command that ships with the SDK takes ``--bind``.)
    """
    rerun_cli = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    process = subprocess.Popen([rerun_cli, "--serve-web", "--bind", "127.0.0.1", "--port",
                                str(grpc_port), "--web-viewer-port", str(web_port)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)
    grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    page = f"http://127.0.0.1:{web_port}/?url={quote(grpc_url, safe='')}"
    return process, grpc_url, page
