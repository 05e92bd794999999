"""Contact events while recording: a capture listener that runs the event pipeline.

:class:`LiveEvents` takes the capture's chunks of samples (dicts of column arrays, as
sources yield them) and runs each chunk through the feature chain's observer
(:meth:`contactkit.features.timeseries.TimeseriesChain.feed`, state carried) and each
sample, in arrival order, through the event
pipeline (:class:`contactkit.classify.events.contact_events.EventPipeline`): the same code, on the
same samples, as ``replay`` runs on the written session, so both find the same
events. Samples that lack a joint value (NaN gaps of a CAN source) are skipped, as
the replay of the session skips them. Each onset, decision and release is handed to
``report`` as it happens; :meth:`LiveEvents.session_fields` gives the events for the
session metadata when the capture closes.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from contactkit.classify.events.contact_events import ContactEvent, EventModel, EventPipeline
from contactkit.features.detector import DYNAMIC_FEATURE, DetectorConfig
from contactkit.features.isolation import OK, ContactEstimate, ContactIsolator
from contactkit.features.timeseries import ChainConfig, TimeseriesChain
from contactkit.robots import RobotSetup
from contactkit.schemas.session import SampleBatch

Report = Callable[[str, ContactEvent], None]
"""Called with ("onset" | "decision" | "release", the event) as each happens."""


def contact_text(estimate: ContactEstimate | None) -> str:
    """Return a short text for a contact estimate: link, point (base frame, m), force
    (base frame, N) and confidence, or why there is none."""
    if estimate is None:
        return "no contact estimate"
    if estimate.status != OK:
        return (f"link {estimate.link}, no point ({estimate.status})" if estimate.link
                else f"no contact estimate ({estimate.status})")
    assert estimate.point_base is not None and estimate.force is not None  # status OK
    point = ", ".join(f"{v:.3f}" for v in estimate.point_base)
    force = ", ".join(f"{v:.1f}" for v in estimate.force)
    return (f"link {estimate.link} at ({point}) m, force ({force}) N, confidence "
            f"{estimate.confidence:.2f}" + (", ambiguous" if estimate.ambiguous else ""))


def describe(kind: str, event: ContactEvent) -> str:
    """Return a one-line text for an event report: times in s, probability of the label,
    and the contact estimate at the decision and (at the release) at the peak."""
    if kind == "onset":
        return f"contact onset at {event.onset_s:.3f} s"
    if kind == "decision":
        p = event.probabilities.get(event.label)
        return (f"contact decided at {event.decision_s:.3f} s: {event.label}"
                + ("" if p is None else f" (p = {p:.2f})")
                + (" (outside the training range)" if event.out_of_range else
                   f" (beyond the training range, {event.beyond_range}: "
                   f"{', '.join(event.beyond_features)})" if event.beyond_range else "")
                + ("" if event.contact_at_decision is None
                   else f"; {contact_text(event.contact_at_decision)}"))
    assert event.release_s is not None  # a release
    return (f"contact released at {event.release_s:.3f} s: {event.label}, "
            f"{event.release_s - event.onset_s:.3f} s long"
            + ("" if event.contact_at_peak is None
               else f"; at the peak {contact_text(event.contact_at_peak)}"))


class LiveEvents:
    """Capture listener: per sample observer -> detector -> decide -> hold.

    ``chain`` is the feature chain configuration of the model (its observer),
    ``robot`` the arm being recorded, ``detector`` and ``model`` the
    contact detector settings and intent classifier, ``decide_after_s`` [s] the
    decision delay (None: the model's), ``report`` receives every onset, decision
    and release as it happens, ``isolator`` estimates the touched link, point and force.
    The events keep their estimates at the decision and at the peak; with ``keep_track``
    they also keep every estimate of their track (50 Hz while a contact lasts, about 1.7
    kB each), which the session's metadata leaves out: without it (the default) a
    capture's memory does not grow with the time spent in contact.
    """

    def __init__(self, chain: ChainConfig, robot: RobotSetup, detector: DetectorConfig,
                 model: EventModel | None = None, decide_after_s: float | None = None,
                 report: Report | None = None,
                 isolator: ContactIsolator | None = None, keep_track: bool = False) -> None:
        self.chain = TimeseriesChain(chain, robot, detector.chain_features)
        self.pipeline = EventPipeline(detector.for_robot(self.chain.model.spec), model,
                                      decide_after_s, isolator, keep_track)
        self.report = report
        self.samples = 0

    def on_chunk(self, chunk: dict[str, np.ndarray]) -> None:
        """Feed one chunk of recorded rows (``t`` [s] and the joint columns)."""
        batch = SampleBatch.from_columns(chunk).complete()
        features = self.chain.feed(batch)
        r, dyn = features["r"], features.get(DYNAMIC_FEATURE)
        for k in range(len(batch)):
            state = self.pipeline.update(float(batch.t[k]), r[k], batch.dq[k], batch.q[k],
                                         None if dyn is None else dyn[k])
            self.samples += 1
            if self.report is None:
                continue
            for kind, event in (("onset", state.started), ("decision", state.decided),
                                ("release", state.released)):
                if event is not None:
                    self.report(kind, event)

    @property
    def events(self) -> list[ContactEvent]:
        """The events so far (the last one may still be open)."""
        return self.pipeline.finish()

    def session_fields(self) -> dict[str, list[dict]]:
        """Return the session metadata fields to store: ``events``, one dict per event."""
        return {"events": [event.to_dict() for event in self.events]}
