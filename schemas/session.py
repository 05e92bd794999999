"""Session file format v1: one Parquet file per recording.

Columns (flat, so Polars, DuckDB, pandas and PlotJuggler open the file directly;
joints are numbered 1..7 as in the thesis):

=====================  =========  =====================================================
column                 unit       meaning
=====================  =========  =====================================================
``t``                  s          time since session start, strictly increasing
``q_1..q_7``           rad        measured joint positions
``dq_1..dq_7``         rad/s      measured joint velocities
``tau_1..tau_7``       Nm         measured link-side joint torque, gravity included
                                  (libfranka's ``tau_J``)
``q_d_1..q_d_7``       rad        optional: commanded joint positions
``dq_d_1..dq_d_7``     rad/s      optional: commanded joint velocities
``tau_ext_hat_1..7``   Nm         optional: the robot's own external-torque estimate
                                  (libfranka ``tau_ext_hat_filtered``; its sign is
                                  opposite to the momentum-observer residual)
``f_ext_x/y/z``        N          optional: ground-truth applied force, world frame
``contact``            bool       optional: ground truth, a person is touching the arm
``f_ext_hat_x/y/z``    N          optional: the robot's own estimate of the external
``m_ext_hat_x/y/z``    Nm         wrench at the stiffness frame, base frame (libfranka
                                  ``O_F_ext_hat_K``)
``robot_mode``         int8       optional: libfranka ``RobotMode`` (0 other, 1 idle,
                                  2 move, 3 guiding, 4 reflex, 5 user stopped, 6
                                  automatic error recovery)
``command_success_rate`` 1        optional: libfranka ``control_command_success_rate``
=====================  =========  =====================================================

The Parquet key-value metadata holds one JSON document under the key
``contactkit.session``: the :class:`SessionMeta` fields, including
``schema_version``.
"""

from __future__ import annotations

import json
import math
import re
import uuid
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.errors import InputError, input_error_about
from contactkit.robots import (
    DEFAULT_ROBOT,
    URDF_PREFIX,
    RobotSetup,
    canonical_robot_name,
    get_robot,
)
from contactkit.util.atomic import Owned, atomic_write, check_target

SCHEMA_VERSION = 1
N_JOINTS = 7
METADATA_KEY = b"contactkit.session"
ACTIONS = ("none", "bump", "adjust", "shove")
CONDITIONS = ("static", "dynamic")


def joint_columns(prefix: str, n: int = N_JOINTS) -> list[str]:
    """Return the column names ``prefix_1 .. prefix_n`` (joints numbered from 1)."""
    return [f"{prefix}_{i}" for i in range(1, n + 1)]


REQUIRED_JOINT_PREFIXES = ("q", "dq", "tau")
OPTIONAL_JOINT_PREFIXES = ("q_d", "dq_d", "tau_ext_hat")
FORCE_COLUMNS = ("f_ext_x", "f_ext_y", "f_ext_z")
WRENCH_HAT_COLUMNS = ("f_ext_hat_x", "f_ext_hat_y", "f_ext_hat_z", "m_ext_hat_x", "m_ext_hat_y",
                      "m_ext_hat_z")
REQUIRED_COLUMNS = ["t", *[c for p in REQUIRED_JOINT_PREFIXES for c in joint_columns(p)]]
OPTIONAL_FLOAT_COLUMNS = [
    *[c for p in OPTIONAL_JOINT_PREFIXES for c in joint_columns(p)],
    *FORCE_COLUMNS,
    *WRENCH_HAT_COLUMNS,
    "command_success_rate",
]
OPTIONAL_COLUMNS = [*OPTIONAL_FLOAT_COLUMNS, "contact", "robot_mode"]
COLUMN_ORDER = REQUIRED_COLUMNS + OPTIONAL_COLUMNS
ALL_JOINT_PREFIXES = REQUIRED_JOINT_PREFIXES + OPTIONAL_JOINT_PREFIXES


def column_type(name: str) -> pa.DataType:
    """Return the Arrow type of a session column (``contact`` is bool, ``robot_mode`` int8,
    the rest float64)."""
    if name == "contact":
        return pa.bool_()
    return pa.int8() if name == "robot_mode" else pa.float64()


def session_schema(columns: Iterable[str], meta: SessionMeta | None = None) -> pa.Schema:
    """Return the Arrow schema for the given session columns, in canonical order."""
    wanted = set(columns)
    unknown = wanted - set(COLUMN_ORDER)
    if unknown:
        raise InputError(f"unexpected column {sorted(unknown)[0]!r}")
    schema = pa.schema([pa.field(c, column_type(c), nullable=False) for c in COLUMN_ORDER
                        if c in wanted])
    if meta is not None:
        schema = schema.with_metadata({METADATA_KEY: meta.to_json().encode()})
    return schema


