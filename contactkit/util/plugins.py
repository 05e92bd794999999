"""One registry class for everything contactkit chooses by name and installed packages
extend through an entry-point group, as python-can's interfaces are: the sources
(``contactkit.sources``), the importers (``contactkit.importers``), the classifier kinds
(``contactkit.models``) and the robots (``contactkit.robots``).

Names are listed without importing anything; a plugin is imported when it is first
asked for, checked, and kept. A built-in name cannot be taken over by a plugin."""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Iterable, Mapping
from typing import Generic, TypeVar

from contactkit.errors import ContactkitError, InputError

T = TypeVar("T")

Check = Callable[[str, str, object], T]
"""``check(name, target, loaded)``: return what ``target`` (``module:attr``) gave, as the
registry's type, or raise one InputError line saying why it is not usable."""


class Registry(Generic[T]):
    """Things of one kind by name: the ``builtin`` ones (the things themselves, or
    ``module:attr`` targets imported on first use), then those installed packages declare
    in the entry-point ``group`` (by name), then those added in-process with
    :meth:`register`.

    ``what`` names the kind in messages (``"importer"``, ``"model kind"``); ``check``
    turns an imported target into the registry's type or refuses it (see :data:`Check`);
    ``reserved`` are further names no plugin may take (a built-in's aliases). The
    entry points are read once (:meth:`refresh` reads them again)."""

    def __init__(self, what: str, group: str, builtin: Mapping[str, T | str],
                 check: Check[T], reserved: Iterable[str] = ()) -> None:
        self.what, self.group, self._check = what, group, check
        self._builtin: dict[str, T | str] = dict(builtin)
        self._reserved = frozenset(reserved)
        self._added: dict[str, T] = {}
        self._loaded: dict[str, T] = {}
        self._plugins: dict[str, str] | None = None

    def refresh(self) -> None:
        """Forget the entry points read and the plugins loaded (a test that installs
        one, a notebook after ``pip install``)."""
        self._plugins = None
        self._loaded.clear()

    def _entry_points(self) -> dict[str, str]:
        if self._plugins is None:
            import importlib.metadata  # some 35 ms, paid only where plugins are looked for

            taken = self._builtin.keys() | self._reserved
            self._plugins = {}
            entries = importlib.metadata.entry_points(group=self.group)
            for entry in sorted(entries, key=lambda entry: entry.name):
                if entry.name not in taken:
                    self._plugins.setdefault(entry.name, entry.value)
        return self._plugins

    def targets(self) -> dict[str, T | str]:
        """Return every name with what it stands for: a thing, or the ``module:attr``
        of one not imported yet; built-in first, then plugins, then those registered
        in-process. Nothing is imported."""
        found: dict[str, T | str] = dict(self._builtin)
        for name, target in self._entry_points().items():
            found.setdefault(name, target)
        for name, item in self._added.items():
            found.setdefault(name, item)
        return found

    def names(self) -> list[str]:
        """Return every name (see :meth:`targets`); nothing is imported."""
        return list(self.targets())

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self.targets()

    def get(self, name: str) -> T:
        """Return the thing registered as ``name``, importing and checking a target on
        first use. Raises one InputError line for an unknown name (listing the known
        ones) or a target that cannot be loaded or is not usable."""
        found = self.targets()
        if name not in found:
            raise InputError(f"unknown {self.what} {name!r} (expected one of "
                             f"{', '.join(found)})")
        return self._resolve(name, found[name])

    def _resolve(self, name: str, target: T | str) -> T:
        if not isinstance(target, str):
            return target
        if name not in self._loaded:
            module, _, attr = target.partition(":")
            try:
                loaded = getattr(importlib.import_module(module), attr)
            except (ImportError, AttributeError) as err:
                raise InputError(f"{self.what} {name!r} ({target}) cannot be loaded: "
                                 f"{err}") from err
            self._loaded[name] = self._check(name, target, loaded)
        return self._loaded[name]

    def load_all(self) -> tuple[dict[str, T], dict[str, str]]:
        """Return every loadable thing by name, and the one-line problem of each one
        that is not: a broken plugin must not hide the others."""
        things: dict[str, T] = {}
        problems: dict[str, str] = {}
        for name, target in self.targets().items():
            try:
                things[name] = self._resolve(name, target)
            except ContactkitError as err:
                problems[name] = str(err)
        return things, problems

    def register(self, name: str, item: T, *, replace: bool = False) -> T:
        """Add ``item`` under ``name`` in this process; return it. A name already taken
        by something else is refused unless ``replace`` (then ``item`` is what the name
        gives from now on)."""
        found = self.targets()
        if name in found and not replace and self._resolve(name, found[name]) is not item:
            raise InputError(f"{self.what} {name!r} is already registered")
        for table in (self._builtin, self._loaded):
            table.pop(name, None)
        if self._plugins is not None:
            self._plugins.pop(name, None)
        self._added[name] = item
        return item

    def unregister(self, name: str) -> None:
        """Remove ``name`` wherever it came from (for tests and notebooks that
        registered their own)."""
        for table in (self._builtin, self._added, self._loaded):
            table.pop(name, None)
        if self._plugins is not None:
            self._plugins.pop(name, None)


def subclass_check(what: str, base: type) -> Check[type]:
    """Return a :data:`Check` that accepts a complete (non-abstract) subclass of
    ``base`` and refuses anything else in one line."""

    def check(name: str, target: str, loaded: object) -> type:
        if not (inspect.isclass(loaded) and issubclass(loaded, base)) \
                or inspect.isabstract(loaded):
            raise InputError(f"{what} {name!r} ({target}) is not a complete "
                             f"{base.__name__} subclass")
        return loaded

    return check
