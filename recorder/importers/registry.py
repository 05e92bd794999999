"""Importers chosen by file suffix or by name (like python-can's log readers).

The built-in formats are listed in :data:`IMPORTERS`, one line each. A lab adds its own
format from its own package without touching contactkit: one module with a subclass of
:class:`~contactkit.recorder.importers.base.Importer`, and one entry point in the group
``contactkit.importers``, for example in its ``pyproject.toml``::

    [project.entry-points."contactkit.importers"]
    toy = "mylab.toy:ToyImporter"

after which ``recorder import run.toy --pose B --action bump`` works (``--format toy``
for a file whose suffix does not say). Listing the names reads the entry points' names
only: a plugin is imported when its format is asked for by name, when a file's suffix
is claimed by no built-in format, or by ``recorder importers``. A built-in name cannot
be taken over.
"""

from __future__ import annotations

from pathlib import Path
from typing import cast

from contactkit.errors import InputError
from contactkit.recorder.importers.base import Importer
from contactkit.util.plugins import Registry, subclass_check

ENTRY_POINT_GROUP = "contactkit.importers"
IMPORTERS: dict[str, str] = {
    "csv": "contactkit.recorder.importers.csv_import:CsvImporter",
    "can": "contactkit.recorder.importers.can_tools:CanLogImporter",
    "bag": "contactkit.recorder.importers.bags:BagImporter",
    "arrays": "contactkit.recorder.importers.arrays:ArraysImporter",
}
"""The built-in formats: name -> ``module:Class``. Suffixes are tried in this order."""


def _check(name: str, target: str, loaded: object) -> type[Importer]:
    cls = cast(type[Importer], subclass_check("importer", Importer)(name, target, loaded))
    if getattr(cls, "name", None) != name or not isinstance(getattr(cls, "source", None), str):
        raise InputError(f"importer {name!r} ({target}) must set name = {name!r} and a "
                         "source")
    return cls


REGISTRY: Registry[type[Importer]] = Registry("import format", ENTRY_POINT_GROUP, IMPORTERS,
                                              _check)
"""The import formats by name (:class:`contactkit.util.plugins.Registry`)."""


def registered_importers() -> list[str]:
    """Return every format name: the built-in ones, then those installed packages
    declare in the ``contactkit.importers`` entry-point group (nothing is imported)."""
    return REGISTRY.names()


def importer_class(name: str) -> type[Importer]:
    """Return the importer registered under ``name``; raise InputError for an unknown
    name or an importer that cannot be loaded."""
    return REGISTRY.get(name)


def importer_for(path: Path) -> type[Importer]:
    """Return the importer that claims ``path`` (by its suffix, or a ROS 2 bag's folder):
    the built-in formats first, then plugins, each imported only when the ones before
    did not claim it. Raises InputError naming the file when none does."""
    found = REGISTRY.names()
    for name in found:
        try:
            cls = REGISTRY.get(name)
        except InputError:
            if name in IMPORTERS:
                raise
            continue  # a broken plugin must not break the other formats
        if cls.claims(path):
            return cls
    what = f"{path.suffix!r} files" if path.suffix else "this file"
    raise InputError(f"no import format reads {what} (formats: {', '.join(found)}; give "
                     "--format)", path)


def load_importers() -> tuple[dict[str, type[Importer]], dict[str, str]]:
    """Return the loadable importers by name, and the problem of each one that is not (a
    broken plugin must not hide the others)."""
    return REGISTRY.load_all()


__all__ = ["ENTRY_POINT_GROUP", "IMPORTERS", "REGISTRY", "Importer", "importer_class",
           "importer_for", "load_importers", "registered_importers"]