@dataclass
class SessionMeta:
    """Metadata of one session (the JSON document in the Parquet key-value metadata).

    Angles are in rad, speeds in rad/s, times in s, rates in Hz.
    """

    session_id: str
    source: str
    action: str
    condition: str = "static"
    pose: str | None = None
    pose_q: list[float] | None = None
    target_pose: str | None = None
    target_q: list[float] | None = None
    speed_rad_s: float | None = None
    link: int | None = None
    planned_at_s: float | None = None
    nominal_rate_hz: float | None = None
    operator: str = ""
    notes: str = ""
    created_utc: str = ""
    robot: str = DEFAULT_ROBOT
    """The arm's registry name (:mod:`contactkit.robots`): ``panda``, ``fr3``, a plugin's
    name or ``urdf:PATH``; sessions written before robots were chosen say
    ``franka_panda``, read as ``panda``."""
    with_hand: bool = True
    payload_kg: float = 0.0
    """Mass on the flange besides the hand [kg] (libfranka's configured load)."""
    payload_com_m: list[float] | None = None
    """The payload's centre of mass in the flange frame [m]."""
    urdf_sha256: str = ""
    simulator: dict[str, Any] | None = None
    source_info: dict[str, Any] = field(default_factory=dict)
    recovered: bool = False
    recovered_samples: int | None = None
    events: list[dict[str, Any]] | None = None
    """Contact events found while recording (a live event pipeline), one dict each."""
    residual_agreement: dict[str, Any] | None = None
    """For a session with the robot's own estimate (``tau_ext_hat``): how well the
    observer residual agreed with it, measured at import or capture
    (:mod:`contactkit.features.agreement`)."""
    tool_version: str = ""
    schema_version: int = SCHEMA_VERSION

    def to_json(self) -> str:
        """Return the metadata as one compact JSON document."""
        return json.dumps(asdict(self), sort_keys=True, separators=(",", ":"))

    def robot_setup(self, path: str | Path | None = None) -> RobotSetup:
        """Return the arm this session was recorded on (robot, hand, payload).

        Raises :class:`InputError` naming ``path`` for an unknown robot, and for a
        ``urdf:PATH`` robot whose file's SHA-256 differs from the one stored.
        """
        try:
            name = canonical_robot_name(self.robot)
            if name.startswith(URDF_PREFIX) and self.urdf_sha256:
                found = get_robot(name).urdf_sha256(self.with_hand)
                if found != self.urdf_sha256:
                    raise InputError(f"the URDF at {name[len(URDF_PREFIX):]} is not the one "
                                     f"the session was recorded with (SHA-256 {found[:12]}, "
                                     f"stored {self.urdf_sha256[:12]}); pass --robot to "
                                     "choose the model")
        except InputError as err:
            raise input_error_about(err, path) from err
        com = self.payload_com_m or (0.0, 0.0, 0.0)
        return RobotSetup(robot=name, with_hand=self.with_hand,
                          payload_kg=float(self.payload_kg),
                          payload_com_m=(float(com[0]), float(com[1]), float(com[2])))

    def with_robot(self, robot: str | None) -> SessionMeta:
        """Return a copy that names ``robot`` (the session's own when None), with the
        URDF hash of that robot's model: how ``--robot`` overrides a session's arm."""
        if robot is None:
            return self
        name = canonical_robot_name(robot)
        return replace(self, robot=name,
                       urdf_sha256=get_robot(name).urdf_sha256(self.with_hand))

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any], path: str | Path | None = None) -> SessionMeta:
        """Build and check metadata from a parsed JSON document.

        Raises :class:`InputError` naming ``path`` on a missing or wrong field.
        """
        if not isinstance(doc, Mapping):
            raise InputError("session metadata is not a JSON object", path)
        version = doc.get("schema_version")
        if version != SCHEMA_VERSION:
            raise InputError(f"unknown schema version {version!r} (this tool reads "
                             f"version {SCHEMA_VERSION})", path)
        known = {f.name for f in fields(cls)}
        for required in ("session_id", "source", "action"):
            if required not in doc:
                raise InputError(f"session metadata lacks {required!r}", path)
        meta = cls(**{k: v for k, v in doc.items() if k in known})
        meta.check(path)
        return meta

    def check(self, path: str | Path | None = None) -> None:
        """Raise :class:`InputError` when a field holds a value outside its domain.

        Domains: action and condition from their lists; pose names A-H or a safe name
        (they become file-name parts); links 1..7; joint vectors of 7 finite numbers;
        times [s] finite and within :data:`MAX_SESSION_S`; rates and speeds finite and
        positive; text fields strings; flags booleans.
        """
        for name, kinds in _FIELD_TYPES.items():
            value = getattr(self, name)
            if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
                raise InputError(f"metadata {name} has the wrong type "
                                 f"({type(value).__name__}: {_short(value)})", path)
        try:
            canonical_robot_name(self.robot)
        except InputError as err:
            raise InputError(f"metadata {err.problem}", path) from err
        if not (_finite(self.payload_kg) and 0.0 <= self.payload_kg <= MAX_PAYLOAD_KG):
            raise InputError(f"metadata payload_kg {_short(self.payload_kg)} is outside "
                             f"0..{MAX_PAYLOAD_KG:g} kg", path)
        com = self.payload_com_m
        if com is not None and (len(com) != 3 or not all(
                _finite(v) and abs(v) <= 1.0 for v in com)):
            raise InputError("metadata payload_com_m is not 3 coordinates within 1 m", path)
        if self.action not in ACTIONS:
            raise InputError(f"unknown action {_short(self.action)} (expected one of "
                             f"{', '.join(ACTIONS)})", path)
        if self.condition not in CONDITIONS:
            raise InputError(f"unknown condition {_short(self.condition)} (expected static or "
                             "dynamic)", path)
        if not SESSION_ID.fullmatch(self.session_id):
            raise InputError(f"metadata session_id {_short(self.session_id)} is not 1-64 "
                             "letters, digits, '_' or '-'", path)
        for name in ("pose", "target_pose"):
            value = getattr(self, name)
            if value is not None and not POSE_NAME.fullmatch(value):
                raise InputError(f"metadata {name} {_short(value)} is not a pose name (A-H, or "
                                 "1-32 letters, digits, '_' or '-')", path)
        for name in ("pose_q", "target_q"):
            value = getattr(self, name)
            if value is not None and (len(value) != N_JOINTS or not all(map(_finite, value))):
                raise InputError(f"metadata {name} is not {N_JOINTS} finite joint angles "
                                 "[rad]", path)
        if self.link is not None and not 1 <= self.link <= N_JOINTS:
            raise InputError(f"metadata link {self.link} is not a link 1..{N_JOINTS}", path)
        for name, low, high in _BOUNDS:
            value = getattr(self, name)
            if value is not None and not (_finite(value) and low <= value <= high):
                raise InputError(f"metadata {name} {value!r} is outside {low:g}..{high:g}",
                                 path)
        if self.recovered_samples is not None and self.recovered_samples < 0:
            raise InputError(f"metadata recovered_samples {self.recovered_samples} is "
                             "negative", path)
        incomplete = self.source_info.get("incomplete_samples", 0)
        if not (_finite(incomplete) and float(incomplete).is_integer() and incomplete >= 0):
            raise InputError(f"metadata source_info.incomplete_samples {_short(incomplete)} "
                             "is not a count", path)
        _check_true_contact(self.simulator, path)


