"""Rigid-body model of the Franka Emika Panda (pinocchio + example-robot-data URDF).

The URDF's link inertial parameters are the feasible parameters identified by
Gaz et al. (IEEE RA-L 2019). The model has the 7 arm joints: the two finger
joints are locked with ``pin.buildReducedModel`` (their inertia merges into link
7). ``with_hand=False`` strips the hand and fingers from the URDF before parsing,
which is how the reference recording in ``shared/reference`` was made.

Units: q [rad], dq [rad/s], ddq [rad/s^2], torques [Nm], forces [N], lengths [m].
Joint vectors are numpy arrays of shape (7,), joint 1 first.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
import pinocchio as pin

from contactkit.util.atomic import any_regular_file, write_text
from contactkit.util.cache import cache_dir

N_JOINTS = 7
URDF_RELATIVE = ("cmeel.prefix/share/example-robot-data/robots/panda_description/urdf/"
                 "panda.urdf")
HAND_LINKS = ("panda_hand", "panda_leftfinger", "panda_rightfinger", "panda_hand_tcp")
FINGER_JOINTS = ("panda_finger_joint1", "panda_finger_joint2")
JOINT_NAMES = tuple(f"panda_joint{i}" for i in range(1, N_JOINTS + 1))
LINK_FRAMES = tuple(f"panda_link{i}" for i in range(1, N_JOINTS + 1))

# Franka datasheet limits (frankaemika.github.io/docs/control_parameters.html), per joint.
DDQ_MAX = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])  # rad/s^2
DTAU_MAX = np.full(N_JOINTS, 1000.0)  # Nm/s


def urdf_path() -> Path:
    """Return the path of the Panda URDF shipped by example-robot-data."""
    dist = importlib.metadata.distribution("example-robot-data")
    return Path(str(dist.locate_file(URDF_RELATIVE)))


@cache
def urdf_text(with_hand: bool) -> str:
    """Return the URDF XML, with the hand and fingers removed when ``with_hand`` is false."""
    text = urdf_path().read_text()
    if with_hand:
        return text
    root = ET.fromstring(text)
    for element in list(root):
        is_hand_link = element.tag == "link" and element.get("name") in HAND_LINKS
        is_hand_joint = (element.tag == "joint"
                         and element.find("child").get("link") in HAND_LINKS)
        if is_hand_link or is_hand_joint:
            root.remove(element)
    return ET.tostring(root, encoding="unicode")


def urdf_sha256(with_hand: bool) -> str:
    """Return the SHA-256 of the URDF text the model is built from (hex)."""
    return hashlib.sha256(urdf_text(with_hand).encode()).hexdigest()


@cache
def _nominal_model(with_hand: bool) -> pin.Model:
    full = pin.buildModelFromXML(urdf_text(with_hand))
    locked = [full.getJointId(n) for n in FINGER_JOINTS if full.existJointName(n)]
    if not locked:
        return full
    return pin.buildReducedModel(full, locked, pin.neutral(full))


@dataclass(frozen=True)
class JointLimits:
    """Joint limits: positions [rad], velocities [rad/s], accelerations [rad/s^2],
    torques [Nm] and torque rates [Nm/s], each of shape (7,)."""

    q_min: np.ndarray
    q_max: np.ndarray
    dq_max: np.ndarray
    ddq_max: np.ndarray
    tau_max: np.ndarray
    dtau_max: np.ndarray


class PandaModel:
    """Panda dynamics through pinocchio: M(q), C(q, dq), g(q), Jacobians, ID and FD.

    Each instance owns its pinocchio ``Data``, so it is not shared between threads.
    """

    def __init__(self, with_hand: bool = True, model: pin.Model | None = None) -> None:
        self.with_hand = with_hand
        self.model = pin.Model(_nominal_model(with_hand)) if model is None else model
        self.data = self.model.createData()
        self.end_effector = "panda_hand_tcp" if with_hand else "panda_link8"
        self._frame_ids = {name: self.model.getFrameId(name) for name in
                           (*LINK_FRAMES, "panda_link8", self.end_effector)}
        self.limits = JointLimits(
            q_min=self.model.lowerPositionLimit.copy(),
            q_max=self.model.upperPositionLimit.copy(),
            dq_max=self.model.velocityLimit.copy(),
            ddq_max=DDQ_MAX.copy(),
            tau_max=self.model.effortLimit.copy(),
            dtau_max=DTAU_MAX.copy(),
        )

    @property
    def urdf_sha256(self) -> str:
        """SHA-256 of the URDF text this model was built from."""
        return urdf_sha256(self.with_hand)

    def perturbed(self, rng: np.random.Generator, mass_rel: float = 0.05,
                  com_m: float = 0.005) -> PandaModel:
        """Return a copy whose link masses and inertias are scaled by 1 + U(-mass_rel,
        mass_rel) and whose centres of mass move by up to ``com_m`` [m] per axis.

        This is how the simulator's plant differs from the nominal model the
        observer uses, as a real robot's true parameters differ from identified ones.
        """
        model = pin.Model(self.model)
        for j in range(1, model.njoints):
            inertia = model.inertias[j]
            scale = 1.0 + rng.uniform(-mass_rel, mass_rel)
            lever = inertia.lever + rng.uniform(-com_m, com_m, 3)
            model.inertias[j] = pin.Inertia(inertia.mass * scale, lever,
                                            inertia.inertia * scale)
        return PandaModel(self.with_hand, model)

    def frame_id(self, link: int | str) -> int:
        """Return the pinocchio frame id of link 1..7, or of a frame given by name."""
        name = LINK_FRAMES[link - 1] if isinstance(link, int) else link
        if name not in self._frame_ids:
            self._frame_ids[name] = self.model.getFrameId(name)
        return self._frame_ids[name]

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Return the joint-space inertia matrix M(q) [kg m^2], shape (7, 7), symmetric."""
        m = pin.crba(self.model, self.data, q)
        return np.triu(m) + np.triu(m, 1).T

    def coriolis_matrix(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Return C(q, dq) [Nm s/rad] with dM/dt - 2C skew-symmetric, shape (7, 7)."""
        return pin.computeCoriolisMatrix(self.model, self.data, q, dq).copy()

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """Return the gravity torque g(q) [Nm], shape (7,)."""
        return pin.computeGeneralizedGravity(self.model, self.data, q).copy()

    def inverse_dynamics(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Return M ddq + C dq + g [Nm]: the joint torque for ``ddq`` with no external force."""
        return pin.rnea(self.model, self.data, q, dq, ddq).copy()

    def forward_dynamics(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Return ddq [rad/s^2] = M^-1 (tau - C dq - g) (articulated-body algorithm)."""
        return pin.aba(self.model, self.data, q, dq, tau).copy()

    def frame_placement(self, q: np.ndarray, link: int | str) -> pin.SE3:
        """Return the world placement of link 1..7 (or a named frame) at ``q``."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.frame_id(link)].copy()

    def point_jacobian(self, q: np.ndarray, link: int | str,
                       point_local: np.ndarray | None = None) -> np.ndarray:
        """Return the 6x7 Jacobian of a point fixed on a link, world-aligned axes.

        Rows 0-2 map dq to the point's linear velocity [m/s], rows 3-5 to the link's
        angular velocity [rad/s]. ``point_local`` is the point in the link frame [m]
        (the frame origin when omitted). J^T [f; m] is the joint torque [Nm] produced
        by a force f [N] and moment m [Nm] acting at that point.
        """
        fid = self.frame_id(link)
        pin.computeJointJacobians(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        jac = pin.getFrameJacobian(self.model, self.data, fid, pin.LOCAL_WORLD_ALIGNED)
        if point_local is not None:
            offset = self.data.oMf[fid].rotation @ np.asarray(point_local, dtype=float)
            jac = jac.copy()
            jac[:3] -= np.cross(offset, jac[3:].T).T
        return jac


@dataclass(frozen=True)
class FrictionModel:
    """Joint friction of Gaz et al. 2019, per joint j:

    tau_f = phi1 / (1 + exp(-phi2 (dq + phi3))) - phi1 / (1 + exp(-phi2 phi3))  [Nm]

    It is zero at rest and sits on the link side of the torque sensor, so the
    measured torque is tau_J = M ddq + C dq + g + tau_f - tau_ext.
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
        return phi1 / (1.0 + np.exp(-phi2 * (dq + phi3))) - rest

    @property
    def at_rest(self) -> np.ndarray:
        """The sigmoid's value at dq = 0, subtracted so that friction is zero at rest [Nm]."""
        cached = self.__dict__.get("_at_rest")
        if cached is None:
            cached = self.phi1 / (1.0 + np.exp(-self.phi2 * self.phi3))
            object.__setattr__(self, "_at_rest", cached)
        return cached

    def scaled(self, scale: np.ndarray) -> FrictionModel:
        """Return a copy with the amplitudes phi1 multiplied by ``scale`` (per joint)."""
        return FrictionModel(self.phi1 * scale, self.phi2, self.phi3)


GAZ_FRICTION = FrictionModel(
    phi1=np.array([0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489]),
    phi2=np.array([5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336]),
    phi3=np.array([0.039533, 0.025882, -0.04607, 0.036194, 0.026226, -0.021047, 0.0035526]),
)


def viewer_urdf_file(with_hand: bool) -> Path:
    """Return a URDF file for viewers (Rerun), written once into the cache.

    Links are drawn with their coarse collision meshes (about 150 kB in all, against
    about 10 MB for the visual meshes, which every recording would carry), and
    ``package://`` references become absolute paths.
    """
    share = urdf_path().parents[4]
    root = ET.fromstring(urdf_text(with_hand))
    for link in root.iter("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
        for collision in link.findall("collision"):
            collision.tag = "visual"
    text = re.sub(r"package://([^\"']+)", lambda m: str(share / m.group(1)),
                  ET.tostring(root, encoding="unicode"))
    variant = "hand" if with_hand else "nohand"
    path = cache_dir() / f"panda_{variant}_{urdf_sha256(with_hand)[:12]}.urdf"
    if not path.exists():
        write_text(path, text, owned=any_regular_file)
    return path
