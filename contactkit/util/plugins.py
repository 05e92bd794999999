"""Registries of classes by name that installed packages extend through an entry-point
group, as python-can's interfaces are: the sources (``contactkit.sources``) and the
importers (``contactkit.importers``). Names are listed without importing anything; a
class is imported when it is first asked for."""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Mapping

from contactkit.errors import ContactkitError, InputError


def registered(builtin: Mapping[str, str], group: str) -> dict[str, str]:
    """Return every name with its ``module:Class``: the ``builtin`` ones, then those that
    installed packages declare in the entry-point ``group`` (a built-in name cannot be
    taken over). Nothing is imported."""
    import importlib.metadata  # some 35 ms, paid only where plugins are looked for

    found = dict(builtin)
    for entry in importlib.metadata.entry_points(group=group):
        found.setdefault(entry.name, entry.value)
    return found


def load_class(what: str, name: str, target: str, base: type) -> type:
    """Import ``target`` (``module:Class``) registered as the ``what`` called ``name``;
    return the class. Raises one InputError line when it cannot be imported, or is not a
    complete (non-abstract) subclass of ``base``."""
    module, _, attr = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as err:
        raise InputError(f"{what} {name!r} ({target}) cannot be loaded: {err}") from err
    if not (inspect.isclass(cls) and issubclass(cls, base)) or inspect.isabstract(cls):
        raise InputError(f"{what} {name!r} ({target}) is not a complete {base.__name__} "
                         "subclass")
    return cls


def load_all(targets: Mapping[str, str], load: Callable[[str, str], type]
             ) -> tuple[dict[str, type], dict[str, str]]:
    """Return the classes ``load(name, target)`` gives for each of ``targets`` (name ->
    ``module:Class``), and the one-line problem of each that cannot be loaded: a broken
    plugin must not hide the others."""
    classes: dict[str, type] = {}
    problems: dict[str, str] = {}
    for name, target in targets.items():
        try:
            classes[name] = load(name, target)
        except ContactkitError as err:
            problems[name] = str(err)
    return classes, problems
