"""A dataset as a Rerun catalog: one recording per session, with its properties, and two
tables to query.

:func:`build_catalog` replays every session of a dataset (:func:`replay_session`, the
``replay`` pipeline) into ``DIR/<session id>.rrd``, whose recording id is the session id,
so that Rerun's catalog server (``rerun server -d DIR``, ``rr.server.Server``) serves
``DIR`` as one dataset with one segment per session. Each recording carries Rerun
recording properties, which the Viewer's dataset table shows as columns:

- ``session``: the session's metadata (:func:`~contactkit.replay.recording.log_session_properties`),
  its ``file`` relative to the dataset;
- ``catalog``: the model (name, SHA-256) and the dynamics the catalog was built with;
- ``result``: the recorded contact interval, the offline prediction and whether it was
  the recorded action (``correct``), the number of contact events and of those whose
  label is not the recorded action, and the residual's agreement with the robot's own
  estimate (the lowest correlation and the largest RMS difference over the joints);
- ``events``: one list per field with one entry per contact event (onset, decision,
  release, label, probabilities, the isolated link, point and force at the residual's
  peak, the peak score).

The same values go into two Parquet tables in ``DIR/tables/`` (:data:`TABLES`),
``sessions`` (one row per session) and ``events`` (one row per event, with its
session id), which :mod:`contactkit.replay.query` queries. ``DIR``'s top level holds
only the recordings; ``DIR/tables/manifest.json`` records, per session, its file's
SHA-256 and the recording written, and the model and dynamics of the catalog. A re-run
replays only the sessions that are new or whose file changed, and removes only
recordings it wrote (same name and size as recorded, a recording) whose session is
gone. A ``.rrd`` in ``DIR`` that the manifest does not list is refused, never
replaced or removed: the server would serve it as a segment.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.classify.modelfile.model_file import ModelFile, load_model
from contactkit.errors import DATA_ERRORS, InputError, problem_text
from contactkit.replay.engine import ReplayStream
from contactkit.replay.recording import RRD_MAGIC
from contactkit.replay.session_replay import ReplaySummary, replay_session
from contactkit.robots.dynamics import RobotChoice
from contactkit.schemas import read_session_meta
from contactkit.schemas.dataset import session_files
from contactkit.util.atomic import atomic_write, output_directory, write_text
from contactkit.util.owned import owned_result, result_json
from contactkit.util.parallel import map_ordered
from contactkit.util.progress import ProgressCallback

TABLES = "tables"
"""The subfolder of a catalog that holds its manifest and tables."""
MANIFEST = "manifest.json"
SESSIONS = "sessions.parquet"
EVENTS = "events.parquet"
FORMAT = 1
"""The manifest's format; a catalog of another format is rebuilt only with overwrite."""
TABLE_MARK = b"contactkit catalog"
"""Schema metadata key of the catalog's Parquet tables: a re-run replaces only those."""
_HASH_CHUNK = 1 << 20


@dataclass(frozen=True)
class CatalogIdentity:
    """What a catalog's recordings were computed with: the model (``name``, ``sha256`` of
    its file) and the robot dynamics (None: each session's own; ``--dynamics FILE``: the
    file's name and checksum). A catalog built with another identity is rebuilt only
    with overwrite."""

    model: dict
    dynamics: dict | None = None

    def to_dict(self) -> dict:
        """Return the identity as JSON-ready values."""
        return {"model": self.model, "dynamics": self.dynamics}


def file_sha256(path: str | Path) -> str:
    """Return the SHA-256 (hex) of a file's bytes, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_HASH_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def model_identity(path: Path, name: str | None = None) -> dict:
    """Return a model file's identity: ``name`` (default: the file's name) and SHA-256."""
    return {"name": name or Path(path).name, "sha256": file_sha256(path)}


def recording_name(session_id: str) -> str:
    """Return the file name of a session's recording in the catalog."""
    return f"{session_id}.rrd"


@dataclass
class CatalogJob:
    """One session to replay into the catalog (plain data, sent to a worker)."""

    path: Path
    file: str
    """The session file relative to the dataset (as the properties name it)."""
    target: Path
    model_path: Path
    identity: dict
    robot: RobotChoice = None


@dataclass
class CatalogResult:
    """What :func:`build_catalog` did: recordings ``replayed`` (session ids), ``kept``
    (unchanged) and ``removed`` (sessions gone), the sessions that failed as
    ``(file, problem)``, and the catalog's folder."""

    out: Path
    replayed: list[str] = field(default_factory=list)
    kept: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)


