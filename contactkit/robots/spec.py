"""What a robot model is, without pinocchio: names, limits, friction, end effector.

A :class:`RobotSpec` describes one kind of 7-joint serial arm: where its URDF is, the
names of its joints and link frames, its joint limits, its identified friction (if
any), the simulator's armature, and the observer's defaults. A :class:`RobotSetup`
is one arm as mounted in a session: a robot name plus what is on its flange (the
Franka Hand, a payload, or nothing). Everything here loads with numpy and the
standard library only, so readers can validate against names and limits without
importing pinocchio (:mod:`contactkit.robots.model` builds the dynamics).

Units: q [rad], dq [rad/s], ddq [rad/s^2], dddq (jerk) [rad/s^3], tau [Nm], dtau
[Nm/s], masses [kg], lengths [m].
"""

from __future__ import annotations

import hashlib
import json
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from contactkit.util.safe_open import read_input_text

N_JOINTS = 7
DEFAULT_JERK_MAX = (1000.0,) * N_JOINTS
"""The joint jerk limit [rad/s^3] of an arm that states none (a ``urdf:`` robot): a
conservative guess, under a quarter of the Franka arms' smallest (3750 rad/s^3, the Panda's
joint 2), since an unknown arm's controller may filter less."""

FORMAT = "contactkit-dynamics/1"
PARAMETER_NAMES = ("m", "mc_x", "mc_y", "mc_z", "I_xx", "I_xy", "I_yy", "I_xz", "I_yz", "I_zz")
"""The 10 inertial parameters of a link, pinocchio's ``Inertia.toDynamicParameters``
order: mass [kg], first moment m c [kg m] and inertia about the joint frame's origin
[kg m^2], in the link's joint frame."""
FRICTION_TERMS = ("phi1", "phi2", "phi3", "viscous", "offset")


@dataclass(frozen=True)
class JointLimits:
    """Joint limits: positions [rad], velocities [rad/s], accelerations [rad/s^2],
    torques [Nm], torque rates [Nm/s] and jerks [rad/s^3], each of shape (7,)."""

    q_min: np.ndarray
    q_max: np.ndarray
    dq_max: np.ndarray
    ddq_max: np.ndarray
    tau_max: np.ndarray
    dtau_max: np.ndarray
    jerk_max: np.ndarray


def _sigmoid(x: np.ndarray) -> np.ndarray:
    """Return the logistic function 1 / (1 + exp(-x)), without overflow for large |x|."""
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def _zeros7() -> np.ndarray:
    return np.zeros(N_JOINTS)


