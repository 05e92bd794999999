"""Logging a replay's isolated contacts: the track of points and force arrows, block by
block as the engine streams the session, and each event's link highlight at the end.

The engine's events keep no track of estimates (see :mod:`contactkit.replay.engine`):
each block carries the estimates made among its samples, and
:class:`ContactTrackLogger` sends them with the block, so memory stays bounded by a
batch however long the session is in contact. An event's track is cleared at its
release (when its last estimate came before it), and an event still open at the end
at the session's last sample. The highlight of each event's link needs only its
onset, its end and its estimate at the peak: :func:`log_contact_links` logs it once
the blocks have streamed (events are few).
"""

from __future__ import annotations

from typing import cast

import numpy as np
import rerun as rr

from contactkit.replay.engine import Block, ReplayStream
from contactkit.viewer import layout


class ContactTrackLogger:
    """Sends the contact estimates of the events' tracks of ``stream`` to ``rec`` as
    the blocks come: a point [m] and a force arrow [N] (base frame) at each estimate
    with a point, none at one without (cleared), and none from each release whose
    event's last estimate came before it. Keeps only the time of the last estimate
    sent, how many released events it has handled and the last block's last sample."""

    def __init__(self, rec: rr.RecordingStream, stream: ReplayStream) -> None:
        self.rec, self.stream = rec, stream
        pipeline = stream.pipeline
        self.active = pipeline is not None and pipeline.isolator is not None
        """Whether there is anything to log: an event pipeline with contact isolation."""
        self._last_s: float | None = None
        """Time [s] of the last estimate sent (None before the first)."""
        self._released = 0
        """The number of released events whose release has been handled."""
        self._end: tuple[float, int] | None = None
        """Time [s] and sample of the last block's last sample."""

    def log(self, block: Block) -> None:
        """Send the estimates of one block (in session order after the previous
        block's) and a clearing row at each release up to its last sample."""
        if not self.active or not len(block.t):
            return
        self._end = float(block.t[-1]), block.stop - 1
        times = [e.t_s for _, e in block.estimates]
        samples = [k for k, _ in block.estimates]
        points = [np.zeros(3) if e.point_base is None else e.point_base
                  for _, e in block.estimates]
        # an estimate with a point has its force
        forces = [np.zeros(3) if e.point_base is None else cast(np.ndarray, e.force)
                  for _, e in block.estimates]
        present = [e.point_base is not None for _, e in block.estimates]
        estimated = np.array(times)
        assert self.stream.pipeline is not None  # active: the stream has events
        released = self.stream.pipeline.events
        while self._released < len(released) and \
                released[self._released].release_s <= block.t[-1]:
            end = released[self._released].release_s
            assert end is not None  # a released event
            self._released += 1
            before = int(np.searchsorted(estimated, end, side="right"))
            last = float(estimated[before - 1]) if before else self._last_s
            if last is not None and last < end:
                times.append(end)
                samples.append(self.stream.event_samples[end])
                points.append(np.zeros(3))
                forces.append(np.zeros(3))
                present.append(False)
        if block.estimates:
            self._last_s = block.estimates[-1][1].t_s
        self._send(times, samples, points, forces, present)

    def finish(self) -> None:
        """Clear the track of an event still open at the end at the last sample (when
        its last estimate came before it); call once, after the last block."""
        if not self.active or self._end is None or self.stream.pipeline is None \
                or self.stream.pipeline.current is None:
            return
        end, sample = self._end
        if self._last_s is not None and self._last_s < end:
            self._send([end], [sample], [np.zeros(3)], [np.zeros(3)], [False])

    def _send(self, times: list[float], samples: list[int], points: list[np.ndarray],
              forces: list[np.ndarray], present: list[bool]) -> None:
        """Send rows of the contact track in time order: times [s], samples, points [m]
        and forces [N] (3 each, zeros where not ``present``)."""
        if not times:
            return
        order = np.argsort(times, kind="stable")
        layout.log_contact_columns(self.rec, np.array(times)[order],
                                   np.array(samples, dtype=np.int64)[order],
                                   np.array(points)[order], np.array(forces)[order],
                                   np.array(present)[order])


def log_contact_links(rec: rr.RecordingStream, stream: ReplayStream) -> None:
    """Highlight, while each event of ``stream`` lasts (onset to release, or to the
    last sample for one still open at the end), the link its contact estimate at the
    peak names, where that link has a collision surface. Call once the blocks have
    streamed."""
    isolator = None if stream.pipeline is None else stream.pipeline.isolator
    if isolator is None:
        return
    ends = stream.event_samples
    last = max(ends)
    shown: dict[int, list[tuple[float, int, bool]]] = {}
    for event in stream.events:
        end = event.release_s if event.release_s is not None else last
        peak = event.contact_at_peak
        if peak is not None and peak.link is not None and \
                isolator.samples[peak.link - 1] is not None:
            shown.setdefault(peak.link, []).extend(
                [(event.onset_s, ends[event.onset_s], True), (end, ends[end], False)])
    for link, rows in shown.items():
        rows.sort()
        samples = isolator.samples[link - 1]
        assert samples is not None  # only links with samples are shown
        layout.log_link_highlight(rec, link, samples.points,
                                  np.array([r[0] for r in rows]),
                                  np.array([r[1] for r in rows]),
                                  np.array([r[2] for r in rows]))