@functools.lru_cache(maxsize=2)
def _model(path: Path) -> ModelFile:
    """Return the model at ``path``, loaded once per process."""
    return load_model(path, lazy=True)


def _num(x: float | np.floating[Any] | None) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def event_rows(session_id: str, recorded: str, events: Iterable) -> list[dict]:
    """Return one row per contact event of a session: times [s], label, probabilities
    (JSON), whether its label is the recorded action ``recorded``, and the isolated
    contact at the residual's peak (link, point [m] in the base frame, force [N] and its
    norm), the peak detector score."""
    rows = []
    for k, event in enumerate(events):
        peak = event.contact_at_peak
        point = None if peak is None or peak.point_base is None else peak.point_base
        force = None if peak is None or peak.force is None else peak.force
        rows.append({
            "session_id": session_id, "event": k, "onset_s": float(event.onset_s),
            "decision_s": _num(event.decision_s), "release_s": _num(event.release_s),
            "label": event.label, "correct": event.label == recorded,
            "probabilities": json.dumps({c: round(float(p), 4)
                                         for c, p in event.probabilities.items()}),
            "out_of_range": bool(event.out_of_range), "peak_score": _num(event.peak_score),
            "link": None if peak is None else peak.link,
            "point_x_m": None if point is None else _num(point[0]),
            "point_y_m": None if point is None else _num(point[1]),
            "point_z_m": None if point is None else _num(point[2]),
            "force_x_n": None if force is None else _num(force[0]),
            "force_y_n": None if force is None else _num(force[1]),
            "force_z_n": None if force is None else _num(force[2]),
            "force_n": None if force is None else _num(np.linalg.norm(force)),
        })
    return rows


EVENT_SCHEMA = pa.schema([
    ("session_id", pa.string()), ("event", pa.int64()), ("onset_s", pa.float64()),
    ("decision_s", pa.float64()), ("release_s", pa.float64()), ("label", pa.string()),
    ("correct", pa.bool_()), ("probabilities", pa.string()), ("out_of_range", pa.bool_()),
    ("peak_score", pa.float64()), ("link", pa.int64()), ("point_x_m", pa.float64()),
    ("point_y_m", pa.float64()), ("point_z_m", pa.float64()), ("force_x_n", pa.float64()),
    ("force_y_n", pa.float64()), ("force_z_n", pa.float64()), ("force_n", pa.float64()),
])
"""The ``events`` table; the recordings' ``events`` properties hold the same fields."""

SESSION_SCHEMA = pa.schema([
    ("session_id", pa.string()), ("file", pa.string()), ("recording", pa.string()),
    ("robot", pa.string()), ("with_hand", pa.bool_()), ("pose", pa.string()),
    ("condition", pa.string()), ("action", pa.string()), ("link", pa.int64()),
    ("planned_at_s", pa.float64()), ("operator", pa.string()),
    ("contact_start_s", pa.float64()), ("contact_end_s", pa.float64()),
    ("model", pa.string()), ("model_sha256", pa.string()), ("dynamics", pa.string()),
    ("offline_label", pa.string()), ("offline_probabilities", pa.string()),
    ("correct", pa.bool_()), ("n_events", pa.int64()), ("n_misclassified", pa.int64()),
    ("agreement_min_correlation", pa.float64()),
    ("agreement_max_rms_difference_nm", pa.float64()), ("agreement", pa.string()),
])
"""The ``sessions`` table; the recordings' ``catalog`` and ``result`` properties hold its
columns from ``model`` on."""