@dataclass(frozen=True)
class FrictionModel:
    """Joint friction of Gaz et al. 2019, with a viscous and a constant term, per joint j:

    tau_f = phi1 / (1 + exp(-phi2 (dq + phi3))) - phi1 / (1 + exp(-phi2 phi3))
            + viscous dq + offset  [Nm]

    The sigmoid part is zero at rest; ``viscous`` [Nm s/rad] and ``offset`` [Nm] are
    zero unless identified (:mod:`contactkit.robots.dynamics`). Coulomb friction Fc is
    the sigmoid with phi1 = 2 Fc, phi3 = 0 and a steep phi2 (Fc tanh(phi2 dq / 2)).
    Friction sits on the link side of the torque sensor, so the measured torque is
    tau_J = M ddq + C dq + g + tau_f - tau_ext. The sigmoid is evaluated as (1 +
    tanh(x / 2)) / 2, which equals 1 / (1 + exp(-x)) and cannot overflow, whatever
    the velocity.
    """

    phi1: np.ndarray
    phi2: np.ndarray
    phi3: np.ndarray
    viscous: np.ndarray = field(default_factory=_zeros7)
    offset: np.ndarray = field(default_factory=_zeros7)

    def torque(self, dq: np.ndarray) -> np.ndarray:
        """Return the friction torque [Nm] for joint velocities ``dq`` [rad/s].

        ``dq`` may be (7,), (N, 7) or (7, B); the parameters broadcast along the
        axis of length 7 that comes last, or first when the array is (7, B).
        """
        phi1, phi2, phi3, rest = self.phi1, self.phi2, self.phi3, self.at_rest
        viscous, offset = self.viscous, self.offset
        if dq.ndim == 2 and dq.shape[0] == N_JOINTS and dq.shape[1] != N_JOINTS:
            phi1, phi2, phi3, rest, viscous, offset = (
                x[:, None] for x in (phi1, phi2, phi3, rest, viscous, offset))
        friction: np.ndarray = phi1 * _sigmoid(phi2 * (dq + phi3)) - rest + viscous * dq + offset
        return friction

    @cached_property
    def sample_coefficients(self) -> tuple[list[float], ...]:
        """Return (a, b, c, d, e), each 7 floats: phi1 / 2 [Nm], phi2 / 2 [s/rad], phi3
        [rad/s], phi1 / 2 - at_rest + offset [Nm] and viscous [Nm s/rad], so that joint
        j's friction torque (:meth:`torque`, to about 1e-15) is a_j tanh(b_j (dq_j +
        c_j)) + d_j + e_j dq_j [Nm]: a live observer's per-sample path computes it on
        Python floats, where seven numbers cost less than array operations."""
        return tuple(x.tolist() for x in (0.5 * self.phi1, 0.5 * self.phi2, self.phi3,
                                           0.5 * self.phi1 - self.at_rest + self.offset,
                                           self.viscous))

    @property
    def at_rest(self) -> np.ndarray:
        """The sigmoid's value at dq = 0, subtracted so that it is zero at rest [Nm]."""
        cached: np.ndarray | None = self.__dict__.get("_at_rest")
        if cached is None:
            cached = self.phi1 * _sigmoid(self.phi2 * self.phi3)
            object.__setattr__(self, "_at_rest", cached)
        return cached

    def scaled(self, scale: np.ndarray) -> FrictionModel:
        """Return a copy with the amplitudes phi1, viscous and offset multiplied by
        ``scale`` (per joint)."""
        return FrictionModel(self.phi1 * scale, self.phi2, self.phi3,
                             self.viscous * scale, self.offset * scale)


@dataclass(frozen=True)
class RobotSpec:
    """One kind of 7-joint serial arm, as the registry holds it.

    ``urdf_file`` returns the URDF with the end effector mounted (when the robot has
    one: ``hand_links`` are removed for a session without it); ``joint_names`` the 7
    arm joints, base first; ``link_frames`` the frames of links 1..7 (a contact's
    link, a Jacobian's frame); ``flange`` the frame a payload is fixed to; ``tcp`` the
    end effector's frame with the hand (the flange without); ``ddq_max`` [rad/s^2],
    ``dtau_max`` [Nm/s] and ``jerk_max`` [rad/s^3] the limits a URDF does not hold
    (positions, velocities and torques come from it; an arm that states no jerk limit,
    a ``urdf:`` robot, gets :data:`DEFAULT_JERK_MAX`, below the Franka arms' own);
    ``friction`` the identified joint friction (the observer compensates it), or None;
    ``armature_kgm2`` the motors' reflected inertia the simulator puts on the plant;
    ``detector_floor_nm`` (7 values) and ``detector_motion_scale`` adapt a contact
    detector calibrated on another arm (the default model's, on a simulated Panda) to
    this one: its at-rest thresholds are raised to the floor [Nm] and its growth with
    speed and acceleration multiplied by the scale; ``provenance`` where the model
    comes from and its licence.
    """

    name: str
    description: str
    urdf_file: Callable[[], Path]
    joint_names: tuple[str, ...]
    link_frames: tuple[str, ...]
    flange: str
    tcp: str | None = None
    hand_links: tuple[str, ...] = ()
    hand_frame: str | None = None
    ddq_max: tuple[float, ...] = (10.0,) * N_JOINTS
    dtau_max: tuple[float, ...] = (1000.0,) * N_JOINTS
    jerk_max: tuple[float, ...] = DEFAULT_JERK_MAX
    friction: FrictionModel | None = None
    armature_kgm2: tuple[float, ...] = (0.0,) * N_JOINTS
    detector_floor_nm: tuple[float, ...] | None = None
    detector_motion_scale: float = 1.0
    provenance: str = ""
    aliases: tuple[str, ...] = field(default=())

    @property
    def has_hand(self) -> bool:
        """Whether the robot's URDF carries a hand that a session can mount or not."""
        return bool(self.hand_links)

    def urdf_text(self, with_hand: bool) -> str:
        """Return the URDF XML, with the hand links removed when ``with_hand`` is false."""
        return _urdf_text(self, with_hand and self.has_hand)

    def urdf_sha256(self, with_hand: bool) -> str:
        """Return the SHA-256 (hex) of the URDF text the model is built from."""
        return hashlib.sha256(self.urdf_text(with_hand).encode()).hexdigest()

    @cached_property
    def limits(self) -> JointLimits:
        """Return the joint limits: q, dq and tau from the URDF, ddq, dtau and jerk from the
        spec."""
        q_min, q_max, dq_max, tau_max = urdf_joint_limits(self.urdf_text(False),
                                                          self.joint_names)
        return JointLimits(q_min=q_min, q_max=q_max, dq_max=dq_max,
                           ddq_max=np.array(self.ddq_max, dtype=float),
                           tau_max=tau_max, dtau_max=np.array(self.dtau_max, dtype=float),
                           jerk_max=np.array(self.jerk_max, dtype=float))

    def end_effector_frame(self, with_hand: bool) -> str:
        """Return the frame the workspace wrench is computed at: the TCP with the hand,
        else the flange."""
        return self.tcp if (with_hand and self.has_hand and self.tcp) else self.flange


