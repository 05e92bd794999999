"""Momentum observer (thesis eq. 2.16) on a session's actual, irregular time steps.

With generalised momentum p = M(q) dq and u = tau + C^T(q, dq) dq - g(q) - tau_f(dq)
(tau_f only with friction compensation), the observer is

    d/dt p_hat = u + r,        r = K_O (p - p_hat),        p_hat(0) = p(0),

a first-order filter of the external joint torque: dr/dt = K_O (tau_ext - r).
We discretise it implicitly in r and u on each actual step h_k = t_k - t_{k-1}:

    r_k = (r_{k-1} + K_O (p_k - p_{k-1} - h_k u_k)) / (1 + K_O h_k),    r_0 = 0,

which is stable for any step (real logs have 0.7-8.8 ms steps and gaps) and uses
only samples up to k (causal, as on a live robot). C^T dq comes from pinocchio's
exact Coriolis matrix (the one with dM/dt - 2C skew-symmetric).

Sign convention: r estimates the torque that the *environment* applies to the
joints (positive r_i pushes joint i in its positive direction). libfranka's
``tau_ext_hat_filtered`` is defined the other way round (the torque the robot
exerts against the contact), so r ~ -tau_ext_hat_filtered.

Default gain K_O = 50 1/s: a 20 ms time constant (8 Hz bandwidth), fast enough
for a 50 ms bump, slow enough that velocity noise (which enters as K_O M dq) stays
near 0.1-0.4 Nm. Units: r and u in Nm, p in Nm s, K_O in 1/s.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from contactkit.robots import FrictionModel

if TYPE_CHECKING:
    from contactkit.robots.model import RobotModel

DEFAULT_GAIN = 50.0
DDQ_FILTER_GAIN = DEFAULT_GAIN
"""1/s: the first-order low-pass of ddq (20 ms) that the detector's acceleration measure
and the chain's ``tau_dyn`` share, the observer's default K_O: the model error it scales
reaches the residual through the observer's own lag."""
BLOCK_DECAY = np.log(1e-3)


@dataclass(frozen=True)
class ObserverConfig:
    """Observer settings: gain K_O [1/s] (scalar or 7 values) and friction compensation
    with the robot's identified model (where it has one)."""

    gain: float | tuple[float, ...] = DEFAULT_GAIN
    friction: bool = True

    def gain_vector(self) -> np.ndarray:
        """Return K_O as a (7,) array [1/s]."""
        return np.broadcast_to(np.asarray(self.gain, dtype=float), (7,)).copy()

    def friction_model(self, robot: RobotModel) -> FrictionModel | None:
        """Return the friction model used for compensation on ``robot``: its identified
        model (the setup's dynamics', else the robot's) when compensation is on and it
        has one, else None."""
        return robot.friction if self.friction else None


