"""The importer protocol: one reader per file format, as python-can has one per log format.

An importer is one class (a subclass of :class:`Importer`) that opens one recording
and streams it as session columns:

* ``name``: the format name ``recorder import --format NAME`` selects it by;
* ``source``: the ``source`` its sessions' metadata names (``csv``, ``can-log``...);
* ``suffixes``: the file suffixes it claims when no ``--format`` is given;
* ``Config``: a dataclass whose fields are the format's options, declared as a
  source's are (:mod:`contactkit.recorder.sources.options`: type, default, ``help``,
  ``unit`` and ``name`` in the field's metadata; a field without a default is
  required). ``recorder import`` offers ``--map``, ``--topic``, ``--label-topic``,
  ``--q``, ``--dq``, ``--tau``, and ``--option NAME=VALUE`` for any other (the text
  read as the field's type); an option the format does not take is an error;
* ``open(path, config)``: reads the file with its checked ``Config`` (a
  :class:`~contactkit.errors.InputError` naming the file when it cannot be used); a
  long file is read in bounded memory, into temporary files where the format decides
  things only at its end;
* ``times()`` and ``chunks()``: fresh iterators over the recording from its start, of
  the time stamps [s] and of dicts of session columns (``t`` in s, ``q_1`` .. in rad,
  ``dq_*`` in rad/s, ``tau_*`` in Nm, optional columns), a block of samples at a time.
  Times are read several times, chunks twice (the writer's contract,
  :func:`contactkit.recorder.importers.writer.write_imported_chunks`);
* ``source_info()``: the statistics stored as the session's ``source_info``.

``close()`` removes what ``open`` left behind; an importer is a context manager. The
other methods have defaults an importer may override: ``defaults()`` (protocol choices
the file itself states, such as a map's robot), ``metadata(meta)`` (the finished
metadata), ``file_name(meta)``, ``summary()`` (the line ``recorder import`` prints),
``claims(path)`` and ``find(directory)``.

This module is light (no numpy at import time), so the registry that lists the
importers keeps ``recorder --help`` fast.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:
    import numpy as np

    from contactkit.schemas import SessionMeta


@dataclass(frozen=True)
class NoOptions:
    """The ``Config`` of a format that takes no option."""


class Importer(ABC):
    """One opened recording of a file format, streamed as session columns (see the
    module docstring for what a subclass declares)."""

    name: ClassVar[str]
    source: ClassVar[str]
    suffixes: ClassVar[tuple[str, ...]] = ()
    Config: ClassVar[type] = NoOptions
    description: ClassVar[str] = ""

    @classmethod
    @abstractmethod
    def open(cls, path: Path, config: Any) -> Importer:
        """Read the recording at ``path`` with the format's options ``config`` (an
        instance of :attr:`Config`, checked); return the opened importer. Raises
        InputError naming the file when it cannot be used."""

    @abstractmethod
    def times(self) -> Iterator[np.ndarray]:
        """Yield the time stamps [s] of every sample, in order, a block at a time."""

    @abstractmethod
    def chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield the session columns of every sample, in order, a block at a time."""

    @abstractmethod
    def source_info(self) -> dict[str, Any]:
        """Return the import's statistics for the session's ``source_info``."""

    def close(self) -> None:  # noqa: B027 (an optional hook, empty by default)
        """Remove the temporary files the import holds (nothing by default)."""

    def __enter__(self) -> Importer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def defaults(self) -> dict[str, Any]:
        """Return protocol choices the file states (keyword arguments of
        :func:`contactkit.recorder.metadata.session_meta`, such as ``robot``), which the
        user's choices override; none by default."""
        return {}

    def metadata(self, meta: SessionMeta) -> SessionMeta:
        """Return the session's metadata, given the metadata built from the protocol
        choices: by default ``meta`` with :meth:`source_info` stored in it."""
        meta.source_info = self.source_info()
        return meta

    def file_name(self, meta: SessionMeta) -> str | None:
        """Return the session's file name, or None for the name from its metadata
        (:func:`contactkit.recorder.metadata.session_filename`)."""
        return None

    def summary(self) -> str:
        """Return what the import read, in a line or two for the terminal."""
        info = self.source_info()
        return ", ".join(f"{key} {value}" for key, value in info.items()
                         if isinstance(value, int | float) and not isinstance(value, bool))

    @classmethod
    def claims(cls, path: Path) -> bool:
        """Return whether this format reads ``path`` when no format is given: by default
        when its suffix is one of ``suffixes`` (any case)."""
        return path.suffix.lower() in cls.suffixes

    @classmethod
    def find(cls, directory: Path) -> list[Path]:
        """Return the recordings of this format in ``directory`` and below, sorted: by
        default the files it claims."""
        return sorted(p for p in directory.rglob("*") if p.is_file() and cls.claims(p))
