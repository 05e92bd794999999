"""The momentum observer: vectorised recurrence, and r recovering the applied torque."""

from __future__ import annotations

import numpy as np

from contactkit.features.observer import (
    BLOCK_DECAY,
    observer_coefficients,
    solve_recurrence,
)
from contactkit.features.timeseries import TimeseriesChain
from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.schemas import read_session
from tests.conftest import make_session


def test_blocked_scan_equals_sample_loop_on_irregular_steps() -> None:
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.choice([0.0007, 0.001, 0.001, 0.001, 0.0088], size=5000))
    p = np.cumsum(rng.normal(size=(5000, 7)), axis=0) * 0.01
    u = rng.normal(size=(5000, 7))
    gain = np.linspace(20, 80, 7)
    batch = solve_recurrence(*observer_coefficients(t, p, u, gain))
    a, b = observer_coefficients(t, p, u, gain)
    loop, r = np.empty_like(p), None
    for k in range(len(t)):  # one sample at a time, the last r carried
        r = loop[k] = solve_recurrence(a[k:k + 1], b[k:k + 1], r)[0]
    assert np.abs(batch - loop).max() < 1e-9
    assert np.all(batch[0] == 0.0)


def _block_loop(a: np.ndarray, b: np.ndarray, r_prev: np.ndarray) -> np.ndarray:
    """solve_recurrence as first written: one block at a time, each with fresh arrays."""
    out = np.empty_like(b)
    decay = np.cumsum(np.log(a).min(axis=1))
    edges = np.flatnonzero(np.diff(np.floor(decay / BLOCK_DECAY))) + 1
    start = 0
    for stop in [*edges.tolist(), len(a)]:
        prod = np.cumprod(a[start:stop], axis=0)
        out[start:stop] = prod * (r_prev + np.cumsum(b[start:stop] / prod, axis=0))
        r_prev, start = out[stop - 1], stop
    return out


def test_solution_equals_the_block_loop_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    for trial in range(60):
        n = int(rng.integers(2, 2500))
        # steps from 1 us to gaps of 0.3 s: blocks of one sample to thousands
        h = rng.choice([1e-6, 0.0007, 0.001, 0.001, 0.0088, 0.05, 0.3], size=(n, 1))
        a = 1.0 / (1.0 + rng.uniform(1.0, 200.0, size=7) * h)
        if trial % 3 == 0:  # one a for every joint, as the detector's filters pass it
            a = np.broadcast_to(a[:, :1], (n, 7))
        b = rng.normal(size=(n, 7)) * 10.0 ** rng.integers(-3, 3)
        r_before = rng.normal(size=7) if trial % 2 else np.zeros(7)
        expected = _block_loop(a, b, r_before)
        assert np.array_equal(solve_recurrence(a, b, r_before), expected)
        if trial % 2 == 0:
            assert np.array_equal(solve_recurrence(a, b), expected)


def test_residual_estimates_the_applied_joint_torque(tmp_path) -> None:
    session = read_session(make_session(tmp_path, seed=4, action="adjust", link=4,
                                        duration_s=6.0, planned_at_s=2.0, rate_hz=1000.0))
    r = TimeseriesChain().compute(session.t, session.q, session.dq, session.tau,
                                                ["r"])["r"]
    spec = session.meta.simulator["session"]["contact"]
    model = RobotModel(RobotSetup(with_hand=True))
    t = session.t
    hold = (t > spec["onset_s"] + spec["rise_s"] + 0.1) & \
           (t < spec["onset_s"] + spec["rise_s"] + spec["hold_s"] - 0.05)
    k = np.flatnonzero(hold)[hold.sum() // 2]
    force = np.array([session.column(c)[k] for c in ("f_ext_x", "f_ext_y", "f_ext_z")])
    jac = model.point_jacobian(session.q[k], spec["link"], np.array(spec["point_local"]))
    applied = jac[:3].T @ force
    before = r[(t > 1.0) & (t < 1.9)].mean(axis=0)
    estimated = r[hold].mean(axis=0) - before
    assert np.linalg.norm(applied) > 1.0
    assert np.linalg.norm(estimated - applied) < 0.15 * np.linalg.norm(applied) + 0.3
    assert np.dot(estimated, applied) > 0