def session_row(job: CatalogJob, stream: ReplayStream, summary: ReplaySummary,
                n_misclassified: int) -> dict:
    """Return a session's row of the ``sessions`` table (see :data:`SESSION_SCHEMA`)."""
    meta = stream.meta
    answer = summary.offline
    agreement = summary.agreement
    correlations = [c for c in (agreement or {}).get("correlation", []) if c is not None]
    differences = [d for d in (agreement or {}).get("rms_difference_nm", []) if d is not None]
    span = summary.contact_span
    dynamics = job.identity.get("dynamics")
    return {
        "session_id": meta.session_id, "file": job.file, "recording": job.target.name,
        "robot": meta.robot, "with_hand": meta.with_hand, "pose": meta.pose,
        "condition": meta.condition, "action": meta.action, "link": meta.link,
        "planned_at_s": _num(meta.planned_at_s), "operator": meta.operator,
        "contact_start_s": None if span is None else span[0],
        "contact_end_s": None if span is None else span[1],
        "model": job.identity["model"]["name"], "model_sha256": job.identity["model"]["sha256"],
        "dynamics": None if dynamics is None else json.dumps(dynamics, sort_keys=True),
        "offline_label": None if answer is None else answer.label,
        "offline_probabilities": None if answer is None else json.dumps(
            {c: round(float(p), 4) for c, p in zip(stream.classes, answer.probabilities,
                                                   strict=True)}),
        "correct": None if answer is None else answer.label == meta.action,
        "n_events": None if summary.events is None else len(summary.events),
        "n_misclassified": None if summary.events is None else n_misclassified,
        "agreement_min_correlation": min(correlations) if correlations else None,
        "agreement_max_rms_difference_nm": max(differences) if differences else None,
        "agreement": None if agreement is None else json.dumps(agreement),
    }


def recording_properties(session: Mapping[str, Any], events: list[dict]
                         ) -> dict[str, dict[str, Any]]:
    """Return the ``catalog``, ``result`` and ``events`` recording properties of a
    session's row and its event rows (nulls left out; the event fields as typed lists,
    one entry per event)."""
    catalog = {k: session[k] for k in ("model", "model_sha256", "dynamics")}
    result = {k: session[k] for k in (
        "contact_start_s", "contact_end_s", "offline_label", "offline_probabilities",
        "correct", "n_events", "n_misclassified", "agreement_min_correlation",
        "agreement_max_rms_difference_nm", "agreement")}
    properties = {"catalog": {k: v for k, v in catalog.items() if v is not None},
                  "result": {k: v for k, v in result.items() if v is not None}}
    if events:
        properties["events"] = {
            f.name: pa.array([row[f.name] for row in events], f.type)
            for f in EVENT_SCHEMA if f.name != "session_id"}
    return properties


def replay_into_catalog(job: CatalogJob) -> tuple[str, dict | None, str | None]:
    """Replay one session into its recording with the catalog's properties; return
    ``(file, {"session": row, "events": rows}, None)``, or ``(file, None, problem)`` for
    a session that cannot be replayed (no recording is left behind)."""
    rows: dict[str, Any] = {}

    def properties(stream: ReplayStream, summary: ReplaySummary) -> dict[str, dict]:
        events = event_rows(stream.meta.session_id, stream.meta.action, summary.events or [])
        session = session_row(job, stream, summary, sum(not e["correct"] for e in events))
        rows.update(session=session, events=events)
        return recording_properties(session, events)

    try:
        replay_session(job.path, _model(job.model_path), save=job.target, robot=job.robot,
                       overwrite=True, session_file=job.file, properties=properties)
    except DATA_ERRORS as err:
        return job.file, None, problem_text(err)
    return job.file, rows, None


def _owned_table(path: Path) -> bool:
    """Whether ``path`` is one of the catalog's Parquet tables (schema metadata)."""
    return TABLE_MARK in (pq.read_schema(path).metadata or {})


def write_table(path: Path, rows: list[dict], schema: pa.Schema) -> Path:
    """Write ``rows`` as a Parquet table of ``schema`` (marked as the catalog's)
    atomically; a file of that name that is not the catalog's own is refused."""
    table = pa.Table.from_pylist(rows, schema=schema.with_metadata({TABLE_MARK: b"1"}))
    with atomic_write(path, owned=_owned_table, suffix=".parquet") as tmp:
        pq.write_table(table, tmp.file)
    return path


def read_table(path: Path) -> list[dict]:
    """Return the rows of one of the catalog's tables ([] when it does not exist)."""
    # ParquetFile, not read_table: that one imports pyarrow.dataset (a second, here)
    return pq.ParquetFile(path).read().to_pylist() if path.is_file() else []


def read_manifest(out: Path) -> dict | None:
    """Return a catalog's manifest, None where there is none; raise InputError when the
    file is not one."""
    path = out / TABLES / MANIFEST
    if not path.exists():
        return None
    if not owned_result(path):
        raise InputError("is not a catalog manifest contactkit wrote", path)
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise InputError(f"unreadable catalog manifest ({err})", path) from err