MAX_CONTACT_POINT_M = 10.0
"""Farthest a simulated contact point may lie from its link's frame [m]."""


def _check_true_contact(simulator: Mapping[str, Any] | None,
                        path: str | Path | None) -> None:
    """Raise :class:`InputError` unless the simulated contact that replay draws
    (``simulator.session.contact``) is absent or a link 1..7 with a point of 3 finite
    coordinates [m] in its frame."""
    session = (simulator or {}).get("session")
    contact = session.get("contact") if isinstance(session, Mapping) else None
    if session is not None and not isinstance(session, Mapping):
        raise InputError(f"metadata simulator.session has the wrong type "
                         f"({type(session).__name__}: {_short(session)})", path)
    if contact is None:
        return
    link = contact.get("link") if isinstance(contact, Mapping) else None
    point = contact.get("point_local") if isinstance(contact, Mapping) else None
    if not (isinstance(link, int) and not isinstance(link, bool) and 1 <= link <= N_JOINTS
            and isinstance(point, (list, tuple)) and len(point) == 3
            and all(_finite(v) and abs(v) <= MAX_CONTACT_POINT_M for v in point)):
        raise InputError(f"metadata simulator.session.contact {_short(contact)} is not a "
                         f"link 1..{N_JOINTS} with a point_local of 3 coordinates within "
                         f"{MAX_CONTACT_POINT_M:g} m", path)


