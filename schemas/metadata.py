"""A session's metadata: the JSON document under the Parquet key-value metadata key
``contactkit.session`` (:class:`SessionMeta`, with ``schema_version``), and its checks as
input: types, bounds, vocabularies (actions, conditions) and the arm it names.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, TypeGuard

from contactkit.errors import InputError, input_error_about
from contactkit.robots import (
    DEFAULT_ROBOT,
    URDF_PREFIX,
    RobotSetup,
    canonical_robot_name,
    get_robot,
)
from contactkit.robots.spec import N_JOINTS, ArmDynamics

SCHEMA_VERSION = 1
ACTIONS = ("none", "bump", "adjust", "shove")
CONDITIONS = ("static", "dynamic")


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
    dynamics: dict[str, Any] | None = None
    """The arm's identified dynamics, stored as values: the document of a dynamics file
    (:mod:`contactkit.robots.dynamics`, ``recorder set-robot --dynamics``), checked as
    that file is on every read (:meth:`arm_dynamics`). None: the robot's nominal
    model."""
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
                          payload_com_m=(float(com[0]), float(com[1]), float(com[2])),
                          dynamics=self.arm_dynamics(path))

    def arm_dynamics(self, path: str | Path | None = None) -> ArmDynamics | None:
        """Return the identified dynamics the session carries (:attr:`dynamics`), None
        for the nominal model. They pass every check of a dynamics file
        (:func:`~contactkit.robots.dynamics.dynamics_from_dict`) and are this session's
        arm's and hand's (:func:`~contactkit.robots.dynamics.check_arm`); InputError
        naming ``path`` (one line) otherwise."""
        if self.dynamics is None:
            return None
        from contactkit.robots.dynamics import check_arm, dynamics_from_dict

        try:
            dynamics = dynamics_from_dict(self.dynamics)
            check_arm(dynamics, RobotSetup(canonical_robot_name(self.robot), self.with_hand))
        except InputError as err:
            raise InputError(f"metadata dynamics: {err.problem}", path) from err
        return replace(dynamics, source=f"{path} (stored dynamics)" if path else "")

    def with_robot(self, robot: str | None) -> SessionMeta:
        """Return a copy that names ``robot`` (the session's own when None), with the
        URDF hash of that robot's model: how ``--robot`` overrides a session's arm. The
        stored :attr:`dynamics` stay when ``robot`` is the session's own arm; another
        arm's model is its nominal one."""
        if robot is None:
            return self
        name = canonical_robot_name(robot)
        same = name == canonical_robot_name(self.robot)
        return replace(self, robot=name,
                       urdf_sha256=get_robot(name).urdf_sha256(self.with_hand),
                       dynamics=self.dynamics if same else None)

    def with_dynamics(self, dynamics: ArmDynamics | None,
                      path: str | Path | None = None) -> SessionMeta:
        """Return a copy that carries ``dynamics`` as values (None: the nominal model);
        InputError naming ``path`` when they are another arm's or hand's."""
        if dynamics is None:
            return replace(self, dynamics=None)
        from contactkit.robots.dynamics import check_arm

        check_arm(dynamics, self.robot_setup(path), path)
        updated = replace(self, dynamics=dynamics.to_dict())
        updated.check(path)
        return updated

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
        positive; text fields strings; flags booleans; stored dynamics every check of
        a dynamics file, for this session's arm and hand.
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
        if self.urdf_sha256 and not SHA256_HEX.fullmatch(self.urdf_sha256):
            raise InputError(f"metadata urdf_sha256 {_short(self.urdf_sha256)} is not a "
                             "SHA-256 (64 hexadecimal digits)", path)
        if self.events is not None and not all(isinstance(e, Mapping) for e in self.events):
            raise InputError(f"metadata events {_short(self.events)} is not a list of event "
                             "objects", path)
        _check_true_contact(self.simulator, path)
        self.arm_dynamics(path)


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
SHA256_HEX = re.compile(r"[0-9a-f]{64}")
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
    "urdf_sha256": (str,), "dynamics": (dict, type(None)), "simulator": (dict, type(None)),
    "source_info": (dict,), "recovered": (bool,), "recovered_samples": (int, type(None)),
    "events": (list, type(None)), "residual_agreement": (dict, type(None)),
    "tool_version": (str,), "schema_version": (int,),
}
_BOUNDS = (("planned_at_s", 0.0, MAX_SESSION_S), ("speed_rad_s", 1e-6, 100.0),
           ("nominal_rate_hz", 1e-3, 1e6))


def _is_number(value: object) -> TypeGuard[int | float]:
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
