"""A frame's Jacobian vectorised over samples equals pinocchio's, sample by sample."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from contactkit.features.kinematics import FrameKinematics
from contactkit.features.timeseries import ChainConfig, TimeseriesChain
from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel


def pinocchio_rows(model: pin.Model, frame_id: int, q: np.ndarray) -> np.ndarray:
    """The frame's LOCAL_WORLD_ALIGNED Jacobian at each sample, as rows (6, nv, n)."""
    data = model.createData()
    jac = []
    for sample in q:
        pin.computeJointJacobians(model, data, sample)
        pin.updateFramePlacements(model, data)
        jac.append(pin.getFrameJacobian(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED))
    return np.stack(jac, axis=-1)


def random_q(model: pin.Model, n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-3.0, 3.0, (n, model.nq))


@pytest.mark.parametrize("setup", [RobotSetup(), RobotSetup(with_hand=False),
                                   RobotSetup(robot="fr3")], ids=["panda", "no-hand", "fr3"])
@pytest.mark.parametrize("frame", ["ee", 1, 4, 7])
def test_arm_frame_jacobians_equal_pinocchio(setup: RobotSetup, frame: str | int) -> None:
    robot = RobotModel(setup)
    frame_id = robot.frame_id(robot.end_effector if frame == "ee" else frame)
    q = random_q(robot.model, 40)
    rows = FrameKinematics.of(robot.model, frame_id).jacobian_rows(q)
    np.testing.assert_allclose(rows, pinocchio_rows(robot.model, frame_id, q), rtol=0,
                               atol=1e-12)


def test_joints_about_every_axis_equal_pinocchio() -> None:
    """Revolute joints about x, y and z, at random placements, on a branch of a tree
    (a joint that does not carry the frame leaves its column 0)."""
    rng = np.random.default_rng(1)
    model = pin.Model()
    kinds = [pin.JointModelRX, pin.JointModelRY, pin.JointModelRZ, pin.JointModelRY]
    parent = 0
    for i, kind in enumerate(kinds):
        parent = model.addJoint(parent, kind(), pin.SE3.Random(), f"j{i}")
    side = model.addJoint(2, pin.JointModelRZ(), pin.SE3.Random(), "side")
    frame_id = model.addFrame(pin.Frame("tip", parent, pin.SE3.Random(), pin.FrameType.OP_FRAME))
    q = random_q(model, 30, int(rng.integers(100)))
    rows = FrameKinematics.of(model, frame_id).jacobian_rows(q)
    np.testing.assert_allclose(rows, pinocchio_rows(model, frame_id, q), rtol=0, atol=1e-12)
    assert not rows[:, model.joints[side].idx_v].any()


def test_other_joints_leave_the_jacobian_to_pinocchio() -> None:
    model = pin.Model()
    joint = model.addJoint(0, pin.JointModelRevoluteUnaligned(np.array([0.0, 0.6, 0.8])),
                           pin.SE3.Identity(), "j")
    frame_id = model.addFrame(pin.Frame("tip", joint, pin.SE3.Identity(),
                                        pin.FrameType.OP_FRAME))
    assert FrameKinematics.of(model, frame_id) is None


@pytest.mark.parametrize("frame", ["ee", 3])
def test_chain_wrench_equals_pinocchio_jacobians_sample_by_sample(
        monkeypatch: pytest.MonkeyPatch, frame: str | int) -> None:
    """A long chunk's wrench from the vectorised Jacobians equals the one from
    pinocchio's, sample by sample (the path of an arm with other joints): the damped
    solve (lambda = 0.01) magnifies the Jacobians' rounding by at most 1 / lambda^2."""
    chain = TimeseriesChain(ChainConfig(wrench_frame=frame))
    rng = np.random.default_rng(2)
    n = 400
    t = np.arange(n) * 1e-3
    q = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]) + np.cumsum(
        rng.normal(0.0, 1e-3, (n, 7)), axis=0)
    dq = rng.normal(0.0, 0.3, (n, 7))
    tau = rng.normal(0.0, 5.0, (n, 7))
    names = ["f", "m", "fm_norm"]
    vectorised = chain.compute(t, q, dq, tau, names)
    monkeypatch.setattr(chain, "_kinematics", None)
    per_sample = chain.compute(t, q, dq, tau, names)
    scale = np.linalg.norm(np.column_stack([per_sample["f"], per_sample["m"]]), axis=1)
    for name in names:
        error = np.abs(vectorised[name] - per_sample[name]).max(axis=1)
        assert (error <= 1e-11 * np.maximum(scale, 1e-300)).all(), name