MAX_PAYLOAD_KG = 100.0
"""Heaviest payload [kg] the metadata may describe."""
MAX_SESSION_S = 86_400.0
"""Longest session [s] the metadata may describe (one day): bounds planned times."""
SESSION_ID = re.compile(r"[A-Za-z0-9_-]{1,64}")
POSE_NAME = re.compile(r"[A-Za-z0-9_-]{1,32}")
_NUMBER = (int, float)
_OPTIONAL_NUMBER = (int, float, type(None))
_FIELD_TYPES: dict[str, tuple[type, ...]] = {
    "session_id": (str,), "source": (str,), "action": (str,), "condition": (str,),
    "pose": (str, type(None)), "target_pose": (str, type(None)),
    "pose_q": (list, type(None)), "target_q": (list, type(None)),
    "speed_rad_s": _OPTIONAL_NUMBER, "link": (int, type(None)),
    "planned_at_s": _OPTIONAL_NUMBER, "nominal_rate_hz": _OPTIONAL_NUMBER,
    "operator": (str,), "notes": (str,), "created_utc": (str,), "robot": (str,),
    "with_hand": (bool,), "payload_kg": _NUMBER, "payload_com_m": (list, type(None)),
    "urdf_sha256": (str,), "simulator": (dict, type(None)),
    "source_info": (dict,), "recovered": (bool,), "recovered_samples": (int, type(None)),
    "events": (list, type(None)), "residual_agreement": (dict, type(None)),
    "tool_version": (str,), "schema_version": (int,),
}
_BOUNDS = (("planned_at_s", 0.0, MAX_SESSION_S), ("speed_rad_s", 1e-6, 100.0),
           ("nominal_rate_hz", 1e-3, 1e6))


def _is_number(value: object) -> bool:
    return isinstance(value, _NUMBER) and not isinstance(value, bool)


def _finite(value: object) -> bool:
    """Return whether ``value`` is a finite number (a huge int counts as infinite)."""
    try:
        return _is_number(value) and math.isfinite(value)
    except OverflowError:
        return False


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def column_array(column: pa.ChunkedArray) -> np.ndarray:
    """Return a null-free float64 or boolean column as numpy, as ``column.to_numpy()``
    does (zero-copy and read-only for one chunk, a copy for several) but without
    pyarrow's pandas bridge: ``to_numpy`` imports pandas (pyarrow 26; about 60 MB and
    half a second of start-up for ``recorder info``)."""
    chunks = [_chunk_array(chunk) for chunk in column.chunks]
    if len(chunks) == 1:
        return chunks[0]
    if not chunks:
        return np.zeros(0, dtype=bool if pa.types.is_boolean(column.type) else float)
    return np.concatenate(chunks)


def _chunk_array(chunk: pa.Array) -> np.ndarray:
    if pa.types.is_boolean(chunk.type):  # bit-packed, least significant bit first
        if not len(chunk):
            return np.zeros(0, dtype=bool)
        bits = np.unpackbits(np.frombuffer(chunk.buffers()[1], np.uint8), bitorder="little")
        return bits[chunk.offset:chunk.offset + len(chunk)].astype(bool)
    return np.from_dlpack(chunk)


@dataclass
class Session:
    """A validated session: its metadata and its columns as an Arrow table."""

    meta: SessionMeta
    table: pa.Table
    path: Path | None = None

    def column(self, name: str) -> np.ndarray:
        """Return one column as a numpy array (float64, or bool for ``contact``)."""
        return column_array(self.table.column(name))

    def joints(self, prefix: str) -> np.ndarray:
        """Return the 7 columns ``prefix_1..prefix_7`` as an (N, 7) float64 array."""
        return np.column_stack([self.column(c) for c in joint_columns(prefix)])

    def has(self, name: str) -> bool:
        """Return whether the session has the column (optional columns may be absent)."""
        return name in self.table.column_names

    @property
    def t(self) -> np.ndarray:
        """Time stamps [s] since session start, shape (N,)."""
        return self.column("t")

    @property
    def q(self) -> np.ndarray:
        """Joint positions [rad], shape (N, 7)."""
        return self.joints("q")

    @property
    def dq(self) -> np.ndarray:
        """Joint velocities [rad/s], shape (N, 7)."""
        return self.joints("dq")

    @property
    def tau(self) -> np.ndarray:
        """Measured joint torques [Nm], gravity included, shape (N, 7)."""
        return self.joints("tau")

    def complete(self) -> Session:
        """Return the session without samples that lack a joint value (NaN gaps left by a
        CAN source); the feature chain treats the gap as one longer time step."""
        table = complete_table(self.table)
        if table is self.table:
            return self
        if table.num_rows == 0:
            raise InputError(f"no complete sample: each of the {self.table.num_rows} samples "
                             "lacks a joint value", self.path)
        return Session(meta=self.meta, table=table, path=self.path)

    @property
    def n_samples(self) -> int:
        """Number of samples (rows)."""
        return self.table.num_rows

    @property
    def duration_s(self) -> float:
        """Time between the first and last sample [s] (0 for fewer than two samples)."""
        t = self.t
        return float(t[-1] - t[0]) if len(t) > 1 else 0.0


def complete_table(table: pa.Table) -> pa.Table:
    """Return the rows of a session table (or of a chunk of one) that have every joint
    value (q, dq, tau); the table itself when none is missing."""
    keep = np.ones(table.num_rows, dtype=bool)
    for prefix in ("q", "dq", "tau"):
        for name in joint_columns(prefix):
            keep &= np.isfinite(column_array(table.column(name)))
    if keep.all():
        return table
    return table.filter(pa.array(keep))


