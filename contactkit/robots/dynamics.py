"""An arm's identified dynamics: what ``recorder identify`` writes and ``--dynamics FILE``
reads.

:class:`ArmDynamics` is one arm's rigid-body and joint parameters as identified from its
own free motion: the 10 standard inertial parameters of each of the 7 links (full values,
in pinocchio's ``Inertia.toDynamicParameters`` order :data:`PARAMETER_NAMES`, about the
link's joint frame), the joints' armature, their friction (:class:`FrictionModel`, Gaz et
al.'s sigmoid with viscous and constant terms), the payload the identification put at the
flange, the contact detector's thresholds calibrated with this model, and where the
parameters come from. It is frozen and hashable, so it travels inside a
:class:`~contactkit.robots.spec.RobotSetup` (``RobotSetup.dynamics``) and every stage that
builds a :class:`~contactkit.robots.model.RobotModel` for that setup uses it. The class
is defined beside ``RobotSetup`` in :mod:`contactkit.robots.spec` (re-exported here);
this module reads, writes and checks its files.

The file is JSON (:data:`FORMAT`). :func:`load_dynamics` runs the same checks on every
load: a known arm (and, for a session, the same arm and hand), finite values, positive
link masses, physically consistent inertias (each link's 4x4 pseudo-inertia positive
semi-definite, which holds the triangle inequalities), non-negative armature and
viscous friction, a bounded size and depth. Its ``checksum`` (SHA-256 over the canonical
content) only shows that the file is whole, as written: anyone can write a file with a
matching checksum, so it is no signature and says nothing about where the file came from.

Units: masses [kg], first moments [kg m], inertias [kg m^2], armature [kg m^2],
friction [Nm] (phi1, offset), [s/rad] (phi2), [rad/s] (phi3), [Nm s/rad] (viscous).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import cast

import numpy as np

from contactkit.errors import InputError
from contactkit.robots.registry import canonical_robot_name, get_robot
from contactkit.robots.spec import (
    FORMAT,
    FRICTION_TERMS,
    N_JOINTS,
    RobotSetup,
    dynamics_checksum,
)
from contactkit.robots.spec import PARAMETER_NAMES as PARAMETER_NAMES  # re-exported
from contactkit.robots.spec import ArmDynamics as ArmDynamics
from contactkit.robots.spec import Payload as Payload
from contactkit.util.atomic import write_text
from contactkit.util.safe_open import parse_json, read_input_bytes

MAX_BYTES = 1_000_000
"""The largest dynamics file read [bytes] (one is some 10 kB)."""
MAX_DEPTH = 8
"""The deepest nesting of JSON objects and lists a dynamics file may have."""
PSD_TOLERANCE = 1e-9
"""How far below zero a pseudo-inertia's smallest eigenvalue may lie, relative to its
largest (rounding of a consistent set written to JSON)."""


def with_dynamics(setup: RobotSetup, dynamics: ArmDynamics,
                  where: str | Path | None = None) -> RobotSetup:
    """Return ``setup`` carrying ``dynamics``; InputError naming ``where`` (default: the
    dynamics' file) when they are another arm's or were identified with(out) the hand
    the setup has."""
    check_arm(dynamics, setup, where or dynamics.source or None)
    return replace(setup, dynamics=dynamics)


def with_payload(dynamics: ArmDynamics, mass_kg: float,
                 com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> ArmDynamics:
    """Return ``dynamics`` with their payload replaced by a point mass ``mass_kg`` [kg] at
    ``com_m`` [m, flange frame]: a robot's configured load (libfranka's ``m_load`` and
    ``F_x_Cload``, which a session from ``--source franka`` stores). Link 7 becomes the
    nominal link 7 (the hand included where mounted) plus that mass, as the nominal
    model adds a payload; the other links, the armature, the friction and the detector
    stay as identified, and the provenance says where the payload came from. InputError
    for a mass that is negative or not finite."""
    from contactkit.robots.model import RobotModel

    if not (math.isfinite(mass_kg) and mass_kg >= 0 and all(map(math.isfinite, com_m))):
        raise InputError(f"a payload of {mass_kg:g} kg at {list(com_m)} m cannot be used")
    loaded = RobotModel(RobotSetup(dynamics.robot, dynamics.with_hand, payload_kg=mass_kg,
                                   payload_com_m=com_m))
    link = loaded.model.inertias[N_JOINTS].toDynamicParameters()
    provenance = dynamics.provenance_doc | {"payload": {
        "from": "the robot's configured load", "mass_kg": mass_kg, "com_m": list(com_m),
        "identified_mass_kg": dynamics.payload.mass_kg}}
    return replace(dynamics,
                   inertias=(*dynamics.inertias[:-1], tuple(float(v) for v in link)),
                   payload=Payload(float(mass_kg), com_m), provenance=json.dumps(
                       provenance, sort_keys=True))


def check_arm(dynamics: ArmDynamics, setup: RobotSetup, where: str | Path | None = None
              ) -> None:
    """Raise InputError naming ``where`` unless ``dynamics`` are for ``setup``'s arm and
    hand."""
    robot = canonical_robot_name(setup.robot)
    hand = setup.with_hand and get_robot(robot).has_hand
    if dynamics.robot != robot:
        raise InputError(f"dynamics identified on a {dynamics.robot!r}, not a {robot!r}: "
                         "identify this arm (recorder identify) or give its --robot", where)
    if dynamics.with_hand != hand:
        raise InputError(f"dynamics identified {'with' if dynamics.with_hand else 'without'}"
                         f" the hand, the session's arm is {'with' if hand else 'without'} "
                         "it", where)


def pseudo_inertia(parameters: np.ndarray) -> np.ndarray:
    """Return the 4x4 pseudo-inertia [[tr(I)/2 E - I, h], [h^T, m]] of one link's 10
    parameters (:data:`PARAMETER_NAMES`); it is positive semi-definite exactly when the
    mass is not negative and the inertia about the centre of mass satisfies the
    triangle inequalities (Wensing et al. 2018)."""
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = parameters
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    out = np.empty((4, 4))
    out[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    out[:3, 3] = out[3, :3] = (hx, hy, hz)
    out[3, 3] = m
    return out


def from_pseudo_inertia(pseudo: np.ndarray) -> np.ndarray:
    """Return the 10 parameters of a 4x4 pseudo-inertia (inverse of :func:`pseudo_inertia`);
    of a stack of them (shape (..., 4, 4)), the stack of their parameters (..., 10). The
    map is linear."""
    sigma = pseudo[..., :3, :3]
    inertia = np.trace(sigma, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) - sigma
    return np.stack([pseudo[..., 3, 3], pseudo[..., 0, 3], pseudo[..., 1, 3],
                     pseudo[..., 2, 3], inertia[..., 0, 0], inertia[..., 0, 1],
                     inertia[..., 1, 1], inertia[..., 0, 2], inertia[..., 1, 2],
                     inertia[..., 2, 2]], axis=-1)


def consistent(parameters: np.ndarray) -> bool:
    """Return whether one link's 10 parameters are physically consistent: a positive
    mass and a positive semi-definite pseudo-inertia (to :data:`PSD_TOLERANCE`)."""
    eig = np.linalg.eigvalsh(pseudo_inertia(parameters))
    return bool(parameters[0] > 0 and eig[0] >= -PSD_TOLERANCE * max(eig[-1], 1e-12))


def _numbers(value: object, count: int, what: str, where: str | Path | None
             ) -> tuple[float, ...]:
    if not (isinstance(value, list) and len(value) == count and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in value)):
        raise InputError(f"{what} must be a list of {count} numbers", where)
    numbers = tuple(float(v) for v in value)
    if not all(math.isfinite(v) for v in numbers):
        raise InputError(f"{what} holds a value that is not finite", where)
    return numbers


def _depth(value: object) -> int:
    """Return the nesting depth of a parsed JSON value (iteratively)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict | list):
            deepest = max(deepest, depth)
            if depth <= MAX_DEPTH:
                stack.extend((v, depth + 1) for v in (item.values() if isinstance(item, dict)
                                                      else item))
    return deepest


