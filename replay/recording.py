"""Logging a replay to Rerun, following the layout in :mod:`contactkit.viewer.layout`.

Series go out with ``send_columns``, block by block as the engine streams the
session: a batch at a time in a ``--rate max`` replay, every hop during a paced
replay, where the viewer updates live. Both send the same values at the same time
stamps. Every time series is logged at the full sample rate unless a log rate thins
it (:class:`Thinning`: the chain still runs on every sample); the 3-D robot and its
force arrow are animated at about 60 Hz (every n-th sample), which is all a 3-D view
needs and keeps files small. The kinematics only the view needs (the end effector's
position, the simulated contact's point) are computed here, at those samples. The
simulator's applied force, zero outside its contacts, is a sparse column
(:class:`ZeroRuns`: the same plot from a fraction of the rows). The isolated
contacts' estimates go out with the blocks too (:mod:`contactkit.replay.contacts`).
:func:`log_contact_events` is where the contact-event pipeline hands over its events
(one state-timeline bar each) and detector thresholds (lines on the residual plot).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from contactkit.classify.events.contact_events import ContactEvent
from contactkit.errors import InputError
from contactkit.replay.contacts import ContactTrackLogger, log_contact_links
from contactkit.replay.engine import Block, OfflineAnswer, ReplayStream
from contactkit.robots.model import RobotModel
from contactkit.robots.surfaces import viewer_urdf_file
from contactkit.util.atomic import Owned
from contactkit.util.owned import owned_by_marker
from contactkit.util.paths import inside
from contactkit.viewer import layout

ROBOT_VIEW_HZ = 60.0
"""The 3-D robot is drawn at about this rate [Hz] (every n-th sample)."""


def new_recording(session_name: str, recording_id: str) -> rr.RecordingStream:
    """Return a recording stream for one session (application ``contactkit-replay``)."""
    rec = rr.RecordingStream("contactkit-replay", recording_id=recording_id)
    rec.send_recording_name(session_name)
    return rec


def log_session_properties(rec: rr.RecordingStream, stream: ReplayStream,
                           file: str | None = None) -> None:
    """Store the session metadata as the recording's ``session`` properties, the session
    file named ``file`` (default: its path as given)."""
    meta = vars(stream.meta).copy()
    values: dict[str, Any] = {k: (json.dumps(v) if isinstance(v, (dict, list)) else v)
                              for k, v in meta.items() if v is not None}
    values["file"] = file if file is not None else str(stream.path or "")
    values["model_kind"] = stream.model.meta.get("kind", "")
    rec.send_property("session", rr.AnyValues(**values))


def log_static(rec: rr.RecordingStream, stream: ReplayStream,
               file: str | None = None) -> rr.urdf.UrdfTree:
    """Log series styles, the robot model, the session properties (the session file
    named ``file``, default its path) and the ground-truth action (at ``t0``, the first
    sample's time [s])."""
    meta = stream.meta
    layout.log_series_styles(rec, stream.classes)
    tree = layout.log_robot_model(rec, viewer_urdf_file(meta.robot_setup()))
    layout.log_force_arrow_style(rec)
    layout.log_contact_styles(rec)
    log_session_properties(rec, stream, file)
    t0, _ = stream.time_span()
    layout.text_event(rec, layout.TRUE_ACTION, t0, 0, f"recorded action: {meta.action}"
                      + (f" on link {meta.link}" if meta.link else ""))
    return tree


def log_planned(rec: rr.RecordingStream, stream: ReplayStream) -> None:
    """Log the planned interaction time (after the stream has found its sample)."""
    planned = stream.meta.planned_at_s
    if planned is not None:
        sample = stream.planned_sample if stream.planned_sample is not None else \
            max(stream.n_samples - 1, 0)
        layout.text_event(rec, layout.PLANNED, planned, sample,
                          f"planned interaction at {planned:.2f} s")


class Thinning:
    """Which samples go to Rerun at ``rate_hz`` [Hz] (None: all of them): the first
    sample of every period of 1 / rate_hz seconds, counted from the first sample, carried
    across blocks."""

    def __init__(self, rate_hz: float | None) -> None:
        self.rate_hz = rate_hz
        self._origin: float | None = None
        self._last = -1

    def keep(self, t: np.ndarray) -> np.ndarray:
        """Return the indices of the samples at times ``t`` [s] to log."""
        if self.rate_hz is None or len(t) == 0:
            return np.arange(len(t))
        if self._origin is None:
            self._origin = float(t[0])
        period = np.floor((t - self._origin) * self.rate_hz + 1e-6).astype(np.int64)
        keep = np.flatnonzero(np.diff(period, prepend=self._last) != 0)
        self._last = int(period[-1])
        return keep


class ZeroRuns:
    """Sends a series that is zero most of the time (the simulator's applied force) as a
    sparse column: its non-zero rows, the zero rows next to them and the first and last
    row. The viewer draws straight lines between logged points, so the plot is the one
    of every row, at a fraction of the file size. Carried across blocks: the same rows go
    out however the series is split."""

    def __init__(self, path: str) -> None:
        self.path = path
        self._before = True  # the row before the next block is non-zero (or there is none)
        self._pending: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        """The previous block's last row (t [s], sample, values), when it is zero and
        not logged yet: it goes out when the next row is non-zero or the series ends."""

    def log(self, rec: rr.RecordingStream, t: np.ndarray, sample: np.ndarray,
            values: np.ndarray) -> None:
        """Send the rows of one block that the sparse column keeps: times ``t`` [s],
        sample indices ``sample`` and ``values`` (N, k)."""
        if not len(t):
            return
        nonzero = np.any(values != 0, axis=1)
        keep = nonzero | np.concatenate([[self._before], nonzero[:-1]]) | \
            np.concatenate([nonzero[1:], [False]])
        rows = (t[keep], sample[keep], values[keep])
        if self._pending is not None and nonzero[0]:
            rows = tuple(np.concatenate([p, r]) for p, r in zip(self._pending, rows,
                                                                 strict=True))
        self._pending = None if keep[-1] else (t[-1:], sample[-1:], values[-1:])
        self._before = bool(nonzero[-1])
        if len(rows[0]):
            layout.log_scalar_columns(rec, self.path, *rows)

    def finish(self, rec: rr.RecordingStream) -> None:
        """Send the series' last row if it is still pending."""
        if self._pending is not None:
            layout.log_scalar_columns(rec, self.path, *self._pending)
            self._pending = None


class BlockLogger:
    """Sends the blocks of ``stream`` as columns, every series thinned to ``log_rate_hz``
    [Hz] (None: every sample) and the 3-D robot (every n-th sample, about
    ``ROBOT_VIEW_HZ`` at the session's rate) to at most that rate; the predictions
    always go out in full, and so does the track of isolated contacts
    (:class:`~contactkit.replay.contacts.ContactTrackLogger`). The 3-D view's
    kinematics come from the session's robot model: the end effector's position for
    the force arrow and, in a simulated session, the true contact point [m] (base
    frame)."""

    def __init__(self, rec: rr.RecordingStream, tree: rr.urdf.UrdfTree,
                 stream: ReplayStream, log_rate_hz: float | None = None) -> None:
        self.rec, self.tree, self.stream = rec, tree, stream
        self.series = Thinning(log_rate_hz)
        self.robot = Thinning(None if log_rate_hz is None or log_rate_hz >= ROBOT_VIEW_HZ
                              else log_rate_hz)
        self._contact: bool | None = None
        self.contact_span: tuple[float, float] | None = None
        """The first and last time [s] of the recorded contact so far (None: none)."""
        self.truth = ZeroRuns(layout.TRUE_FORCE)
        self.contacts = ContactTrackLogger(rec, stream)
        self._stride: int | None = None
        self.model = RobotModel(stream.meta.robot_setup(stream.path))
        truth = ((stream.meta.simulator or {}).get("session") or {}).get("contact")
        self.true_contact = (int(truth["link"]), np.asarray(truth["point_local"], float)) \
            if isinstance(truth, dict) else None
        """The simulated contact's link and point [m] (link frame), None without one."""

    def _robot_rows(self, block: Block) -> np.ndarray:
        """Return the rows of ``block`` where the 3-D robot is drawn."""
        if self._stride is None:
            rate = self.stream.rate_hz
            self._stride = 1 if rate is None else max(1, round(rate / ROBOT_VIEW_HZ))
        robot = np.flatnonzero(block.sample % self._stride == 0)
        return robot[self.robot.keep(block.t[robot])]

    def _points(self, q: np.ndarray, link: int | str, point: np.ndarray) -> np.ndarray:
        """Return ``point`` [m] (in the frame of ``link``) in the base frame at each
        configuration ``q`` (m, 7) [rad], (m, 3)."""
        rotation, translation = self.model.frame_placements(q, link)
        return rotation @ point + translation

    def finish(self) -> None:
        """Send what the last block left pending (call once, after the last block)."""
        self.truth.finish(self.rec)
        self.contacts.finish()

    def log(self, block: Block) -> None:
        """Send the (thinned) samples, the predictions and the contact estimates of one
        block."""
        rec = self.rec
        kept = self.series.keep(block.t)
        if len(kept):
            # every row: the block's arrays themselves, no copies
            keep: np.ndarray | slice = slice(None) if len(kept) == len(block.t) else kept
            t, sample = block.t[keep], block.sample[keep]
            layout.log_joint_columns(rec, t, sample, block.q[keep], block.dq[keep],
                                     block.tau[keep])
            layout.log_scalar_columns(rec, layout.RESIDUAL, t, sample, block.r[keep])
            if block.robot_estimate is not None:
                layout.log_scalar_columns(rec, layout.ROBOT_ESTIMATE, t, sample,
                                          block.robot_estimate[keep])
            layout.log_scalar_columns(rec, layout.FORCE, t, sample, block.force[keep])
            layout.log_scalar_columns(rec, layout.MOMENT, t, sample, block.moment[keep])
            layout.log_scalar_columns(rec, layout.FORCE_NORM, t, sample, block.norms[keep, :1])
            layout.log_scalar_columns(rec, layout.MOMENT_NORM, t, sample,
                                      block.norms[keep, 1:])
            contact = None if block.contact is None else block.contact[keep]
            if block.true_force is not None:
                force = block.true_force[keep]
                if contact is None:
                    contact = np.linalg.norm(force, axis=1) > 0
                self.truth.log(rec, t, sample, force)
            if contact is not None:  # a labelled contact column, simulated or imported
                layout.log_contact_lane(rec, t, sample, contact, self._contact)
                self._contact = bool(contact[-1])
                touched = t[contact]
                if len(touched):
                    first = touched[0] if self.contact_span is None else self.contact_span[0]
                    self.contact_span = (float(first), float(touched[-1]))
        rows = self._robot_rows(block)
        if len(rows):
            t, sample, q = block.t[rows], block.sample[rows], block.q[rows]
            layout.log_joint_transforms(rec, self.tree, t, sample, q)
            ee = self._points(q, self.model.end_effector, np.zeros(3))
            layout.log_force_arrows(rec, t, sample, ee, block.force[rows])
            if self.true_contact is not None and block.true_force is not None:
                applied = block.true_force[rows]
                layout.log_contact_columns(rec, t, sample, self._points(q, *self.true_contact),
                                           applied, np.linalg.norm(applied, axis=1) > 0,
                                           truth=True)
        if len(block.pred_t):
            pt, ps = block.pred_t, block.pred_sample
            layout.log_scalar_columns(rec, layout.PROBABILITY, pt, ps, block.pred_proba)
            rec.send_columns(layout.PREDICTED, indexes=layout.time_columns(pt, ps),
                             columns=rr.StateChange.columns(state=block.pred_label))
        self.contacts.log(block)


def log_offline(rec: rr.RecordingStream, stream: ReplayStream, answer: OfflineAnswer) -> None:
    """Log the offline window (a state lane and an event) and the offline label."""
    window = answer.window
    k0, k1 = answer.start_sample, answer.end_sample
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


def log_contact_events(rec: rr.RecordingStream, t: np.ndarray,
                       events: Sequence[ContactEvent],
                       thresholds: Mapping[str, float] | None = None,
                       samples: np.ndarray | None = None) -> None:
    """Log each contact event as one bar (onset to release) labelled with its decision in
    the state timeline, a text event at its decision time, and each detector threshold
    [Nm] as a constant line over the session on the residual plot. ``t`` [s] are sample
    times from the first to the last, at least those of the events' onsets, decisions
    and releases; ``samples`` their sample indices (default: 0, 1, ...)."""
    t = np.asarray(t, dtype=float)
    index = np.arange(len(t)) if samples is None else np.asarray(samples, dtype=np.int64)

    def sample_at(times: np.ndarray) -> np.ndarray:
        return index[np.minimum(np.searchsorted(t, times), len(t) - 1)]

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
        layout.log_scalar_columns(rec, layout.THRESHOLD, ends, index[[0, -1]],
                                  np.tile([thresholds[n] for n in names], (2, 1)))


def log_results(rec: rr.RecordingStream, stream: ReplayStream,
                answer: OfflineAnswer | None) -> None:
    """Log what a replay knows once its blocks have streamed: the planned time, the
    contact events with the detector's thresholds and the isolated contacts (with an
    event pipeline), and the offline ``answer`` (None: the session has no planned time).
    The isolated contacts' track went out with the blocks (:class:`BlockLogger`); here
    each event's link is highlighted (:func:`log_contact_links`)."""
    log_planned(rec, stream)
    if stream.pipeline is not None:
        times = sorted(stream.event_samples)
        assert stream.detector is not None  # the pipeline's
        log_contact_events(rec, np.array(times), stream.events, {
            f"joint {j} at rest": v for j, v in enumerate(stream.detector.noise, 1)},
            samples=np.array([stream.event_samples[t] for t in times]))
        log_contact_links(rec, stream)
    if answer is not None:
        log_offline(rec, stream, answer)


RRD_MAGIC = b"RRF"
"""How every .rrd file starts (``RRF2`` and a version): the test for a recording."""
owned_recording: Owned = owned_by_marker(RRD_MAGIC, within=len(RRD_MAGIC))
"""The default ``replay.rrd`` is replaced only when it is a recording (see
:mod:`contactkit.util.atomic`)."""


def save_path_for(save: Path, session_path: Path, many: bool) -> Path:
    """Return the .rrd path of one session: ``save`` itself, or with several sessions
    ``<save stem>_<session stem>.rrd``."""
    if not many:
        return save
    return inside(save.parent, f"{save.stem}_{session_path.stem}.rrd")


def save_paths_for(save: Path, session_paths: Sequence[Path]) -> list[Path]:
    """Return the .rrd path of each session (:func:`save_path_for`); raise InputError
    when two sessions would be saved under one name (equal file names in different
    directories), so that no session's recording silently replaces another's."""
    many = len(session_paths) > 1
    targets: list[Path] = []
    first: dict[Path, Path] = {}
    for session_path in session_paths:
        target = save_path_for(save, Path(session_path), many)
        if target in first:
            raise InputError(f"sessions {first[target]} and {session_path} would both be "
                             f"saved as {target.name}; replay them separately", target)
        first[target] = session_path
        targets.append(target)
    return targets
