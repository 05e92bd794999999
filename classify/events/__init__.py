"""Contact events: the pipeline a replay and a live capture run (:mod:`.contact_events`),
its per-sample listener (:mod:`.listener`), event-level metrics (:mod:`.metrics`), the
per-event classifier's training (:mod:`.training`) and the detector's calibration
(:mod:`.calibrate`).

The names of :mod:`contactkit.classify.events.contact_events` can also be imported from here (``from
contactkit.classify.events import EventPipeline``), as they were before this package had
modules of its own; nothing is imported until one is asked for.
"""

from __future__ import annotations

from contactkit.classify import names_of

__all__ = ["calibrate", "contact_events", "listener", "metrics", "training"]
"""The public modules, for the API reference."""
__getattr__ = names_of(__name__, "contactkit.classify.events.contact_events")
