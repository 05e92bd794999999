"""Data sources, chosen by name (like python-can's interface registry).

A source is one class (subclass of :class:`Source`) that owns everything about
where samples come from:

* ``name``: the name ``recorder capture --source NAME`` selects it by;
* ``Config``: a dataclass whose fields are its options. ``recorder capture`` offers
  each field as ``--field-name VALUE`` (``--flag/--no-flag`` for a bool), with the
  help, unit and default taken from the field (``metadata={"help": ..., "unit":
  ...}``, see :mod:`contactkit.recorder.sources.options`); ``recorder sources``
  lists every source with its options. Field names must not repeat a protocol
  option (pose, action, condition, target_pose, speed, link, planned_at, duration,
  operator, hand, notes, out, overwrite, realtime, viewer, save_rrd): the protocol
  choices reach the source through ``choices``. Two sources may share an option of
  the same type (``--timeout`` of a bus and of a robot);
* ``from_config(config, choices)``: builds the source from its options and the
  protocol choices (:class:`ProtocolChoices`: pose, action, timing, operator...);
* ``stream()``: yields chunks of session columns (``t`` in s, then ``q_1..``);
* ``metadata()``: the fields it contributes to the session metadata (``source``,
  ``source_info`` with its statistics, ``simulator``), asked again after the stream.

Built-in sources are listed in ``SOURCES``. A lab adds its arm from its own package
without touching contactkit: it declares an entry point in the group
``contactkit.sources``, for example in its ``pyproject.toml``::

    [project.entry-points."contactkit.sources"]
    myarm = "mylab.myarm:MyArmSource"

after which ``recorder capture --source myarm --my-option 3 --pose B --action adjust``
works. A source module should import heavy or optional packages (robot SDKs) inside
``from_config`` or ``stream``, since ``recorder capture`` and ``recorder sources`` import
every source to list its options (``recorder --help`` and the other commands import
none).
"""

from __future__ import annotations

from typing import cast

from contactkit.recorder.sources.base import ProtocolChoices, Source
from contactkit.recorder.sources.options import make_config, source_options
from contactkit.schemas import InputError
from contactkit.util.plugins import Registry, subclass_check

ENTRY_POINT_GROUP = "contactkit.sources"
SOURCES: dict[str, str] = {
    "sim": "contactkit.recorder.sources.sim:SimSource",
    "can": "contactkit.recorder.sources.can:CanSource",
    "franka": "contactkit.recorder.sources.franka:FrankaSource",
}


def _check(name: str, target: str, loaded: object) -> type[Source]:
    cls = cast(type[Source], subclass_check("source", Source)(name, target, loaded))
    try:
        source_options(cls.Config)
    except (AttributeError, TypeError, NameError) as err:
        raise InputError(f"source {name!r} ({target}) has no usable Config dataclass: "
                         f"{err}") from err
    return cls


REGISTRY: Registry[type[Source]] = Registry("source", ENTRY_POINT_GROUP, SOURCES, _check)
"""The sources by name (:class:`contactkit.util.plugins.Registry`)."""


def registered_sources() -> list[str]:
    """Return every source name: the built-in ones, then those that installed packages
    declare in the ``contactkit.sources`` entry-point group (a built-in name cannot be
    taken over; nothing is imported)."""
    return REGISTRY.names()


def source_class(name: str) -> type[Source]:
    """Return the source class registered under ``name``; raise InputError for an unknown
    name or a source that cannot be loaded."""
    return REGISTRY.get(name)


def load_sources() -> tuple[dict[str, type[Source]], dict[str, str]]:
    """Return the loadable sources by name, and the problem of each one that is not (a
    broken plugin must not break the others)."""
    return REGISTRY.load_all()


def open_source(name: str, options: dict, choices: ProtocolChoices) -> Source:
    """Return source ``name`` built from ``options`` (values keyed by ``Config`` field
    name; None means the default) and the protocol ``choices``."""
    cls = source_class(name)
    return cls.from_config(make_config(name, cls.Config, options), choices)


__all__ = ["ENTRY_POINT_GROUP", "REGISTRY", "SOURCES", "ProtocolChoices", "Source",
           "load_sources", "open_source", "registered_sources", "source_class",
           "source_options"]
