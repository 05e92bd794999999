"""Rigid-body dynamics of a session's arm through pinocchio: M(q), C(q, dq), g(q),
Jacobians, inverse and forward dynamics.

The model has the 7 arm joints: any other joint of the URDF (a hand's fingers) is
locked with ``pin.buildReducedModel`` (its inertia merges into link 7). A session without
the hand has its links stripped from the URDF before parsing; a payload is added
to link 7's inertia at its centre of mass (flange frame). A setup with identified
dynamics (:mod:`contactkit.robots.dynamics`) has its links' inertias and armature
replaced by them.

Units: q [rad], dq [rad/s], ddq [rad/s^2], torques [Nm], forces [N], lengths [m].
Joint vectors are numpy arrays of shape (7,), joint 1 first.
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache

import numpy as np
import pinocchio as pin

from contactkit.errors import InputError
from contactkit.robots.registry import get_robot
from contactkit.robots.spec import N_JOINTS, RobotSetup, RobotSpec

log = logging.getLogger(__name__)


def _revolute(text: str, joints: tuple[str, ...]) -> str:
    """Return URDF ``text`` with its continuous arm ``joints`` made revolute: one angle
    each, as sessions record them (pinocchio gives a continuous joint two configuration
    values, its angle's cosine and sine), with position limits that never bind."""
    if "continuous" not in text:
        return text
    root = ET.fromstring(text)
    changed = False
    for joint in root.iter("joint"):
        if joint.get("type") == "continuous" and joint.get("name") in joints:
            joint.set("type", "revolute")
            limit = joint.find("limit")
            if limit is None:
                limit = ET.SubElement(joint, "limit", effort="0", velocity="0")
            limit.set("lower", "-1e9")
            limit.set("upper", "1e9")
            changed = True
    return ET.tostring(root, encoding="unicode") if changed else text


@contextmanager
def _native_stderr() -> Iterator[list[str]]:
    """Capture what native code writes to file descriptor 2 (urdfdom's parse errors,
    printed even when pinocchio goes on with a model missing what it could not parse);
    the lines are in the yielded list after the block. Nothing is captured when fd 2
    cannot be duplicated."""
    lines: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:
        yield lines
        return
    sys.stderr.flush()
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            captured.seek(0)
            lines += captured.read(100_000).decode(errors="replace").splitlines()


@cache
def _nominal_model(setup: RobotSetup) -> pin.Model:
    spec = get_robot(setup.robot)
    failure: Exception | None = None
    with _native_stderr() as messages:
        try:
            full = pin.buildModelFromXML(_revolute(spec.urdf_text(setup.with_hand),
                                                   spec.joint_names))
        except (RuntimeError, ValueError) as err:
            failure = err
    complaints = [m.strip()[len("Error:"):].strip() for m in messages
                  if m.strip().startswith("Error:")]
    if failure is not None or complaints:
        detail = "; ".join(complaints[:2]) if complaints else str(failure)
        raise InputError(f"robot {setup.robot!r}: pinocchio cannot build its URDF: "
                         f"{detail[:300]}") from failure
    for line in messages:  # what urdfdom says beside errors (warnings) is said, not swallowed
        if line.strip() and not line.strip().startswith("at line "):
            log.warning("robot %r, building its model: %s", setup.robot, line.strip())
    # every link, a locked gripper's too (before locking adds it to its parent's)
    for name, inertia in zip(full.names, full.inertias, strict=True):
        tensor = np.asarray(inertia.inertia, dtype=float)
        if not (np.isfinite(inertia.mass) and inertia.mass >= 0 and np.isfinite(tensor).all()
                and np.linalg.eigvalsh(tensor).min() >= -1e-9 * max(1.0, np.abs(tensor).max())):
            raise InputError(f"robot {setup.robot!r}: the links on joint {name!r} have a "
                             f"mass of {inertia.mass:g} kg or an inertia that is not finite "
                             "and positive (masses must be finite and not negative, inertia "
                             "tensors positive semi-definite)")
    # every joint beyond the 7 arm joints (a hand's fingers, a gripper) is locked at rest
    locked = [full.getJointId(n) for n in full.names[1:] if n not in spec.joint_names]
    model = full if not locked else pin.buildReducedModel(full, locked, pin.neutral(full))
    if model.nq != N_JOINTS:
        raise InputError(f"robot {setup.robot!r} has {model.nq} joints, not {N_JOINTS}")
    if setup.dynamics is not None:
        for joint, parameters in enumerate(setup.dynamics.parameters, 1):
            model.inertias[joint] = pin.Inertia.FromDynamicParameters(parameters)
        model.armature[:] = setup.dynamics.armature_kgm2
    elif setup.payload_kg:
        flange = model.frames[model.getFrameId(spec.flange)]
        payload = pin.Inertia(setup.payload_kg, np.array(setup.payload_com_m, dtype=float),
                              np.zeros((3, 3)))
        model.inertias[flange.parentJoint] += flange.placement.act(payload)
    return model


class RobotModel:
    """An arm's dynamics through pinocchio, for one :class:`RobotSetup`.

    Each instance owns its pinocchio ``Data``, so it is not shared between threads.
    ``spec`` is the robot's registry entry, ``limits`` its joint limits,
    ``end_effector`` the frame of the workspace wrench (hand TCP or flange),
    ``friction`` the joint friction (identified, else the robot's; None for none).
    """

    def __init__(self, setup: RobotSetup | None = None, model: pin.Model | None = None) -> None:
        self.setup = setup or RobotSetup()
        self.spec: RobotSpec = get_robot(self.setup.robot)
        self.model = pin.Model(_nominal_model(self.setup)) if model is None else model
        self.data = self.model.createData()
        self.end_effector = self.spec.end_effector_frame(self.setup.with_hand)
        self._frame_ids: dict[str, int] = {}
        self._axes: dict[int, np.ndarray] = {}
        self.limits = self.spec.limits
        self.friction = self.setup.friction(self.spec)

    @property
    def with_hand(self) -> bool:
        """Whether the model carries the robot's hand."""
        return self.setup.with_hand and self.spec.has_hand

    @property
    def urdf_sha256(self) -> str:
        """SHA-256 of the URDF text this model was built from."""
        return self.spec.urdf_sha256(self.setup.with_hand)

    def perturbed(self, rng: np.random.Generator, mass_rel: float = 0.05,
                  com_m: float = 0.005) -> RobotModel:
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
        return RobotModel(self.setup, model)

    def frame_id(self, link: int | str) -> int:
        """Return the pinocchio frame id of link 1..7, or of a frame given by name."""
        name = self.spec.link_frames[link - 1] if isinstance(link, int) else link
        if name not in self._frame_ids:
            if not self.model.existFrame(name):
                raise InputError(f"robot {self.setup.robot!r} has no frame {name!r}")
            self._frame_ids[name] = self.model.getFrameId(name)
        return self._frame_ids[name]

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Return the joint-space inertia matrix M(q) [kg m^2], shape (7, 7), symmetric."""
        m: np.ndarray = pin.crba(self.model, self.data, q)
        symmetric: np.ndarray = np.triu(m) + np.triu(m, 1).T
        return symmetric

    def coriolis_matrix(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Return C(q, dq) [Nm s/rad] with dM/dt - 2C skew-symmetric, shape (7, 7)."""
        c: np.ndarray = pin.computeCoriolisMatrix(self.model, self.data, q, dq).copy()
        return c

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """Return the gravity torque g(q) [Nm], shape (7,)."""
        g: np.ndarray = pin.computeGeneralizedGravity(self.model, self.data, q).copy()
        return g

    def inverse_dynamics(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Return M ddq + C dq + g [Nm]: the joint torque for ``ddq`` with no external force."""
        tau: np.ndarray = pin.rnea(self.model, self.data, q, dq, ddq).copy()
        return tau

    def forward_dynamics(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Return ddq [rad/s^2] = M^-1 (tau - C dq - g) (articulated-body algorithm)."""
        ddq: np.ndarray = pin.aba(self.model, self.data, q, dq, tau).copy()
        return ddq

    def frame_placement(self, q: np.ndarray, link: int | str) -> pin.SE3:
        """Return the world placement of link 1..7 (or a named frame) at ``q``."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.frame_id(link)].copy()

    def frame_placements(self, q: np.ndarray, link: int | str
                         ) -> tuple[np.ndarray, np.ndarray]:
        """Return the world placements of link 1..7 (or a named frame) at every row of
        ``q`` (n, 7) [rad] at once: rotations (n, 3, 3) and translations [m] (n, 3).

        The forward kinematics of :meth:`frame_placement` (equal to rounding) in numpy
        over all rows, instead of one pinocchio call per row. The arm's joints are
        revolute (:func:`contactkit.robots.registry.urdf_robot` takes no other)."""
        q = np.asarray(q, dtype=float).reshape(-1, self.model.nq)
        frame = self.model.frames[self.frame_id(link)]
        chain = []  # the frame's joint and its ancestors, back to the root
        joint = frame.parentJoint
        while joint > 0:
            chain.append(joint)
            joint = self.model.parents[joint]
        rotation = np.broadcast_to(np.eye(3), (len(q), 3, 3))
        translation = np.zeros((len(q), 3))
        for joint in reversed(chain):
            placement = self.model.jointPlacements[joint]
            value = q[:, self.model.joints[joint].idx_q]
            axis = self._joint_axis(joint)
            translation = translation + _rotate(rotation, placement.translation)
            rotation = _compose(rotation, placement.rotation)
            # Rodrigues: R (cos I + sin [a]x + (1 - cos) a a^T), about the joint's axis a
            cos, sin = np.cos(value)[:, None, None], np.sin(value)[:, None, None]
            cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                              [-axis[1], axis[0], 0.0]])
            rotation = (cos * rotation + sin * _compose(rotation, cross)
                        + (1.0 - cos) * _rotate(rotation, axis)[:, :, None] * axis)
        translation = translation + _rotate(rotation, frame.placement.translation)
        return _compose(rotation, frame.placement.rotation), translation

    def _joint_axis(self, joint: int) -> np.ndarray:
        """Return the unit axis (3,) of revolute joint ``joint`` in its own frame (the
        angular part of its motion subspace)."""
        if joint not in self._axes:
            data = self.model.joints[joint].createData()
            self.model.joints[joint].calc(data, np.zeros(self.model.joints[joint].nq))
            self._axes[joint] = np.asarray(data.S, dtype=float).reshape(6)[3:]
        return self._axes[joint]

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
        jac: np.ndarray = pin.getFrameJacobian(self.model, self.data, fid,
                                               pin.LOCAL_WORLD_ALIGNED)
        if point_local is not None:
            offset = self.data.oMf[fid].rotation @ np.asarray(point_local, dtype=float)
            jac = jac.copy()
            jac[:3] -= np.cross(offset, jac[3:].T).T
        return jac


def _rotate(rotation: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """Return ``rotation`` (n, 3, 3) applied to one ``vector`` (3,): (n, 3)."""
    rotated: np.ndarray = (rotation.reshape(-1, 3) @ vector).reshape(-1, 3)
    return rotated


def _compose(rotation: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Return ``rotation`` (n, 3, 3) times one matrix ``right`` (3, 3): (n, 3, 3)."""
    composed: np.ndarray = (rotation.reshape(-1, 3) @ right).reshape(-1, 3, 3)
    return composed