def dynamics_from_dict(doc: object, where: str | Path | None = None) -> ArmDynamics:
    """Build and check dynamics from :meth:`ArmDynamics.to_dict`'s document; InputError
    naming ``where`` (one line) for any check that fails (see the module's docstring)."""
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(f"not a dynamics file (format must be {FORMAT!r})", where)
    if _depth(doc) > MAX_DEPTH:
        raise InputError(f"dynamics file nested deeper than {MAX_DEPTH} levels", where)
    known = {"format", "robot", "with_hand", "parameter_order", "links", "armature_kgm2",
             "friction", "payload", "detector", "provenance", "checksum"}
    missing = sorted(known - {"detector"} - set(doc))
    if missing:
        raise InputError(f"dynamics file lacks {missing[0]!r}", where)
    unknown = sorted(set(doc) - known)
    if unknown:
        raise InputError(f"unknown dynamics entry {unknown[0]!r}", where)
    stored = doc["checksum"]
    body = {k: v for k, v in doc.items() if k != "checksum"}
    try:
        expected = dynamics_checksum(body)
    except ValueError as err:  # NaN or infinity in the document
        raise InputError("dynamics file holds a value that is not finite", where) from err
    if stored != expected:
        raise InputError("dynamics file's checksum does not match its content (changed or "
                         "damaged after it was written)", where)
    if doc["parameter_order"] != list(PARAMETER_NAMES):
        raise InputError(f"parameter_order must be {list(PARAMETER_NAMES)}", where)
    if not isinstance(doc["robot"], str) or not isinstance(doc["with_hand"], bool):
        raise InputError("robot must be a name and with_hand true or false", where)
    try:
        robot = canonical_robot_name(doc["robot"])
        get_robot(robot)
    except InputError as err:
        raise InputError(f"dynamics for an unknown robot: {err}", where) from err
    links = doc["links"]
    if not isinstance(links, list) or len(links) != N_JOINTS:
        raise InputError(f"links must list {N_JOINTS} links' parameters", where)
    inertias = tuple(_numbers(link, len(PARAMETER_NAMES), f"link {i}'s parameters", where)
                     for i, link in enumerate(links, 1))
    for i, link in enumerate(inertias, 1):
        if not link[0] > 0:
            raise InputError(f"link {i}'s mass is {link[0]:g} kg: masses must be positive",
                             where)
        if not consistent(np.array(link)):
            raise InputError(f"link {i}'s inertia is not physically consistent (its "
                             "pseudo-inertia is not positive semi-definite: a triangle "
                             "inequality fails)", where)
    armature = _numbers(doc["armature_kgm2"], N_JOINTS, "armature_kgm2", where)
    if min(armature) < 0:
        raise InputError("armature_kgm2 must not be negative", where)
    friction = doc["friction"]
    if not isinstance(friction, dict) or sorted(friction) != sorted(FRICTION_TERMS):
        raise InputError(f"friction must hold exactly {list(FRICTION_TERMS)}", where)
    terms = tuple(_numbers(friction[k], N_JOINTS, f"friction {k}", where)
                  for k in FRICTION_TERMS)
    if min(terms[1]) < 0 or min(terms[3]) < 0:
        raise InputError("friction phi2 and viscous must not be negative", where)
    payload = doc["payload"]
    if not isinstance(payload, dict) or sorted(payload) != ["com_m", "inertia_kgm2",
                                                            "mass_kg"]:
        raise InputError("payload must hold mass_kg, com_m and inertia_kgm2", where)
    mass = _numbers([payload["mass_kg"]], 1, "payload mass_kg", where)[0]
    detector = doc.get("detector")
    if detector is not None and not isinstance(detector, dict):
        raise InputError("detector must be an object or null", where)
    if not isinstance(doc["provenance"], dict):
        raise InputError("provenance must be an object", where)
    return ArmDynamics(
        robot=robot, with_hand=doc["with_hand"], inertias=inertias, armature_kgm2=armature,
        friction=terms,
        payload=Payload(mass, cast("tuple[float, float, float]",  # three, checked
                                   _numbers(payload["com_m"], 3, "payload com_m", where)),
                        _numbers(payload["inertia_kgm2"], 6, "payload inertia_kgm2", where)),
        detector=None if detector is None else json.dumps(detector, sort_keys=True),
        provenance=json.dumps(doc["provenance"], sort_keys=True))


