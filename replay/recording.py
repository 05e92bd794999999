"""Logging a replay to Rerun, following the layout in :mod:`contactkit.schemas.rerun_layout`.

Whole series go out with ``send_columns``: at once after a ``--rate max`` replay,
or block by block (every hop) during a paced replay, where the viewer updates live.
Both send the same values at the same time stamps. Every time series is logged at
the full sample rate; the 3-D robot and its force arrow are animated at about
60 Hz (every n-th sample), which is all a 3-D view needs and keeps files small.
:func:`log_contact_events` is where the contact-event pipeline hands over its events
(one state-timeline bar each) and detector thresholds (lines on the residual plot).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr

from contactkit.features.dynamics import viewer_urdf_file
from contactkit.replay.engine import Block, OfflineAnswer, ReplayStream
from contactkit.schemas import rerun_layout as layout
from contactkit.util.paths import inside


def new_recording(session_name: str, recording_id: str) -> rr.RecordingStream:
    """Return a recording stream for one session (application ``contactkit-replay``)."""
    rec = rr.RecordingStream("contactkit-replay", recording_id=recording_id)
    rec.send_recording_name(session_name)
    return rec


def log_session_properties(rec: rr.RecordingStream, stream: ReplayStream) -> None:
    """Store the session metadata as the recording's ``session`` properties."""
    meta = vars(stream.session.meta).copy()
    values = {k: (json.dumps(v) if isinstance(v, (dict, list)) else v) for k, v in meta.items()
              if v is not None}
    values["file"] = str(stream.session.path or "")
    values["model_kind"] = stream.model.meta.get("kind", "")
    rec.send_property("session", rr.AnyValues(**values))


def log_static(rec: rr.RecordingStream, stream: ReplayStream) -> rr.urdf.UrdfTree:
    """Log series styles, the robot model, the planned time and the ground-truth action."""
    session = stream.session
    layout.log_series_styles(rec, stream.classes)
    tree = layout.log_robot_model(rec, viewer_urdf_file(session.meta.with_hand))
    layout.log_force_arrow_style(rec)
    log_session_properties(rec, stream)
    planned = session.meta.planned_at_s
    if planned is not None:
        k = int(np.searchsorted(session.t, planned))
        layout.text_event(rec, layout.PLANNED, planned, k, f"planned interaction at "
                          f"{planned:.2f} s")
    layout.text_event(rec, layout.TRUE_ACTION, float(session.t[0]), 0,
                      f"recorded action: {session.meta.action}"
                      + (f" on link {session.meta.link}" if session.meta.link else ""))
    if session.has("f_ext_x"):
        force = np.column_stack([session.column(c) for c in ("f_ext_x", "f_ext_y", "f_ext_z")])
        contact = session.column("contact") if session.has("contact") else \
            np.linalg.norm(force, axis=1) > 0
        layout.log_ground_truth(rec, session.t, np.arange(session.n_samples), force, contact)
    return tree


def log_block(rec: rr.RecordingStream, tree: rr.urdf.UrdfTree, stream: ReplayStream,
              block: Block) -> None:
    """Send the samples and predictions of one block as columns."""
    s = slice(block.start, block.stop)
    session = stream.session
    t = session.t[s]
    sample = np.arange(block.start, block.stop)
    if len(t):
        layout.log_joint_columns(rec, t, sample, session.q[s], session.dq[s], session.tau[s])
        layout.log_scalar_columns(rec, layout.RESIDUAL, t, sample, stream.r[s])
        layout.log_scalar_columns(rec, layout.FORCE, t, sample, stream.force[s])
        layout.log_scalar_columns(rec, layout.MOMENT, t, sample, stream.moment[s])
        layout.log_scalar_columns(rec, layout.FORCE_NORM, t, sample, stream.norms[s][:, :1])
        layout.log_scalar_columns(rec, layout.MOMENT_NORM, t, sample, stream.norms[s][:, 1:])
        keep = sample % stream.robot_stride == 0
        if keep.any():
            layout.log_joint_transforms(rec, tree, t[keep], sample[keep], session.q[s][keep])
            layout.log_force_arrows(rec, t[keep], sample[keep], stream.ee_position[s][keep],
                                    stream.force[s][keep])
    p = block.predictions
    if len(p):
        pt = np.array(stream.pred_t[p.start:p.stop])
        ps = np.array(stream.pred_sample[p.start:p.stop])
        layout.log_scalar_columns(rec, layout.PROBABILITY, pt, ps,
                                  np.array(stream.pred_proba[p.start:p.stop]))
        rec.send_columns(layout.PREDICTED, indexes=layout.time_columns(pt, ps),
                         columns=rr.StateChange.columns(state=stream.pred_label[p.start:p.stop]))