def new_session_id() -> str:
    """Return a fresh random session id (32 hex digits)."""
    return uuid.uuid4().hex


def table_from_columns(columns: Mapping[str, np.ndarray], meta: SessionMeta) -> pa.Table:
    """Build a session table (canonical column order, metadata attached) from arrays."""
    schema = session_schema(columns.keys(), meta)
    arrays = [pa.array(np.asarray(columns[f.name]), type=f.type) for f in schema]
    return pa.Table.from_arrays(arrays, schema=schema)


def write_session(path: str | Path, columns: Mapping[str, np.ndarray] | pa.Table,
                  meta: SessionMeta, *, overwrite: bool = False) -> Path:
    """Validate and write a session atomically; return the written path.

    The data go to a temporary file in the same directory, are flushed to disk and
    then linked into place, so a reader never sees a half-written file. An existing
    file is left untouched (``InputError``) unless ``overwrite`` is true.
    """
    path = Path(path)
    meta.check(path)
    if isinstance(columns, pa.Table):
        table = table_from_columns({n: columns.column(n).to_numpy() for n in columns.column_names},
                                   meta)
    else:
        table = table_from_columns(columns, meta)
    validate_table(table, path, allows_gaps(meta))
    check_target(path, overwrite=overwrite)
    atomic_write_parquet(table, path, overwrite=overwrite)
    return path


def atomic_write_parquet(table: pa.Table, path: Path, *, overwrite: bool,
                         owned: Owned | None = None) -> None:
    """Write ``table`` to ``path`` with :func:`contactkit.util.atomic.atomic_write`
    (``overwrite`` and ``owned`` are its overwrite policy)."""
    with atomic_write(path, overwrite=overwrite, owned=owned) as tmp:
        pq.write_table(table, tmp.file, compression="zstd")