def save_dynamics(path: str | Path, dynamics: ArmDynamics, *, overwrite: bool = False
                  ) -> Path:
    """Write ``dynamics`` as JSON to ``path`` atomically; return the path. An existing
    file is replaced only with ``overwrite``. The document passes the checks of every
    load first (InputError naming ``path`` otherwise): no file is written that cannot be
    read back."""
    doc = dynamics.to_dict()
    dynamics_from_dict(doc, path)
    return write_text(path, json.dumps(doc, indent=1, allow_nan=False) + "\n",
                      overwrite=overwrite)


def load_dynamics(path: str | Path, setup: RobotSetup | None = None) -> ArmDynamics:
    """Read and check a dynamics file (:func:`dynamics_from_dict`); with ``setup``, also
    that it is that arm's (:func:`check_arm`). InputError naming the file, one line,
    for a missing, oversized, malformed or failing file."""
    path = Path(path)
    raw = read_input_bytes(path, "dynamics file", "json")  # a regular file, never a FIFO
    if len(raw) > MAX_BYTES:
        raise InputError(f"dynamics file larger than {MAX_BYTES} bytes", path)
    doc = parse_json(raw, "dynamics file", path, limit=MAX_BYTES, max_depth=MAX_DEPTH)
    dynamics = replace(dynamics_from_dict(doc, path), source=str(path))
    if setup is not None:
        check_arm(dynamics, setup, path)
    return dynamics


@dataclass(frozen=True)
class ArmOverride:
    """The arm's model a command uses instead of each session's own: ``robot`` the
    registry name (``--robot``; None: the session's) and its identified ``dynamics``
    (``--dynamics``; None: the nominal model). Accepted wherever a ``robot`` override
    name is (:data:`RobotChoice`)."""

    robot: str | None = None
    dynamics: ArmDynamics | None = None


RobotChoice = str | ArmOverride | None
"""A command's arm override: a robot name, an :class:`ArmOverride`, or None (the
session's own arm and model)."""


def arm_override(robot: str | None, dynamics: ArmDynamics | None) -> RobotChoice:
    """Return the override of ``--robot`` and ``--dynamics``: the name alone when no
    dynamics are given (as before), else an :class:`ArmOverride`."""
    return robot if dynamics is None else ArmOverride(robot, dynamics)


def override_robot(choice: RobotChoice) -> str | None:
    """Return the robot name of an override (None: the session's)."""
    return choice.robot if isinstance(choice, ArmOverride) else choice


def override_dynamics(choice: RobotChoice) -> ArmDynamics | None:
    """Return the identified dynamics of an override (None: the nominal model)."""
    return choice.dynamics if isinstance(choice, ArmOverride) else None