def log_offline(rec: rr.RecordingStream, stream: ReplayStream, answer: OfflineAnswer) -> None:
    """Log the offline window (a state lane and an event) and the offline label."""
    window = answer.window
    t = stream.session.t
    k0 = int(np.searchsorted(t, window.start_s))
    k1 = min(int(np.searchsorted(t, window.end_s)), len(t) - 1)
    how = "detected onset" if window.found else "planned time (nothing detected)"
    layout.log_state_spans(rec, layout.WINDOW, np.array([window.start_s]),
                           np.array([window.end_s]), ["window"], np.array([k0]), np.array([k1]))
    layout.text_event(rec, layout.WINDOW, window.start_s, k0,
                      f"{window.method} window {window.start_s:.3f}-{window.end_s:.3f} s "
                      f"from the {how}")
    probs = ", ".join(f"{c} {p:.2f}" for c, p in zip(stream.classes, answer.probabilities,
                                                     strict=True))
    layout.text_event(rec, layout.OFFLINE_LABEL, window.end_s, k1,
                      f"offline label: {answer.label} ({probs})")


@dataclass(frozen=True)
class ContactEvent:
    """One contact as the event pipeline decides it: onset, decision and release time
    [s] and the decided label."""

    onset_s: float
    decision_s: float
    release_s: float
    label: str


def log_contact_events(rec: rr.RecordingStream, t: np.ndarray,
                       events: Sequence[ContactEvent],
                       thresholds: Mapping[str, float] | None = None) -> None:
    """Log each contact event as one bar (onset to release) labelled with its decision in
    the state timeline, a text event at its decision time, and each detector threshold
    [Nm] as a constant line over the session (times ``t`` [s]) on the residual plot."""
    t = np.asarray(t, dtype=float)

    def sample_at(times: np.ndarray) -> np.ndarray:
        return np.minimum(np.searchsorted(t, times), len(t) - 1)

    if events:
        onset = np.array([e.onset_s for e in events])
        # a contact still open at the end of the session lasts to its last sample
        release = np.array([t[-1] if e.release_s is None else e.release_s for e in events])
        layout.log_state_spans(rec, layout.CONTACT_EVENTS, onset, release,
                               [e.label for e in events], sample_at(onset), sample_at(release))
        for event, end in zip(events, release, strict=True):
            if event.decision_s is None:
                continue
            layout.text_event(rec, layout.CONTACT_EVENTS, event.decision_s,
                              int(sample_at(np.array([event.decision_s]))[0]),
                              f"contact {event.onset_s:.2f}-{end:.2f} s: "
                              f"{event.label} (decided at {event.decision_s:.2f} s)")
    if thresholds:
        names = list(thresholds)
        rec.log(layout.THRESHOLD, rr.SeriesLines(names=names, colors=[layout.THRESHOLD_COLOR]
                                                 * len(names)), static=True)
        ends = np.array([t[0], t[-1]])
        layout.log_scalar_columns(rec, layout.THRESHOLD, ends, np.array([0, len(t) - 1]),
                                  np.tile([thresholds[n] for n in names], (2, 1)))


def save_path_for(save: Path, session_path: Path, many: bool) -> Path:
    """Return the .rrd path of one session: ``save`` itself, or with several sessions
    ``<save stem>_<session stem>.rrd``."""
    if not many:
        return save
    return inside(save.parent, f"{save.stem}_{session_path.stem}.rrd")