def read_session_meta(path: str | Path) -> tuple[SessionMeta, pq.FileMetaData]:
    """Read only the metadata of a session file (its Parquet footer).

    Returns the session metadata and the Parquet file metadata (row count, column
    statistics). Raises :class:`InputError` on a foreign or corrupt file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    try:
        footer = pq.read_metadata(path)
    except (pa.ArrowInvalid, OSError) as err:
        raise InputError(f"not a readable Parquet file ({_first_line(err)})", path) from err
    kv = footer.metadata or {}
    if METADATA_KEY not in kv:
        raise InputError("no contactkit session metadata (not a contactkit session file)", path)
    try:
        doc = json.loads(kv[METADATA_KEY])
    except (ValueError, RecursionError) as err:
        raise InputError(f"session metadata is not valid JSON ({_first_line(err)})",
                         path) from err
    return SessionMeta.from_dict(doc, path), footer


def validate_session(path: str | Path) -> Session:
    """Read and fully validate a session file; return it.

    Raises :class:`InputError` naming the file and the first problem found: not
    Parquet, missing metadata, unknown schema version, missing or unexpected
    column, wrong joint count, wrong type, NaN/inf, non-increasing ``t``.
    """
    path = Path(path)
    meta, _ = read_session_meta(path)
    try:
        # ParquetFile, not pq.read_table: that one goes through pyarrow.dataset, whose
        # import loads pandas (a second of start-up for `recorder info`)
        with pq.ParquetFile(path) as file:
            table = file.read()
    except (pa.ArrowInvalid, OSError) as err:
        raise InputError(f"cannot read the Parquet data ({_first_line(err)})", path) from err
    validate_table(table, path, allows_gaps(meta))
    return Session(meta=meta, table=table, path=path)


read_session = validate_session


def allows_gaps(meta: SessionMeta) -> bool:
    """Return whether a session may hold NaN joint values: only when its source
    reported incomplete samples (a CAN frame that never came)."""
    return int(meta.source_info.get("incomplete_samples", 0) or 0) > 0


def validate_table(table: pa.Table, path: str | Path | None = None,
                   gaps_allowed: bool = False) -> None:
    """Check a session table's columns, types and values; raise :class:`InputError`.

    NaN is accepted in q, dq and tau only with ``gaps_allowed``; ``t`` must always be
    finite and strictly increasing.
    """
    names = table.column_names
    _check_joint_count(names, path)
    for name in REQUIRED_COLUMNS:
        if name not in names:
            raise InputError(f"missing column {name!r}", path)
    for name in names:
        if name not in COLUMN_ORDER:
            raise InputError(f"unexpected column {name!r}", path)
        expected = column_type(name)
        if table.schema.field(name).type != expected:
            raise InputError(f"column {name!r} has type {table.schema.field(name).type}, "
                             f"expected {expected}", path)
        if table.column(name).null_count:
            raise InputError(f"null values in column {name!r}", path)
    gap_columns = set(REQUIRED_COLUMNS[1:]) if gaps_allowed else set()
    for name in (n for n in names if n != "contact"):
        values = column_array(table.column(name))
        bad = np.isinf(values) if name in gap_columns else ~np.isfinite(values)
        if bad.any():
            row = int(np.argmax(bad))
            kind = "NaN" if math.isnan(values[row]) else "infinite value"
            raise InputError(f"{kind} in column {name!r} at row {row}", path)
        bound = hard_limit(name)
        if bound is not None:
            with np.errstate(invalid="ignore"):
                beyond = np.abs(values) > bound
            if beyond.any():
                row = int(np.argmax(beyond))
                raise InputError(f"impossible value {values[row]:.6g} in column {name!r} at "
                                 f"row {row} (beyond the hard limit {bound:g}: a corrupt "
                                 "file or a unit error)", path)
    t = column_array(table.column("t"))
    if len(t) == 0:
        raise InputError("session has no samples", path)
    check_times(t, path)


HARD_LIMITS = {"q": 100.0, "q_d": 100.0, "dq": 1000.0, "dq_d": 1000.0, "tau": 1e4,
               "tau_ext_hat": 1e4, "f_ext": 1e5, "f_ext_hat": 1e5, "m_ext_hat": 1e4}
"""Bounds no robot arm's measurement reaches, per column prefix (q [rad], dq [rad/s],
tau [Nm], forces [N], moments [Nm]): a value beyond one is refused where data enter
and on read, naming the column and row. The session robot's own limits (with a
margin) are far lower; values beyond those are flagged by ``recorder stats --deep``
and refused by the simulator."""


def hard_limit(column: str) -> float | None:
    """Return the hard bound on ``|value|`` of a session column (None: no bound)."""
    prefix = column.rsplit("_", 1)[0]
    return HARD_LIMITS.get(prefix)


MAX_STEP_S = 10.0
"""The longest step between two samples [s] a session may hold. Real recordings step
0.35-8.8 ms (host-stamped FR3 logs 0.35-5 ms, the Gaz log 0.7-8.8 ms, MindLab 5 ms); a
longer step is a time jump (a clock switched from sim time to wall time, a log
restarted, a corrupt stamp), refused where data enter rather than read as one
session of years. Steps above 3x the median but within this bound are gaps, counted
by :func:`contactkit.features.timing.sampling_stats`; after a step longer than
:data:`contactkit.features.timing.RESTART_STEP_S` (0.1 s) the feature chain and the
contact detector restart."""
MAX_ABS_T_S = 1e10
"""The largest time stamp [s] a session may hold (about 300 years; sessions start at
0 s, epoch stamps are 1.7e9 s): larger values overflow time arithmetic."""


def check_times(t: np.ndarray, path: str | Path | None = None, offset: int = 0,
                last_t: float | None = None) -> None:
    """Check the time rule on time stamps ``t`` [s]: finite, within
    :data:`MAX_ABS_T_S`, strictly increasing, no step longer than :data:`MAX_STEP_S`.
    ``last_t`` is the stamp before ``t[0]`` (chunked reading) and ``offset`` the row of
    ``t[0]`` in the file. Raises one :class:`InputError` line naming the row."""
    t = np.asarray(t, dtype=float)
    big = np.abs(t) > MAX_ABS_T_S
    if big.any():
        row = int(np.argmax(big))
        raise InputError(f"time stamp {t[row]:.6g} s at row {offset + row} is beyond "
                         f"{MAX_ABS_T_S:.0e} s", path)
    steps = np.diff(t) if last_t is None else np.diff(t, prepend=last_t)
    first = offset if last_t is None else offset - 1
    if (steps <= 0).any():
        row = int(np.argmax(steps <= 0)) + 1
        before = t[row - 1] if last_t is None else np.r_[last_t, t][row - 1]
        here = t[row] if last_t is None else t[row - 1]
        raise InputError(f"t is not strictly increasing at row {first + row} "
                         f"(t={here:.6f} s after {before:.6f} s)", path)
    if (steps > MAX_STEP_S).any():
        row = int(np.argmax(steps > MAX_STEP_S)) + 1
        raise InputError(f"time jumps by {steps[row - 1]:.6g} s at row {first + row} (more "
                         f"than {MAX_STEP_S:g} s between samples: a clock switch or a "
                         "restarted log; split the recording there)", path)


def _check_joint_count(names: list[str], path: str | Path | None) -> None:
    for prefix in ALL_JOINT_PREFIXES:
        found = sorted(int(n[len(prefix) + 1:]) for n in names
                       if n.startswith(prefix + "_") and n[len(prefix) + 1:].isdigit())
        contiguous = found == list(range(1, len(found) + 1))
        if found and (found[-1] > N_JOINTS or (contiguous and len(found) != N_JOINTS)):
            raise InputError(f"wrong joint count: columns {prefix}_{found[0]}..{prefix}_"
                             f"{found[-1]} ({len(found)} joints), expected {prefix}_1.."
                             f"{prefix}_{N_JOINTS}", path)


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__


ROW_GROUP_ROWS = 65_536
"""Rows per Parquet row group of a session written in chunks (about 65 s at 1 kHz)."""


def iter_session_batches(path: str | Path, batch_rows: int = ROW_GROUP_ROWS,
                         columns: Sequence[str] | None = None) -> Iterator[pa.RecordBatch]:
    """Yield a session file's rows as record batches of at most ``batch_rows`` rows,
    each validated as :func:`validate_session` does, ``t`` increasing across them;
    ``columns`` reads (and validates) only those columns, at least the required ones.

    Memory stays bounded by one batch however long the session is. Raises
    :class:`InputError` naming the file and the problem, on the batch that has it.
    """
    path = Path(path)
    meta, _ = read_session_meta(path)
    gaps = allows_gaps(meta)
    try:
        groups = _group_batches(pq.ParquetFile(path), batch_rows, columns)
        batches = _rebatched(groups, batch_rows)
        offset, last_t = 0, -math.inf
        for batch in batches:
            _validate_chunk(pa.Table.from_batches([batch]), path, gaps, offset, last_t)
            offset += batch.num_rows
            last_t = float(batch.column("t")[-1].as_py())
            yield batch
    except (pa.ArrowInvalid, OSError) as err:
        raise InputError(f"cannot read the Parquet data ({_first_line(err)})", path) from err
    if offset == 0:
        raise InputError("session has no samples", path)


@dataclass(frozen=True)
class SampleBatch:
    """Consecutive samples of a session, each joint quantity stacked (joints 1..7 as
    columns): times ``t`` (n,) [s]; ``q`` [rad], ``dq`` [rad/s], ``tau`` [Nm] (n, 7);
    and the session's optional columns where it has them (None where it has not):
    ``q_d`` [rad], ``dq_d`` [rad/s], ``tau_ext_hat`` [Nm] (n, 7), ``f_ext`` [N]
    (n, 3), ``f_ext_hat`` (n, 6: force [N], then moment [Nm]), ``contact`` (n,) bool,
    ``robot_mode`` (n,) int8 and ``command_success_rate`` (n,). This is what the
    feature chain, the replay, the statistics and the live listeners take."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    q_d: np.ndarray | None = None
    dq_d: np.ndarray | None = None
    tau_ext_hat: np.ndarray | None = None
    f_ext: np.ndarray | None = None
    f_ext_hat: np.ndarray | None = None
    contact: np.ndarray | None = None
    robot_mode: np.ndarray | None = None
    command_success_rate: np.ndarray | None = None

    @classmethod
    def from_columns(cls, columns: pa.Table | pa.RecordBatch | Mapping[str, np.ndarray]
                     ) -> SampleBatch:
        """Return the batch of session columns (a table, a record batch, or a mapping
        of column name to array, as a capture's chunk): ``t`` and every joint column
        of q, dq and tau are required; an optional group is taken where all its
        columns are present."""
        if isinstance(columns, (pa.Table, pa.RecordBatch)):
            names = set(columns.schema.names)

            def get(name: str) -> np.ndarray:
                return columns.column(name).to_numpy(zero_copy_only=False)
        else:
            names = set(columns)

            def get(name: str) -> np.ndarray:
                return np.asarray(columns[name])

        def stacked(group: Sequence[str]) -> np.ndarray | None:
            if not names.issuperset(group):
                return None
            return np.column_stack([get(c) for c in group]).astype(float, copy=False)

        def single(name: str) -> np.ndarray | None:
            return get(name) if name in names else None

        return cls(np.asarray(get("t"), dtype=float),
                   *(stacked(joint_columns(p)) for p in ALL_JOINT_PREFIXES),
                   stacked(FORCE_COLUMNS), stacked(WRENCH_HAT_COLUMNS), single("contact"),
                   single("robot_mode"), single("command_success_rate"))

    def __len__(self) -> int:
        """Return the number of samples."""
        return len(self.t)

    def take(self, rows: np.ndarray | slice) -> SampleBatch:
        """Return the samples ``rows`` (indices, a boolean mask or a slice)."""
        return SampleBatch(**{f.name: None if getattr(self, f.name) is None
                              else getattr(self, f.name)[rows] for f in fields(self)})

    def complete(self) -> SampleBatch:
        """Return the samples that have a time and every joint value (q, dq, tau), as
        :func:`complete_table` keeps them; the batch itself when none is missing."""
        joints = (self.q, self.dq, self.tau)
        if np.isfinite(self.t).all() and all(np.isfinite(x).all() for x in joints):
            return self  # checked as whole arrays: a reduction along rows of 7 costs 10x
        keep = np.isfinite(self.t) & np.isfinite(self.q).all(axis=1) \
            & np.isfinite(self.dq).all(axis=1) & np.isfinite(self.tau).all(axis=1)
        return self.take(keep)