def dataset_sessions(dataset: Path) -> tuple[dict[str, tuple[Path, str]], list[tuple[str, str]]]:
    """Return {session id: (path, file relative to ``dataset``)} of a dataset's sessions
    and the files whose metadata cannot be read, as ``(file, problem)``; raise InputError
    when two files hold one session (they would be one segment) or there is no session
    file."""
    dataset = Path(dataset)
    found: dict[str, tuple[Path, str]] = {}
    unreadable = []
    paths = session_files(dataset)
    if not paths:
        raise InputError("no session files in the dataset", dataset)
    for path in paths:
        rel = path.relative_to(dataset).as_posix()
        try:
            meta, _ = read_session_meta(path)
        except DATA_ERRORS as err:
            unreadable.append((rel, problem_text(err)))
            continue
        if meta.session_id in found:
            raise InputError(f"session {meta.session_id} is in two files, "
                             f"{found[meta.session_id][1]} and {rel}; a catalog holds one "
                             "recording per session: remove one", dataset)
        found[meta.session_id] = (path, rel)
    return found, unreadable


def _ours(out: Path, entry: Mapping[str, Any]) -> bool:
    """Whether the recording of a manifest entry is still the file the catalog wrote."""
    path = out / entry["recording"]
    if path.is_symlink() or not path.is_file():
        return False
    with open(path, "rb") as fh:
        if fh.read(len(RRD_MAGIC)) != RRD_MAGIC:
            return False
    # the size, not the modification time: a copied catalog (cp -r) stays the catalog's
    return path.stat().st_size == entry["size"]


def check_catalog(out: Path, identity: CatalogIdentity, *, overwrite: bool = False
                  ) -> dict:
    """Check that ``out`` may hold this catalog; return its manifest's sessions (empty
    for a new catalog, or with ``overwrite`` one built with another identity: all are
    replayed).

    Raises InputError (one line) when a ``.rrd`` in ``out`` is not a recording the
    catalog wrote, and, unless ``overwrite``, when the catalog was built with another
    model, dynamics or format."""
    manifest = read_manifest(out)
    sessions = {} if manifest is None else dict(manifest.get("sessions", {}))
    written = {entry["recording"] for entry in sessions.values()}
    for path in sorted(out.glob("*.rrd")) if out.is_dir() else []:
        if path.name.startswith("."):  # a writer's temporary (see contactkit.util.atomic)
            continue
        if path.name not in written or not _ours(out, sessions[path.stem]):
            raise InputError("is not a recording this catalog wrote; the catalog server "
                             "would serve it as a session: move it out of the catalog "
                             "folder", path)
    if manifest is None:
        return {}
    built = manifest.get("identity") or {}
    same = (manifest.get("format") == FORMAT  # the model by its bytes; its name is a label
            and (built.get("model") or {}).get("sha256") == identity.model["sha256"]
            and built.get("dynamics") == identity.dynamics)
    if not same:
        if not overwrite:
            model = (built.get("model") or {}).get("name", "?")
            raise InputError(f"the catalog was built with another model or dynamics "
                             f"(model {model}, dynamics {built.get('dynamics')}); pass "
                             "--overwrite to rebuild it", out)
        return {sid: entry | {"sha256": None} for sid, entry in sessions.items()}
    return sessions


def check_inputs(dataset: Path, out: Path, identity: CatalogIdentity, *,
                 overwrite: bool = False
                 ) -> tuple[dict[str, tuple[Path, str]], list[tuple[str, str]], dict]:
    """Check a catalog's inputs before any work (what :func:`build_catalog` checks
    first); return the dataset's sessions, its unreadable files and the catalog's
    manifest entries (:func:`dataset_sessions`, :func:`check_catalog`). Raises
    InputError (one line) as those do, and when ``out`` is the dataset itself."""
    if Path(out).resolve() == Path(dataset).resolve():
        raise InputError("the catalog folder cannot be the dataset itself: give another --out",
                         out)
    found, unreadable = dataset_sessions(dataset)
    return found, unreadable, check_catalog(out, identity, overwrite=overwrite)