_TEXTS: dict[tuple[str, Path, bool], str] = {}


def _urdf_text(spec: RobotSpec, with_hand: bool) -> str:
    path = spec.urdf_file()
    key = (spec.name, path, with_hand)
    if key not in _TEXTS:
        text = read_input_text(path, "robot's URDF", "urdf")
        _TEXTS[key] = text if with_hand or not spec.hand_links else strip_links(
            text, spec.hand_links)
    return _TEXTS[key]


def strip_links(text: str, links: tuple[str, ...]) -> str:
    """Return URDF ``text`` without the named links and the joints that lead to them."""
    root = ET.fromstring(text)
    for element in list(root):
        is_link = element.tag == "link" and element.get("name") in links
        child = element.find("child") if element.tag == "joint" else None
        if is_link or (child is not None and child.get("link") in links):
            root.remove(element)
    return ET.tostring(root, encoding="unicode")


def urdf_joint_limits(text: str, joint_names: tuple[str, ...]
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return (q_min, q_max, dq_max, tau_max) of the named joints from URDF ``text``
    (rad, rad, rad/s, Nm); a continuous joint's positions are unlimited (-inf, inf).
    Raises ValueError when a joint or its limit is missing."""
    root = ET.fromstring(text)
    joints = {j.get("name"): j for j in root.iter("joint")}
    rows = []
    for name in joint_names:
        joint = joints.get(name)
        limit = None if joint is None else joint.find("limit")
        if joint is None or limit is None:
            raise ValueError(f"the URDF has no joint {name!r} with a <limit>")
        row = [float(limit.get(k, "nan")) for k in ("lower", "upper", "velocity", "effort")]
        if joint.get("type") == "continuous":
            row[:2] = -np.inf, np.inf
        rows.append(row)
    values = np.array(rows, dtype=float)
    if np.isnan(values).any() or not np.isfinite(values[:, 2:]).all():
        raise ValueError("a joint limit of the URDF is missing or not a number")
    return values[:, 0], values[:, 1], values[:, 2], values[:, 3]


@dataclass(frozen=True)
class Payload:
    """What the identification put on the flange beyond the nominal link 7: ``mass_kg``
    [kg] at ``com_m`` [m] with inertia ``inertia_kgm2`` [kg m^2] about that centre of
    mass (Ixx, Ixy, Iyy, Ixz, Iyz, Izz), all in the flange frame. It is the difference
    between the identified and the nominal link 7 (hand included where mounted): negative
    when the arm's end is lighter than its model. Reported, not applied on top: link 7's
    identified parameters already hold it."""

    mass_kg: float = 0.0
    com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inertia_kgm2: tuple[float, ...] = (0.0,) * 6


@dataclass(frozen=True)
class ArmDynamics:
    """One arm's identified dynamics (see the module's docstring).

    ``robot`` the registry's name, ``with_hand`` whether the hand was mounted;
    ``inertias`` 7 tuples of the 10 :data:`PARAMETER_NAMES`; ``armature_kgm2`` 7 values;
    ``friction`` 5 tuples of 7 values, :data:`FRICTION_TERMS` in order; ``payload``;
    ``detector`` the contact detector's settings calibrated with this model, as their
    JSON document's text (None when none was; read and checked by
    :func:`contactkit.features.detector.dynamics_detector`);
    ``provenance`` a JSON text (sessions and their SHA-256, samples, the excitation
    report, the tool's version, when it was made); ``source`` the file they were read
    from (not part of their identity).
    """

    robot: str
    with_hand: bool
    inertias: tuple[tuple[float, ...], ...]
    armature_kgm2: tuple[float, ...] = (0.0,) * N_JOINTS
    friction: tuple[tuple[float, ...], ...] = ((0.0,) * N_JOINTS, (1.0,) * N_JOINTS,
                                              (0.0,) * N_JOINTS, (0.0,) * N_JOINTS,
                                              (0.0,) * N_JOINTS)
    payload: Payload = field(default_factory=Payload)
    detector: str | None = None
    provenance: str = "{}"
    source: str = field(default="", compare=False)

    @cached_property
    def friction_model(self) -> FrictionModel:
        """Return the joint friction as the observer's :class:`FrictionModel`."""
        return FrictionModel(*(np.array(values, dtype=float) for values in self.friction))

    @cached_property
    def parameters(self) -> np.ndarray:
        """Return the links' inertial parameters, (7, 10)."""
        return np.array(self.inertias, dtype=float)

    @property
    def provenance_doc(self) -> dict[str, Any]:
        """Return the provenance as a dictionary."""
        doc: dict[str, Any] = json.loads(self.provenance)
        return doc

    def to_dict(self) -> dict[str, Any]:
        """Return the JSON document of these dynamics, with its ``checksum``."""
        doc = {
            "format": FORMAT,
            "robot": self.robot,
            "with_hand": self.with_hand,
            "parameter_order": list(PARAMETER_NAMES),
            "links": [list(link) for link in self.inertias],
            "armature_kgm2": list(self.armature_kgm2),
            "friction": {name: list(values) for name, values in
                         zip(FRICTION_TERMS, self.friction, strict=True)},
            "payload": {"mass_kg": self.payload.mass_kg, "com_m": list(self.payload.com_m),
                        "inertia_kgm2": list(self.payload.inertia_kgm2)},
            "detector": None if self.detector is None else json.loads(self.detector),
            "provenance": self.provenance_doc,
        }
        return doc | {"checksum": dynamics_checksum(doc)}

    @cached_property
    def checksum(self) -> str:
        """The file's checksum (``sha256:`` and 64 hex digits) over the canonical content:
        it shows the content is whole, nothing more."""
        checksum: str = self.to_dict()["checksum"]
        return checksum


def dynamics_checksum(doc: dict[str, Any]) -> str:
    """Return the checksum (``sha256:`` and 64 hex digits) of a dynamics document without
    its ``checksum``: SHA-256 over its canonical JSON (sorted keys, no spaces)."""
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()




@dataclass(frozen=True)
class RobotSetup:
    """One arm as mounted in a session: the robot's registry name, whether its hand
    is mounted, a payload on the flange (``payload_kg`` [kg] at ``payload_com_m``
    [m], flange frame; 0 kg for none), and the arm's identified ``dynamics``
    (:mod:`contactkit.robots.dynamics`; None: the robot's nominal model). Identified
    dynamics replace the links' inertias, the armature and the friction; their link 7
    already holds what was on the flange, so the payload is then not added again."""

    robot: str = "panda"
    with_hand: bool = True
    payload_kg: float = 0.0
    payload_com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dynamics: ArmDynamics | None = None

    def friction(self, spec: RobotSpec) -> FrictionModel | None:
        """Return the arm's joint friction: the identified one, else ``spec``'s."""
        return spec.friction if self.dynamics is None else self.dynamics.friction_model