def iter_sample_batches(source: Session | str | Path, batch_rows: int = ROW_GROUP_ROWS,
                        columns: Sequence[str] | None = None) -> Iterator[SampleBatch]:
    """Yield the complete samples (:meth:`SampleBatch.complete`) of a session, a file
    read and validated by :func:`iter_session_batches` or a :class:`Session` in
    memory, as :class:`SampleBatch` of at most ``batch_rows`` rows; batches left empty
    are skipped. ``columns`` as for :func:`iter_session_batches` (files only)."""
    if isinstance(source, Session):
        batches: Iterable[pa.RecordBatch] = source.table.to_batches(max_chunksize=batch_rows)
    else:
        batches = iter_session_batches(source, batch_rows, columns)
    for batch in batches:
        samples = SampleBatch.from_columns(batch).complete()
        if len(samples):
            yield samples


def _group_batches(file: pq.ParquetFile, batch_rows: int,
                   columns: Sequence[str] | None = None) -> Iterator[pa.RecordBatch]:
    """Read one row group at a time: a single ``iter_batches`` over the whole file keeps
    buffers of the groups already read (RSS grew by about 30 MB per 65,536 rows)."""
    for group in range(file.metadata.num_row_groups):
        yield from file.iter_batches(batch_size=batch_rows, row_groups=[group],
                                     columns=None if columns is None else list(columns),
                                     use_threads=False)


