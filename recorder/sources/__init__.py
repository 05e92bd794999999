"""Data sources, chosen by name (like python-can's interface registry).

A source is a small class implementing :class:`contactkit.recorder.sources.base.Source`; a
new robot is one new module here and one line in ``SOURCES``.
"""

from __future__ import annotations

import importlib

from contactkit.recorder.sources.base import Source
from contactkit.schemas import InputError

SOURCES: dict[str, str] = {
    "sim": "contactkit.recorder.sources.sim:SimSource",
    "can": "contactkit.recorder.sources.can:CanSource",
    "franka": "contactkit.recorder.sources.franka:FrankaSource",
}


def source_class(name: str) -> type[Source]:
    """Return the source class registered under ``name``, or raise InputError."""
    if name not in SOURCES:
        raise InputError(f"unknown source {name!r} (available: {', '.join(SOURCES)})")
    module, cls = SOURCES[name].split(":")
    return getattr(importlib.import_module(module), cls)


__all__ = ["SOURCES", "Source", "source_class"]
