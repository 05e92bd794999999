"""Showing a capture live in Rerun, with replay's entity paths and blueprint pieces.

Each chunk of samples is sent as columns as it is recorded: joint q, dq and tau,
the applied force (simulated sources), the robot animated at about 60 Hz, and the
operator cue (countdown and the planned time) as text events.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from contactkit.features.dynamics import viewer_urdf_file
from contactkit.schemas import SessionMeta, joint_columns
from contactkit.schemas import rerun_layout as layout

ROBOT_VIEW_HZ = 60.0


class CaptureViewer:
    """Logs a capture to a recording stream; use :meth:`on_chunk` as a capture callback."""

    def __init__(self, rec: rr.RecordingStream, meta: SessionMeta, rate_hz: float) -> None:
        self.rec = rec
        self.sample = 0
        self.stride = max(1, round(rate_hz / ROBOT_VIEW_HZ))
        layout.log_series_styles(rec)
        self.tree = layout.log_robot_model(rec, viewer_urdf_file(meta.with_hand))
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
        t = chunk["t"]
        sample = self.sample + np.arange(len(t))
        self.sample += len(t)
        q = np.column_stack([chunk[c] for c in joint_columns("q")])
        dq = np.column_stack([chunk[c] for c in joint_columns("dq")])
        tau = np.column_stack([chunk[c] for c in joint_columns("tau")])
        layout.log_joint_columns(self.rec, t, sample, q, dq, tau)
        if "f_ext_x" in chunk:
            force = np.column_stack([chunk[c] for c in ("f_ext_x", "f_ext_y", "f_ext_z")])
            layout.log_scalar_columns(self.rec, layout.TRUE_FORCE, t, sample, force)
        keep = sample % self.stride == 0
        if keep.any():
            layout.log_joint_transforms(self.rec, self.tree, t[keep], sample[keep], q[keep])
