"""Contact events: the pipeline a replay and a live capture run (:mod:`.contact_events`),
its per-sample listener (:mod:`.listener`), event-level metrics (:mod:`.metrics`), the
per-event classifier's training (:mod:`.training`) and the detector's calibration
(:mod:`.calibrate`).

The names of :mod:`contactkit.classify.events.contact_events` can also be imported from here (``from
contactkit.classify.events import EventPipeline``), as they were before this package had
modules of its own; nothing is imported until one is asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["calibrate", "contact_events", "listener", "metrics", "training"]
"""The public modules, for the API reference."""
_MAIN = "contactkit.classify.events.contact_events"


def __getattr__(name: str) -> Any:
    """Return ``name`` from
    :mod:`contactkit.classify.events.contact_events` (imported on first use)."""
    if name.startswith("__"):
        raise AttributeError(name)
    try:
        return getattr(importlib.import_module(_MAIN), name)
    except AttributeError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