def build_catalog(dataset: Path, out: Path, model_path: Path, identity: CatalogIdentity, *,
                  workers: int = 1, overwrite: bool = False, robot: RobotChoice = None,
                  scheduler: str | None = None, progress: ProgressCallback | None = None,
                  on_done: Callable[[str, str | None], None] | None = None
                  ) -> CatalogResult:
    """Build or update the catalog of ``dataset`` in ``out`` (see the module docstring);
    return what was done.

    Sessions are replayed in parallel (``workers`` local processes, or the Dask
    ``scheduler``), each with the model at ``model_path`` (``identity`` names it),
    ``robot`` overriding the sessions' arm. Memory stays bounded: each job returns one
    row per session and event. A session that fails is listed in the result and leaves
    no recording; the others are written. ``on_done(file, problem)`` is called after
    each replayed session. Raises InputError before any work on two files of one
    session, a foreign ``.rrd`` in ``out``, or a catalog of another identity (unless
    ``overwrite``)."""
    dataset, out = Path(dataset), Path(out)
    found, unreadable, previous = check_inputs(dataset, out, identity, overwrite=overwrite)
    output_directory(out)
    output_directory(out / TABLES)
    result = CatalogResult(out, failed=list(unreadable))
    hashes = {sid: file_sha256(path) for sid, (path, _) in found.items()}
    manifest_sessions = {sid: entry for sid, entry in previous.items()
                         if sid in found and entry.get("sha256") == hashes[sid]
                         and entry.get("file") == found[sid][1] and _ours(out, entry)}
    for sid, entry in previous.items():
        if sid not in found and _ours(out, entry):
            (out / entry["recording"]).unlink()
            result.removed.append(sid)
    old_sessions = {r["session_id"]: r for r in read_table(out / TABLES / SESSIONS)}
    old_events: dict[str, list[dict]] = {}
    for row in read_table(out / TABLES / EVENTS):
        old_events.setdefault(row["session_id"], []).append(row)
    sessions = {sid: old_sessions[sid] for sid in manifest_sessions if sid in old_sessions}
    events = {sid: old_events.get(sid, []) for sid in sessions}
    todo = [sid for sid in found if sid not in sessions]
    result.kept = sorted(sessions)
    # the recordings still to be replaced stay listed (to be replayed) until they are, so
    # that a build killed before then does not leave recordings its manifest disowns
    manifest_sessions = {sid: manifest_sessions[sid] for sid in sessions} | {
        sid: previous[sid] | {"sha256": None} for sid in todo
        if sid in previous and _ours(out, previous[sid])}
    jobs = [CatalogJob(found[sid][0], found[sid][1], out / recording_name(sid), model_path,
                       identity.to_dict(), robot) for sid in todo]

    def save_manifest() -> None:
        write_text(out / TABLES / MANIFEST, json.dumps(result_json(
            {"format": FORMAT, "identity": identity.to_dict(), "dataset": str(dataset),
             "sessions": manifest_sessions}), indent=1), owned=owned_result)

    save_manifest()
    for sid, (file, rows, problem) in zip(
            todo, map_ordered(replay_into_catalog, jobs, workers=workers, progress=progress,
                              scheduler=scheduler), strict=True):
        if problem is not None:
            result.failed.append((file, problem))
            stale = manifest_sessions.pop(sid, None)
            if stale is not None and _ours(out, stale):  # of the file before it changed
                (out / stale["recording"]).unlink()
        else:
            assert rows is not None  # a session without a problem has its rows
            sessions[sid], events[sid] = rows["session"], rows["events"]
            target = out / recording_name(sid)
            manifest_sessions[sid] = {"file": file, "sha256": hashes[sid],
                                      "recording": target.name,
                                      "size": target.stat().st_size}
            result.replayed.append(sid)
        save_manifest()  # after every session: a killed build keeps what it finished
        if on_done is not None:
            on_done(file, problem)
    order = [sid for sid in found if sid in sessions]
    write_table(out / TABLES / SESSIONS, [sessions[sid] for sid in order], SESSION_SCHEMA)
    write_table(out / TABLES / EVENTS, [row for sid in order for row in events[sid]],
                EVENT_SCHEMA)
    return result


def catalog_tables(out: Path) -> dict[str, Path]:
    """Return {table name: Parquet file} of a catalog; raise InputError when ``out`` is
    not one (no manifest or tables)."""
    out = Path(out)
    tables = {"sessions": out / TABLES / SESSIONS, "events": out / TABLES / EVENTS}
    if read_manifest(out) is None or not all(p.is_file() for p in tables.values()):
        raise InputError("is not a catalog (no tables/manifest.json and tables): build one "
                         "with `recorder catalog DATASET --out DIR`", out)
    return tables


def is_catalog(path: Path) -> bool:
    """Whether ``path`` is a catalog folder (it has a manifest), not a dataset."""
    return (Path(path) / TABLES / MANIFEST).is_file()

