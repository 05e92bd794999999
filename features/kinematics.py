"""A frame's world-aligned Jacobian at many samples at once, in numpy.

The feature chain's wrench needs the 6x7 Jacobian of one frame at every sample.
pinocchio gives it sample by sample (``getFrameJacobian`` after a pass that places
the joints), a Python call per sample; here the same forward kinematics runs once
over a whole chunk, each rotation and position entry a vector over the samples, for
arms whose joints all turn about an axis of their own frame (pinocchio's revolute
joints RX, RY and RZ: the Panda's and the FR3's). The Jacobians equal pinocchio's to
rounding (about 1e-16 absolute: the same products, summed in another order).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

_AXES = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}


@dataclass(frozen=True, eq=False)
class _Joint:
    """A revolute joint: its index in the model, its parent's (0: the world), its
    column of q and of the Jacobian, the axis it turns about (0, 1, 2: x, y, z of its
    own frame) and its placement in the parent's frame (rotation (3, 3), translation
    (3,) [m])."""

    index: int
    parent: int
    q_column: int
    column: int
    axis: int
    rotation: np.ndarray
    translation: np.ndarray


@dataclass(frozen=True, eq=False)
class FrameKinematics:
    """Forward kinematics of the joints that carry one frame, vectorised over samples.

    Build with :meth:`of`; :meth:`jacobian_rows` gives the frame's Jacobian in
    pinocchio's ``LOCAL_WORLD_ALIGNED`` convention (linear velocity of the frame's
    origin, then angular velocity, both in world axes) at each sample."""

    joints: tuple[_Joint, ...]
    nv: int
    frame_translation: np.ndarray

    @classmethod
    def of(cls, model: pin.Model, frame_id: int) -> FrameKinematics | None:
        """Return the kinematics of frame ``frame_id`` of ``model``, or None when a
        joint that carries it is not a revolute joint about an axis of its own frame
        (then pinocchio computes the Jacobian sample by sample)."""
        frame = model.frames[frame_id]
        chain, index = [], frame.parentJoint
        while index > 0:
            chain.append(index)
            index = model.parents[index]
        joints = []
        for index in reversed(chain):
            joint = model.joints[index]
            axis = _AXES.get(joint.shortname())
            if axis is None or joint.nq != 1 or joint.nv != 1:
                return None
            placement = model.jointPlacements[index]
            joints.append(_Joint(index, int(model.parents[index]), joint.idx_q, joint.idx_v,
                                 axis, placement.rotation.copy(),
                                 placement.translation.copy()))
        return cls(tuple(joints), model.nv, frame.placement.translation.copy())

    def jacobian_rows(self, q: np.ndarray) -> np.ndarray:
        """Return the frame's world-aligned Jacobian at each sample of ``q`` [rad] (n, nq)
        as its rows, (6, nv, n): rows 0-2 map joint velocities to the linear velocity
        [m/s] of the frame's origin, rows 3-5 to the angular velocity [rad/s], world
        axes; the columns of joints that do not carry the frame are 0."""
        n = len(q)
        angles = np.ascontiguousarray(q.T)
        cos, sin = np.cos(angles), np.sin(angles)
        placed: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for joint in self.joints:
            placed[joint.index] = self._place(joint, placed.get(joint.parent),
                                              cos[joint.q_column], sin[joint.q_column])
        rows = np.zeros((6, self.nv, n))
        if not self.joints:
            return rows
        rotation, position = placed[self.joints[-1].index]
        origin = position + _rotate(rotation, self.frame_translation)
        for joint in self.joints:
            rotation, position = placed[joint.index]
            axis = rotation[:, joint.axis]  # (3, n): the joint's axis in world axes
            rows[3:, joint.column] = axis
            rows[:3, joint.column] = _cross(axis, origin - position)
        return rows

    @staticmethod
    def _place(joint: _Joint, parent: tuple[np.ndarray, np.ndarray] | None, cos: np.ndarray,
               sin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return the joint frame's rotation (3, 3, n) and position [m] (3, n) in the
        world at each sample, from its parent's (None: the world) and the cosine and
        sine of its angle (n,)."""
        n = len(cos)
        if parent is None:
            fixed = np.broadcast_to(joint.rotation[:, :, None], (3, 3, n))
            position = np.broadcast_to(joint.translation[:, None], (3, n))
        else:
            above, origin = parent
            fixed = np.matmul(joint.rotation.T, above)  # above @ rotation, per sample
            position = origin + _rotate(above, joint.translation)
        u, v = (joint.axis + 1) % 3, (joint.axis + 2) % 3  # the plane it turns in
        rotation = np.empty((3, 3, n))
        rotation[:, joint.axis] = fixed[:, joint.axis]
        np.multiply(fixed[:, u], cos, out=rotation[:, u])
        rotation[:, u] += fixed[:, v] * sin
        np.multiply(fixed[:, v], cos, out=rotation[:, v])
        rotation[:, v] -= fixed[:, u] * sin
        return rotation, position


def _rotate(rotation: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """Return ``rotation`` (3, 3, n) applied to a fixed ``vector`` (3,), as (3, n)."""
    return (rotation[:, 0] * vector[0] + rotation[:, 1] * vector[1]
            + rotation[:, 2] * vector[2])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the cross product of (3, n) vectors, column by column."""
    return np.stack((a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]))
