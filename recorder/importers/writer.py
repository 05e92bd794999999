"""The one writer of every importer, and the parsing of ``--meta KEY=VALUE`` pairs.

:func:`write_imported_chunks` turns a recording streamed in chunks into a validated
session file (time from 0 s, the nominal rate measured, the residual's agreement with
the robot's own estimate), in bounded memory; :func:`write_importer` runs an opened
:class:`~contactkit.recorder.importers.base.Importer` through it.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import fields
from pathlib import Path

import numpy as np
import pyarrow as pa

from contactkit.features.agreement import stream_residual_agreement
from contactkit.features.timing import chunked_steps
from contactkit.recorder.importers.base import Importer
from contactkit.recorder.metadata import session_filename
from contactkit.schemas import InputError, SessionMeta
from contactkit.schemas.columns import check_times
from contactkit.schemas.dataset import INDEX_NAME
from contactkit.schemas.session import table_from_columns, write_session_batches
from contactkit.util.exact_median import exact_medians
from contactkit.util.paths import inside, safe_name
from contactkit.util.text import quote

_FIELDS = {f.name: f for f in fields(SessionMeta)}
_NOT_SETTABLE = {"schema_version", "recovered", "recovered_samples", "simulator", "source_info",
                 "tool_version", "created_utc", "urdf_sha256"}


def parse_meta(pairs: list[str]) -> dict:
    """Parse KEY=VALUE strings into metadata fields (values read as JSON when they can be,
    so numbers, true/false and lists work; anything else is a string)."""
    doc: dict = {}
    for pair in pairs:
        key, sep, raw = pair.partition("=")
        key = key.strip()
        if not sep or key not in _FIELDS or key in _NOT_SETTABLE:
            settable = sorted(set(_FIELDS) - _NOT_SETTABLE)
            raise InputError(f"bad metadata pair {quote(pair)} (expected KEY=VALUE with KEY "
                             f"one of {', '.join(settable)})")
        if len(raw) > MAX_META_CHARS:
            raise InputError(f"metadata value of {key} has {len(raw)} characters (at most "
                             f"{MAX_META_CHARS})")
        if key in BOOLEAN_FIELDS:
            doc[key] = parse_bool(raw, key)
            continue
        try:
            value = json.loads(raw)
        except (ValueError, RecursionError):  # not JSON, or a 5000-digit number
            value = raw
        if key in ("operator", "notes", "pose", "target_pose", "action", "condition",
                   "session_id", "source"):
            value = raw
        doc[key] = value
    return doc


MAX_META_CHARS = 10_000
"""The longest ``--meta`` value [characters]."""
BOOLEAN_FIELDS = ("with_hand",)
_TRUE, _FALSE = ("true", "1"), ("false", "0")


def parse_bool(raw: str, key: str) -> bool:
    """Return the boolean ``raw`` spells (true/false or 1/0, any case); anything else
    (no, maybe, yes, an empty value) is an InputError rather than a guess."""
    word = raw.strip().lower()
    if word in _TRUE or word in _FALSE:
        return word in _TRUE
    raise InputError(f"{key} must be true or false (or 1 or 0), got {quote(raw)}")



def output_name(name: str) -> str:
    """Return a session file name the user gave (``--name``) after checking it: a safe
    file name, and not a name the tool keeps for itself (``index.parquet``)."""
    safe_name(name, "output name")
    if name.lower() == INDEX_NAME:
        raise InputError(f"{INDEX_NAME} is the dataset index's name; choose another --name")
    return name


def write_imported_chunks(times: Callable[[], Iterable[np.ndarray]],
                          chunks: Callable[[], Iterable[Mapping[str, np.ndarray]]],
                          meta: SessionMeta, out_dir: Path, name: str | None = None,
                          overwrite: bool = False) -> Path:
    """Write an imported recording streamed in chunks as a validated session; return
    the path. Time [s] is shifted to start at 0, the nominal rate [Hz] is measured from
    the exact median time step where the metadata has none, and the file name comes
    from the metadata unless ``name`` is given (a safe file name that stays inside
    ``out_dir``). The write is atomic; an existing file is replaced only with
    ``overwrite``. Memory holds one Parquet row group however long the recording is.

    ``times()`` and ``chunks()`` each return a fresh iterable over the recording from
    its start: of the time stamps [s], and of dicts of session columns (``t`` among
    them) for consecutive samples. The times are read once (the time rule, the first
    stamp and the count), and a few more times when the nominal rate must be measured
    (its exact median step); the chunks twice: for
    the residual's agreement, then while writing (row groups of
    :data:`contactkit.schemas.session.ROW_GROUP_ROWS`). A recording with the robot's
    own estimate (``tau_ext_hat``) is run through the chain of its robot first, and
    the residual's agreement with that estimate is stored in the metadata
    (``residual_agreement``, :mod:`contactkit.features.agreement`), which
    ``recorder info`` shows without running the chain.
    """
    first, last, samples = None, None, 0
    for t in times():  # the time rule first: nothing runs on a clock switch's years
        if len(t):
            check_times(t, offset=samples, last_t=last)  # strictly increasing, among others
            first = float(t[0]) if first is None else first
            samples += len(t)
            last = float(t[-1])
    if meta.nominal_rate_hz is None and samples > 1:
        median = exact_medians(lambda: (s[:, None] for s in chunked_steps(times())))[0]
        meta.nominal_rate_hz = float(round(1.0 / median, 3))
    filename = session_filename(meta) if name is None else output_name(name)
    meta.residual_agreement = stream_residual_agreement(chunks(), meta.robot_setup())

    def batches() -> Iterator[pa.RecordBatch]:
        for chunk in chunks():
            columns = dict(chunk)
            columns["t"] = np.asarray(columns["t"], dtype=float) - first
            yield from table_from_columns(columns, meta).to_batches()

    path = inside(out_dir, filename)
    write_session_batches(path, batches(), meta, overwrite=overwrite)
    return path


def write_importer(importer: Importer, meta: SessionMeta, out_dir: Path,
                   name: str | None = None, overwrite: bool = False) -> Path:
    """Write an opened importer's recording as a validated session in ``out_dir``;
    return its path.

    ``meta`` is the metadata of the protocol choices; the importer completes it
    (``source_info``, what the file states, :meth:`Importer.metadata`) and may name the
    file (``name`` overrides it). The chunks are streamed through
    :func:`write_imported_chunks`, the one writer of every importer.
    """
    meta = importer.metadata(meta)
    return write_imported_chunks(importer.times, importer.chunks, meta, out_dir,
                                 name or importer.file_name(meta), overwrite)
