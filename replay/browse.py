"""Serving a catalog with Rerun's catalog server and opening a viewer on it.

:func:`start_catalog_server` starts ``rr.server.Server`` (rerun-sdk's ``catalog``
extra) on a catalog folder, as one dataset with one segment per session recording,
bound to 127.0.0.1 unless told otherwise (Rerun's own default is every interface).
:func:`open_viewer` opens the native viewer on it where there is a display, else serves
the web viewer on 127.0.0.1 and returns its page's URL. :func:`segment_url` is the URL
that opens one session at a time [s].
"""

from __future__ import annotations

import subprocess
import tempfile
import time
from datetime import timedelta
from pathlib import Path
from urllib.parse import quote

from contactkit.errors import InputError
from contactkit.replay.catalog import catalog_tables
from contactkit.viewer.web import (
    START_TIMEOUT_S,
    free_port,
    has_display,
    port_is_free,
    rerun_executable,
)

DEFAULT_HOST = "127.0.0.1"
DATASET = "contactkit"
"""The name the server gives the catalog's dataset."""


def start_catalog_server(out: Path, host: str = DEFAULT_HOST, port: int = 0):
    """Start Rerun's catalog server on the catalog in ``out`` (its ``.rrd`` files as the
    dataset :data:`DATASET`) on ``host:port`` (port 0: a free one); return the
    ``rr.server.Server`` (stop it with ``shutdown()``). Raises InputError (one line)
    when ``out`` is not a catalog or the port is taken."""
    import rerun as rr

    catalog_tables(out)
    if port and not port_is_free(port, host):
        raise InputError(f"port {port} on {host} is already in use; choose another --port")
    try:
        return rr.server.Server(host=host, port=port or None,
                                datasets={DATASET: Path(out).resolve()})
    except ValueError as err:  # the server's own bind failure
        raise InputError(f"the catalog server did not start on {host}:{port}: "
                         f"{' '.join(str(err).split())}") from err


def dataset_url(server) -> str:
    """Return the URL that opens the catalog's dataset table on the server."""
    return f"{server.url()}/dataset/{server.client().get_dataset(DATASET).id}"


def segment_url(server, session_id: str, at_s: float | None = None) -> str:
    """Return the URL that opens session ``session_id`` of the server's dataset, at time
    ``at_s`` [s] of its ``time`` timeline where given; raise InputError for a session the
    dataset does not hold."""
    dataset = server.client().get_dataset(DATASET)
    if session_id not in dataset.segment_ids():
        raise InputError(f"session {session_id} is not in the catalog (recorder query lists "
                         "its sessions)")
    if at_s is None:
        return dataset.segment_url(session_id)
    return dataset.segment_url(session_id, "time", timedelta(seconds=at_s))


def web_page_url(web_port: int, target: str, renderer: str | None = None) -> str:
    """Return the web viewer's page on 127.0.0.1:``web_port`` that opens ``target`` (a
    catalog or segment URL); ``renderer="webgl"`` for browsers without a GPU."""
    page = f"http://{DEFAULT_HOST}:{web_port}/?url={quote(target, safe='')}"
    return page + (f"&renderer={renderer}" if renderer else "")


def open_viewer(target: str, *, web: bool | None = None, web_port: int | None = None
                ) -> tuple[subprocess.Popen, str | None]:
    """Open a viewer on ``target`` (a catalog or segment URL): the native one
    (``web=False``, or None with a display), else Rerun's web viewer served on
    127.0.0.1:``web_port`` (default: a free port). Return the viewer's process and the
    web page's URL (None for the native viewer). Raises InputError when the web
    viewer's port is taken or it does not start."""
    if web is None:
        web = not has_display()
    if not web:
        return subprocess.Popen([rerun_executable(), target]), None
    port = web_port or free_port(DEFAULT_HOST)
    if not port_is_free(port, DEFAULT_HOST):
        raise InputError(f"port {port} on {DEFAULT_HOST} is already in use; the web viewer "
                         "was not started")
    import urllib.request

    with tempfile.TemporaryFile() as log:
        process = subprocess.Popen([rerun_executable(), "--serve-web", "--bind", DEFAULT_HOST,
                                    "--web-viewer-port", str(port), target],
                                   stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + START_TIMEOUT_S
        while process.poll() is None and time.monotonic() < deadline:
            try:
                with urllib.request.urlopen(f"http://{DEFAULT_HOST}:{port}/", timeout=2):
                    return process, web_page_url(port, target)
            except OSError:
                time.sleep(0.2)
        process.kill()
        process.wait()
        log.seek(0)
        lines = [x for x in log.read().decode(errors="replace").splitlines() if x.strip()]
        reason = lines[-1].strip() if lines else f"no answer in {START_TIMEOUT_S:.0f} s"
    raise InputError(f"the Rerun web viewer did not start on {DEFAULT_HOST}:{port}: {reason}")

