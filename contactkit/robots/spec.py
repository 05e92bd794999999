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
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from contactkit.util.safe_open import read_input_text

N_JOINTS = 7
DEFAULT_JERK_MAX = (1000.0,) * N_JOINTS
"""The joint jerk limit [rad/s^3] of an arm that states none (a ``urdf:`` robot): a
conservative guess, under a quarter of the Franka arms' smallest (3750 rad/s^3, the Panda's
joint 2), since an unknown arm's controller may filter less."""


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


@dataclass(frozen=True)
class FrictionModel:
    """Joint friction of Gaz et al. 2019, per joint j:

    tau_f = phi1 / (1 + exp(-phi2 (dq + phi3))) - phi1 / (1 + exp(-phi2 phi3))  [Nm]

    It is zero at rest and sits on the link side of the torque sensor, so the
    measured torque is tau_J = M ddq + C dq + g + tau_f - tau_ext. The sigmoid is
    evaluated as (1 + tanh(x / 2)) / 2, which equals 1 / (1 + exp(-x)) and cannot
    overflow, whatever the velocity.
    """

    phi1: np.ndarray
    phi2: np.ndarray
    phi3: np.ndarray

    def torque(self, dq: np.ndarray) -> np.ndarray:
        """Return the friction torque [Nm] for joint velocities ``dq`` [rad/s].

        ``dq`` may be (7,), (N, 7) or (7, B); the parameters broadcast along the
        axis of length 7 that comes last, or first when the array is (7, B).
        """
        phi1, phi2, phi3, rest = self.phi1, self.phi2, self.phi3, self.at_rest
        if dq.ndim == 2 and dq.shape[0] == N_JOINTS and dq.shape[1] != N_JOINTS:
            phi1, phi2, phi3, rest = phi1[:, None], phi2[:, None], phi3[:, None], rest[:, None]
        friction: np.ndarray = phi1 * _sigmoid(phi2 * (dq + phi3)) - rest
        return friction

    @cached_property
    def sample_coefficients(self) -> tuple[list[float], ...]:
        """Return (a, b, c, d), each 7 floats: phi1 / 2 [Nm], phi2 / 2 [s/rad], phi3
        [rad/s] and phi1 / 2 - at_rest [Nm], so that joint j's friction torque
        (:meth:`torque`, the same sigmoid, to about 1e-15) is a_j tanh(b_j (dq_j + c_j))
        + d_j [Nm]: a live observer's per-sample path computes it on Python floats, where
        seven numbers cost less than array operations."""
        return tuple(x.tolist() for x in (0.5 * self.phi1, 0.5 * self.phi2, self.phi3,
                                           0.5 * self.phi1 - self.at_rest))

    @property
    def at_rest(self) -> np.ndarray:
        """The sigmoid's value at dq = 0, subtracted so that friction is zero at rest [Nm]."""
        cached: np.ndarray | None = self.__dict__.get("_at_rest")
        if cached is None:
            cached = self.phi1 * _sigmoid(self.phi2 * self.phi3)
            object.__setattr__(self, "_at_rest", cached)
        return cached

    def scaled(self, scale: np.ndarray) -> FrictionModel:
        """Return a copy with the amplitudes phi1 multiplied by ``scale`` (per joint)."""
        return FrictionModel(self.phi1 * scale, self.phi2, self.phi3)


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
class RobotSetup:
    """One arm as mounted in a session: the robot's registry name, whether its hand
    is mounted, and a payload on the flange (``payload_kg`` [kg] at ``payload_com_m``
    [m], flange frame; 0 kg for none)."""

    robot: str = "panda"
    with_hand: bool = True
    payload_kg: float = 0.0
    payload_com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
