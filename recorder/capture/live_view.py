"""Showing a capture live in Rerun, with replay's entity paths and blueprint pieces.

Each chunk of samples is sent as columns as it is recorded: joint q, dq and tau,
the applied force (simulated sources), the robot animated at about 60 Hz, and the
operator cue (countdown and the planned time) as text events.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import rerun as rr

from contactkit.errors import InputError
from contactkit.robots.surfaces import viewer_urdf_file
from contactkit.schemas import SessionMeta
from contactkit.schemas.session import SampleBatch
from contactkit.util.atomic import atomic_write
from contactkit.util.rrd_file import check_space, finish_recording, start_recording
from contactkit.viewer import layout
from contactkit.viewer.layout import capture_blueprint
from contactkit.viewer.web import has_display, start_web_viewer

ROBOT_VIEW_HZ = 60.0
PANDA_RATE_HZ = 1000.0


class CaptureViewer:
    """Logs a capture to a recording stream; use :meth:`on_chunk` as a capture callback."""

    def __init__(self, rec: rr.RecordingStream, meta: SessionMeta,
                 rate_hz: float | None) -> None:
        self.rec = rec
        self.files = ExitStack()
        self.saved: tuple[Path, Path] | None = None  # (temporary, target) of --save-rrd
        self.sample = 0
        self.stride = max(1, round((rate_hz or PANDA_RATE_HZ) / ROBOT_VIEW_HZ))
        layout.log_series_styles(rec)
        self.tree = layout.log_robot_model(rec, viewer_urdf_file(meta.robot_setup()))
        rec.send_property("session", rr.AnyValues(session_id=meta.session_id, pose=meta.pose,
                                                  action=meta.action, source=meta.source,
                                                  operator=meta.operator))
        if meta.planned_at_s is not None:
            layout.text_event(rec, layout.CUE, meta.planned_at_s, 0,
                              f"planned interaction: {meta.action}"
                              + (f" on link {meta.link}" if meta.link else ""))

    def cue(self, t: float, text: str) -> None:
        """Log an operator-cue message at session time ``t`` [s]."""
        layout.text_event(self.rec, layout.CUE, t, self.sample, text, level="WARN")

    def on_chunk(self, chunk: dict[str, np.ndarray]) -> None:
        """Send one chunk of recorded rows."""
        if self.saved is not None:
            check_space(self.saved[1])
        t = chunk["t"]
        sample = self.sample + np.arange(len(t))
        self.sample += len(t)
        batch = SampleBatch.from_columns(chunk)
        layout.log_joint_columns(self.rec, t, sample, batch.q, batch.dq, batch.tau)
        if batch.f_ext is not None:
            layout.log_scalar_columns(self.rec, layout.TRUE_FORCE, t, sample, batch.f_ext)
        keep = sample % self.stride == 0
        if keep.any():
            layout.log_joint_transforms(self.rec, self.tree, t[keep], sample[keep],
                                        batch.q[keep])

    def close(self) -> None:
        """Flush the recording, disconnect from the viewer and move a saved .rrd into
        place, only when it was written whole (:func:`finish_recording`); a failed one is
        dropped and its one-line error raised."""
        try:
            if self.saved is not None:
                finish_recording(self.rec, *self.saved)
            else:
                self.rec.flush()
        except BaseException as err:
            self.rec.disconnect()
            self.files.__exit__(type(err), err, err.__traceback__)
            raise
        self.rec.disconnect()
        self.files.close()

    def abort(self) -> None:
        """Disconnect and drop a saved .rrd (the capture failed); nothing is left."""
        self.rec.disconnect()
        self.files.__exit__(InputError, InputError("capture failed"), None)


def open_live_view(viewer: str, save_rrd: Path | None, meta: SessionMeta,
                   rate_hz: float | None, say: Callable[[str], None],
                   overwrite: bool = False) -> CaptureViewer | None:
    """Return a live Rerun view of a capture at ``rate_hz`` [Hz] (None: the Panda's 1 kHz)
    in ``viewer`` (rerun, web or none) and/or saved to ``save_rrd``; None when neither
    is asked for. ``say`` receives notes for the person (the web viewer's address).

    The .rrd goes to a temporary file that :meth:`CaptureViewer.close` renames into
    place (:meth:`CaptureViewer.abort` drops it); an existing ``save_rrd`` is replaced
    only with ``overwrite``."""
    if viewer == "none" and save_rrd is None:
        return None
    rec = rr.RecordingStream("contactkit-capture", recording_id=meta.session_id)
    blueprint = capture_blueprint()
    files = ExitStack()
    if save_rrd is not None:
        tmp = files.enter_context(atomic_write(save_rrd, overwrite=overwrite, suffix=".rrd"))
        start_recording(rec, tmp.path, save_rrd, blueprint)
    try:
        if viewer == "rerun":
            if has_display():
                rec.spawn(default_blueprint=blueprint)
            else:
                say("no display for the native viewer: use the web viewer or save an .rrd "
                    "file")
        elif viewer == "web":
            _, url, page = start_web_viewer()
            say(f"web viewer: {page}")
            rec.connect_grpc(url, default_blueprint=blueprint)
        live = CaptureViewer(rec, meta, rate_hz)
        if save_rrd is not None:
            live.saved = (tmp.path, Path(save_rrd))
    except BaseException as err:
        rec.disconnect()
        files.__exit__(type(err), err, err.__traceback__)
        raise
    live.files = files
    return live
