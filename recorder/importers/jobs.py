"""Running importers: a file in, a validated session out, through the one writer.

Every format takes the same path (:func:`import_file`): its importer (chosen by name
or by the file's suffix, :mod:`contactkit.recorder.importers.registry`) opens the
file, the session metadata is built from the protocol choices over what the file
states, and :func:`contactkit.recorder.importers.writer.write_imported_chunks` writes
the streamed chunks, so memory stays bounded however long the recording.
:func:`import_files` runs many files in parallel, each failure reported on its own.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from contactkit.recorder.importers.base import Importer
from contactkit.recorder.importers.registry import importer_class, importer_for
from contactkit.recorder.importers.writer import output_name, parse_meta, write_importer
from contactkit.recorder.metadata import session_meta
from contactkit.schemas import InputError, SessionMeta
from contactkit.util.parallel import map_ordered, split_problems
from contactkit.util.params import dataclass_params, make_config, parse_text
from contactkit.util.progress import ProgressCallback
from contactkit.util.text import quote

_OPTION_NAME = re.compile(r"[a-z][a-z0-9_]*")


@dataclass(frozen=True)
class ImportJob:
    """One recording to import: the file, where its session goes, the protocol choices
    (keyword arguments of :func:`contactkit.recorder.metadata.session_meta`; a missing
    or None value is not chosen), the format (None: from the file) and its options, and
    the output file name (None: from the metadata)."""

    path: Path
    out_dir: Path
    protocol: Mapping[str, Any] = field(default_factory=dict)
    format: str | None = None
    options: Mapping[str, Any] = field(default_factory=dict)
    name: str | None = None
    overwrite: bool = False


@dataclass(frozen=True)
class Imported:
    """A recording imported: its file, the session written and what the import read, in
    a line or two."""

    recording: Path
    session: Path
    summary: str


def importer_of(path: Path, format: str | None = None) -> type[Importer]:
    """Return the importer of format ``format``, or the one that claims ``path``."""
    return importer_class(format) if format is not None else importer_for(path)


def open_importer(path: Path, format: str | None = None,
                  options: Mapping[str, Any] | None = None) -> Importer:
    """Open ``path`` with the importer of ``format`` (None: the one its suffix says) and
    its format ``options``, keyed by option name (``map``, ``label_topic``); a string
    value (``--option NAME=VALUE``'s) is read as the option's type. An option the
    format does not take, a required one missing or a value it refuses is an
    InputError."""
    cls = importer_of(path, format)
    owner = f"import format {cls.name!r}"
    declared = {p.option.removeprefix("--").replace("-", "_"): p
                for p in dataclass_params(cls.Config)}
    values = {}
    for key, value in (options or {}).items():
        if key not in declared:
            raise InputError(f"{owner} takes no option {key!r} (its options: "
                             f"{', '.join(declared) or 'none'})")
        param = declared[key]
        values[param.name] = (parse_text(param, value, owner) if isinstance(value, str)
                              else value)
    return cls.open(path, make_config(owner, cls.Config, values))


def import_file(job: ImportJob) -> Imported:
    """Import one recording as a validated session; return it and the import's summary.

    The protocol choices the job leaves out come from the file where it states them
    (:meth:`Importer.defaults`), else from :func:`~contactkit.recorder.metadata.session_meta`'s
    defaults (``action`` none). Raises InputError naming the file for a file that cannot
    be used, and for an existing session file unless ``overwrite``.
    """
    if job.name is not None:
        output_name(job.name)
    try:
        with open_importer(job.path, job.format, job.options) as importer:
            chosen = {key: value for key, value in job.protocol.items() if value is not None}
            protocol = {"action": "none", "source": importer.source, **importer.defaults(),
                        **chosen}
            path = write_importer(importer, checked_meta(protocol), job.out_dir, job.name,
                                  job.overwrite)
            return Imported(job.path, path, importer.summary())
    except InputError as err:  # a problem found in the streamed data names no file yet
        if err.path is not None:
            raise
        raise InputError(err.problem, job.path) from err


def checked_meta(protocol: Mapping[str, Any]) -> SessionMeta:
    """Return checked session metadata from ``protocol`` (keyword arguments of
    :func:`~contactkit.recorder.metadata.session_meta`, with ``source``); InputError
    "bad metadata: ..." when the values do not make valid metadata."""
    try:
        meta = session_meta(**protocol)
        meta.check()
    except (InputError, TypeError) as err:
        raise InputError(f"bad metadata: {err}") from err
    return meta


def protocol_from(choices: Mapping[str, Any], pairs: list[str]) -> dict[str, Any]:
    """Return the protocol choices of an import: ``choices`` (session_meta's keyword
    arguments; None: not chosen) and ``KEY=VALUE`` metadata pairs (``--meta``,
    :func:`~contactkit.recorder.importers.writer.parse_meta`). A field given both ways
    with different values is an InputError."""
    doc = parse_meta(pairs)
    for key, argument in (("pose_q", "pose_q_rad"), ("target_q", "target_q_rad")):
        if key in doc:
            doc[argument] = doc.pop(key)
    for key, value in choices.items():
        if value is None:
            continue
        if key in doc and doc[key] != value:
            raise InputError(f"--meta {key}={quote(str(doc[key]))} disagrees with the "
                             f"option's {quote(str(value))}")
        doc[key] = value
    return doc


def format_options(named: Mapping[str, Any], pairs: list[str]) -> dict[str, Any]:
    """Return the format options of an import: the ``named`` ones that were given (not
    None) and ``NAME=VALUE`` strings (``--option``; the value stays a string)."""
    options = {key: value for key, value in named.items() if value is not None}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or not _OPTION_NAME.fullmatch(key):
            raise InputError(f"bad format option {quote(pair)} (expected NAME=VALUE)")
        if key in options:
            raise InputError(f"format option {key!r} given twice")
        options[key] = value
    return options


def import_jobs(paths: list[Path], format: str | None, out_dir: Path, **settings: Any
                ) -> list[ImportJob]:
    """Return the jobs of importing ``paths``: each file, and each recording of
    ``format`` in a directory (a directory that is itself a recording, a ROS 2 bag's,
    counts as one). ``settings`` are the other :class:`ImportJob` fields. Raises
    InputError for an output ``name`` that is not a safe file name or is given for more
    than one path, a missing path, and a directory without ``format`` or without
    recordings."""
    if settings.get("name") is not None:
        output_name(settings["name"])
    jobs = []
    for path in paths:
        if not path.exists():
            raise InputError("no such file or directory", path)
        found = [path]
        if path.is_dir() and not (format is None and _claimed(path)):
            if format is None:
                raise InputError("a directory: give --format to import the recordings in "
                                 "it", path)
            cls = importer_class(format)
            if not cls.claims(path):
                found = cls.find(path)
                if not found:
                    raise InputError(f"no {format} recordings found", path)
        jobs += [ImportJob(p, out_dir, format=format, **settings) for p in found]
    if settings.get("name") is not None and len(jobs) > 1:
        raise InputError(f"--name needs a single recording, not {len(jobs)}")
    return jobs


def _claimed(path: Path) -> bool:
    try:
        importer_for(path)
    except InputError:
        return False
    return True


def _job(job: ImportJob) -> tuple[str, Imported | None, str | None]:
    try:
        return str(job.path), import_file(job), None
    except InputError as err:
        return str(job.path), None, err.problem


def import_files(jobs: list[ImportJob], workers: int = 1,
                 progress: ProgressCallback | None = None, *, scheduler: str | None = None
                 ) -> tuple[list[Imported], list[tuple[str, str]]]:
    """Import many recordings (in ``workers`` processes, or on the Dask ``scheduler``);
    return the written sessions and ``(file, problem)`` for each one that could not be
    imported (one bad file never stops the others)."""
    return split_problems(map_ordered(_job, jobs, workers=workers, progress=progress,
                                      scheduler=scheduler))