def observer_coefficients(t: np.ndarray, p: np.ndarray, u: np.ndarray, gain: np.ndarray,
                          before: tuple[float, np.ndarray | list[float]] | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Return (a, b) of the recurrence r_k = a_k r_{k-1} + b_k, each (N, 7), for times
    ``t`` (N,) [s], momenta ``p`` [Nm s] and ``u`` [Nm] (N, 7). ``before`` is the time
    [s] and momentum of the sample before the first (a stream solved chunk by chunk):
    every row is then a step from the one before it; without it a_0 = 1, b_0 = 0 so
    that r_0 = 0."""
    if before is None:
        step, dp, u = (t[1:] - t[:-1])[:, None], p[1:] - p[:-1], u[1:]
    else:  # the same differences, without concatenating (a live stream's one sample)
        step = np.empty((len(t), 1))
        step[0, 0] = t[0] - before[0]
        step[1:, 0] = t[1:] - t[:-1]
        dp = np.empty_like(p)
        dp[0] = p[0] - before[1]
        dp[1:] = p[1:] - p[:-1]
    a = 1.0 / (1.0 + gain * step)
    b = gain * (dp - step * u) * a
    if before is None:
        a = np.concatenate((np.ones((1, p.shape[1])), a))
        b = np.concatenate((np.zeros((1, p.shape[1])), b))
    return a, b


def solve_recurrence(a: np.ndarray, b: np.ndarray,
                     r_before: np.ndarray | list[float] | None = None) -> np.ndarray:
    """Solve r_k = a_k r_{k-1} + b_k for (N, 7) arrays, vectorised, from r_{-1} =
    ``r_before`` (zero when omitted; the last r of the previous chunk when a stream is
    solved chunk by chunk). Return r (N, 7), in the units of b.

    Blocks end where the product of the a's has fallen by 1e-3, so the closed form
    r = P (r_start + cumsum(b / P)) inside a block never divides by a tiny P; the
    result matches the sample-by-sample loop to about 1e-13 relative. A broadcast
    ``a`` (one column repeated, as the detector's filters pass it) is taken as its one
    column: the same products, a seventh of the work.
    """
    r_prev = np.zeros(b.shape[1]) if r_before is None else np.asarray(r_before, dtype=float)
    if len(a) == 1:  # the closed form below with one row, without its bookkeeping
        return a * (r_prev + b / a)
    if a.shape[1] > 1 and a.strides[1] == 0:  # one a for every column (a broadcast)
        a = a[:, :1]
    edges = _block_edges(a)
    if not edges.size:
        prod = np.cumprod(a, axis=0)
        return prod * (r_prev + np.cumsum(b / prod, axis=0))
    return _solve_blocks(a, b, r_prev, edges)


def filtered_rate(h: np.ndarray, step: np.ndarray,
                  before: np.ndarray | list[float] | None = None) -> np.ndarray:
    """Return the rate of change of a signal low-passed with :data:`DDQ_FILTER_GAIN` K:
    f_k = (f_{k-1} + K step_k) / (1 + K h_k), for time steps ``h`` (N, 1) [s] and the
    signal's steps ``step`` (N, 7) between consecutive samples, from f_{-1} = ``before``
    (zero when omitted), vectorised (:func:`solve_recurrence`). With dq's steps it is
    the low-passed ddq [rad/s^2] of the detector's acceleration measure and the chain's
    ``tau_dyn``."""
    a = 1.0 / (1.0 + DDQ_FILTER_GAIN * h)
    return solve_recurrence(np.broadcast_to(a, step.shape), DDQ_FILTER_GAIN * step * a,
                            before)


def reduce_rows(ufunc: np.ufunc, x: np.ndarray) -> np.ndarray:
    """Return ``ufunc`` (``np.maximum``, ``np.minimum``) reduced along each row of ``x``
    (n, k >= 1), as (n,), NaN where a row holds one: taken column by column, which for
    rows of seven costs about a fifteenth of NumPy's reduction along them."""
    return functools.reduce(ufunc, x.T[1:], x[:, 0])


def _block_edges(a: np.ndarray) -> np.ndarray:
    """Return the rows (ascending, none 0) where a block of :func:`solve_recurrence`
    starts: where the running sum of the rows' smallest log a crosses a multiple of
    :data:`BLOCK_DECAY`."""
    decay = np.cumsum(reduce_rows(np.minimum, np.log(a)))
    return np.flatnonzero(np.diff(np.floor(decay / BLOCK_DECAY))) + 1


def _solve_blocks(a: np.ndarray, b: np.ndarray, r_prev: np.ndarray, edges: np.ndarray
                  ) -> np.ndarray:
    """Return r of :func:`solve_recurrence` block by block, the blocks starting at 0 and
    at ``edges``, with ``a`` (N, 7) or (N, 1) (one a for every column). Each block is
    solved in place in the result (no temporaries but its products: large ones cost
    page faults)."""
    out = np.empty_like(b)
    for start, stop in itertools.pairwise([0, *edges.tolist(), len(b)]):
        prod = a[start:stop].cumprod(axis=0)
        block = np.divide(b[start:stop], prod, out=out[start:stop])
        block.cumsum(axis=0, out=block)
        block += r_prev
        block *= prod
        r_prev = block[-1]
    return out