def _rebatched(batches: Iterable[pa.RecordBatch], rows: int) -> Iterator[pa.RecordBatch]:
    """Yield the rows of ``batches`` in batches of exactly ``rows`` rows (the last may
    hold fewer), whatever the row groups."""
    pending: list[pa.RecordBatch] = []
    count = 0
    for batch in batches:
        pending.append(batch)
        count += batch.num_rows
        while count >= rows:
            table = pa.Table.from_batches(pending)
            yield table.slice(0, rows).combine_chunks().to_batches()[0]
            rest = table.slice(rows)
            pending, count = rest.to_batches(), rest.num_rows
    if count:
        yield pa.Table.from_batches(pending).combine_chunks().to_batches()[0]


def _validate_chunk(table: pa.Table, path: Path, gaps_allowed: bool, offset: int,
                    last_t: float) -> None:
    """Validate one chunk of a session; rows in messages count from the file's start."""
    if table.num_rows == 0:
        return
    try:
        validate_table(table, path, gaps_allowed)
    except InputError as err:
        if offset == 0:
            raise
        raise InputError(f"{err.problem} (counted from row {offset})", path) from err
    if math.isfinite(last_t):
        check_times(column_array(table.column("t"))[:1], path, offset, last_t)


def write_session_batches(path: str | Path, batches: Iterable[pa.RecordBatch],
                          meta: SessionMeta, *, overwrite: bool = False,
                          row_group_rows: int = ROW_GROUP_ROWS) -> int:
    """Validate and write a session from record batches, one Parquet row group of about
    ``row_group_rows`` rows at a time, atomically as :func:`write_session` does.

    Memory stays bounded by one row group however long the session is. Returns the
    number of rows written; raises :class:`InputError` as :func:`write_session` does.
    """
    path = Path(path)
    meta.check(path)
    check_target(path, overwrite=overwrite)
    gaps = allows_gaps(meta)
    written = 0

    with atomic_write(path, overwrite=overwrite) as tmp:
        writer, last_t = None, -math.inf
        try:
            for group in _row_groups(batches, row_group_rows):
                schema = session_schema(group.column_names, meta)
                group = group.select(schema.names).cast(schema)
                _validate_chunk(group, path, gaps, written, last_t)
                if writer is None:
                    writer = pq.ParquetWriter(tmp.file, schema, compression="zstd")
                writer.write_table(group, row_group_size=row_group_rows)
                written += group.num_rows
                last_t = float(group.column("t")[-1].as_py())
        finally:
            if writer is not None:
                writer.close()
        if written == 0:
            raise InputError("session has no samples", path)
    return written


def _row_groups(batches: Iterable[pa.RecordBatch], rows: int) -> Iterator[pa.Table]:
    """Gather record batches into tables of at least ``rows`` rows (the last may be less)."""
    pending: list[pa.RecordBatch] = []
    count = 0
    for batch in batches:
        pending.append(batch)
        count += batch.num_rows
        if count >= rows:
            yield pa.Table.from_batches(pending).combine_chunks()
            pending, count = [], 0
    if count:
        yield pa.Table.from_batches(pending).combine_chunks()
