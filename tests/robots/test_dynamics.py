"""The Panda model: 7 joints, hand on or off, limits, and consistent dynamics."""

from __future__ import annotations

import numpy as np
import pytest

from contactkit.robots import GAZ_FRICTION, RobotSetup
from contactkit.robots.model import RobotModel

POSE_B = np.array([-1.92, -0.26, 2.72, -1.71, 0.46, 2.8, -1.0])


@pytest.fixture(scope="module", params=[True, False], ids=["hand", "no-hand"])
def model(request) -> RobotModel:
    return RobotModel(RobotSetup(with_hand=request.param))


def test_seven_joints_and_datasheet_limits(model: RobotModel) -> None:
    assert model.model.nq == 7 and model.model.nv == 7
    assert np.allclose(model.limits.tau_max, [87, 87, 87, 87, 12, 12, 12])
    assert np.allclose(model.limits.dq_max, [2.175] * 4 + [2.61] * 3)
    assert np.allclose(model.limits.q_max[5], 3.7525)


def test_hand_adds_its_mass_to_link_7() -> None:
    with_hand, without = RobotModel(RobotSetup()), RobotModel(RobotSetup(with_hand=False))
    extra = with_hand.model.inertias[7].mass - without.model.inertias[7].mass
    assert 0.7 < extra < 0.8
    assert with_hand.urdf_sha256 != without.urdf_sha256


def test_mass_matrix_symmetric_positive_definite(model: RobotModel) -> None:
    m = model.mass_matrix(POSE_B)
    assert np.allclose(m, m.T)
    assert np.linalg.eigvalsh(m).min() > 0


def test_inverse_and_forward_dynamics_agree(model: RobotModel) -> None:
    rng = np.random.default_rng(0)
    dq, ddq = rng.normal(size=7), rng.normal(size=7)
    tau = model.inverse_dynamics(POSE_B, dq, ddq)
    assert np.allclose(model.forward_dynamics(POSE_B, dq, tau), ddq, atol=1e-9)
    c = model.coriolis_matrix(POSE_B, dq)
    expected = model.mass_matrix(POSE_B) @ ddq + c @ dq + model.gravity(POSE_B)
    assert np.allclose(tau, expected, atol=1e-9)


def test_coriolis_skew_symmetry(model: RobotModel) -> None:
    dq = np.linspace(-0.5, 0.5, 7)
    eps = 1e-7
    plus, minus = model.mass_matrix(POSE_B + eps * dq), model.mass_matrix(POSE_B - eps * dq)
    m_dot = (plus - minus) / (2 * eps)
    s = m_dot - 2 * model.coriolis_matrix(POSE_B, dq)
    assert np.abs(s + s.T).max() < 1e-6


def test_point_jacobian_matches_finite_differences(model: RobotModel) -> None:
    point = np.array([0.02, -0.03, 0.05])
    jac = model.point_jacobian(POSE_B, 5, point)

    def position(q):
        return model.frame_placement(q, 5).act(point)

    eps = 1e-7
    numeric = np.column_stack([(position(POSE_B + eps * e) - position(POSE_B - eps * e)) / (2 * eps)
                               for e in np.eye(7)])
    assert np.allclose(jac[:3], numeric, atol=1e-7)
    assert np.allclose(jac[:3, 5:], 0.0)


def test_gravity_torque_scale() -> None:
    model = RobotModel(RobotSetup(with_hand=False))
    g = model.gravity(np.array([0.0, -0.78, 0.0, -2.36, 0.0, 1.57, 0.78]))
    assert abs(g[0]) < 1e-9 and 10 < g[3] < 30


def test_friction_is_zero_at_rest_and_opposes_motion() -> None:
    assert np.allclose(GAZ_FRICTION.torque(np.zeros(7)), 0.0)
    assert (GAZ_FRICTION.torque(np.full(7, 0.5)) > 0).all()
    batch = GAZ_FRICTION.torque(np.full((7, 3), 0.5))
    assert np.allclose(batch[:, 1], GAZ_FRICTION.torque(np.full(7, 0.5)))


def test_friction_of_one_sample_on_floats_equals_the_array_form() -> None:
    dq = np.random.default_rng(0).normal(0.0, 2.0, (200, 7))
    a, b, c, d, e = map(np.array, GAZ_FRICTION.sample_coefficients)
    for row in dq:
        assert np.abs(a * np.tanh(b * (row + c)) + d + e * row
                      - GAZ_FRICTION.torque(row)).max() <= 1e-12
