"""Identify an arm's own dynamics from free motion: link inertias, armature, friction,
the payload at the flange, and the detector's thresholds with that model.

A library a notebook can call (:func:`identify` on arrays, :func:`identify_sessions` on
session files), behind ``recorder identify``. It reads only t, q, dq and tau and the
arm's name and hand: nothing comes from a simulated session's own parameters.

Method:

1. Each session is cut at gaps (a single session's last :data:`HOLDOUT`, 25 %, is kept
   back for the detector, step 5). dq and tau are low-passed without phase (4th-order
   Butterworth at :data:`CUTOFF_HZ`, forward and backward, ``scipy.signal.sosfiltfilt``)
   after linear interpolation onto a uniform grid at the median time step (a host's time
   stamps jitter, and dropped samples leave holes), ddq is the filtered dq differenced
   on that grid, the filters' ends are cut, and the samples are thinned to about
   :data:`IDENT_RATE_HZ`.
2. The model is linear in its parameters: tau = Y(q, dq, ddq) theta + F(dq, ddq) phi,
   Y pinocchio's joint-torque regressor (10 parameters per link, their full values),
   F per joint a friction sigmoid of fixed shape (Gaz et al.'s phi2 and phi3 for a
   robot that has them, else a Coulomb step with phi2 = :data:`COULOMB_PHI2`), a viscous
   term dq and the armature ddq, plus a free constant per session and joint (a torque
   sensor's offset moves between sessions; the simulator draws one per session too):
   each session's samples are centred on their means. The normal equations are summed
   chunk by chunk per joint, so memory does not grow with the data. The offset stored
   is the sessions' mean where they agree (:meth:`_Normal.offset`).
3. The fit is regularised toward the nominal model (a Gaussian prior on every
   parameter, centred on the nominal value with a per-parameter scale
   :func:`prior_scales`), with each joint's residual weighted by its own noise level
   (two passes). Directions the motion does not excite keep their nominal values; a
   parameter counts as *determined* when the data shrink its prior's variance at
   least four-fold (:data:`DETERMINED`). The condition number of the whitened
   regressor over the determined directions is reported. With two sessions or more,
   the prior's strength is chosen leave-one-session-out (:func:`_choose_pull`): its
   scales times each factor of :data:`PULLS`, the one whose fits of the other sessions
   predict each left-out session's fitted samples best (on the two real FR3 recordings
   and the two halves of the Gaz et al. log, a four-fold stronger pull than the
   scales' own lowered that out-of-session residual by about a fifth; in simulation,
   with 2 minutes of motion, it changed nothing). The file records it
   (``method.prior_pull``). One session keeps the scales' own.
4. Where the fit leaves a link physically inconsistent (its 4x4 pseudo-inertia not
   positive semi-definite), the fit is solved again under the constraint: the nearest
   consistent parameters in the fit's own quadratic cost, those links parameterised by
   the log-Cholesky factors of their pseudo-inertia (:func:`_consistent_fit`), so the
   result is physically consistent.
5. The detector is calibrated (:func:`contactkit.features.detector.calibrate`, margin
   1.5) on residuals of motion the fit did not see. With two sessions or more,
   leave-one-session-out: each session's whole residual with the model identified
   from the other sessions (same settings); what the detector must absorb on an arm is
   how a fit carries over to another recording, and a tail of the same recording does
   not show it (on the real FR3, identified on one ~10 s recording, the tail-calibrated
   detector gave a false contact on the other). The final fit then uses every session
   whole. A fold whose other sessions determine nothing leaves its session out of the
   calibration; when every fold does, the single session's rule applies to each. With
   one session: its last :data:`HOLDOUT`, with the model fitted to the rest, which is
   also the model returned (cutting one recording into blocks moved the FR3's false
   contact from one recording to the other, so it is not done). The file records which
   (``method.held_out`` in its provenance, ``held_out`` in the detector's source).

6. Around contacts (``identify_sessions(around_contacts=...)``, ``recorder identify
   --around-contacts``): for a dataset without free-motion recordings, every session is
   used outside the contacts a detector finds with the nominal model
   (:func:`motion_around_contacts`; labels and contact columns are not read), and the
   detector's calibration leaves out what stands out of the held-out residuals
   (:func:`contactkit.features.detector.drop_outliers`), a touch that detector missed.
   On simulated ``thesis-dynamic`` datasets of robot instances the default model never
   saw, cross-fitted over poses, it found more of their contacts than the nominal model
   (docs/results.md, "With the arm identified from the dataset itself").

Units: t [s], q [rad], dq [rad/s], ddq [rad/s^2], tau [Nm].
"""

from __future__ import annotations

import hashlib
import itertools
import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np
import pinocchio as pin

from contactkit.errors import DATA_ERRORS, InputError, problem_text
from contactkit.robots import N_JOINTS, RobotSetup, get_robot
from contactkit.robots.dynamics import (
    PARAMETER_NAMES,
    ArmDynamics,
    Payload,
    consistent,
    from_pseudo_inertia,
    pseudo_inertia,
)
from contactkit.robots.model import RobotModel

if TYPE_CHECKING:
    from contactkit.features.detector import DetectorConfig
    from contactkit.schemas import Session

log = logging.getLogger(__name__)

CUTOFF_HZ = 10.0
"""The low-pass cut-off for dq and tau [Hz]: above the arm's motion, below most noise."""
IDENT_RATE_HZ = 100.0
"""About how many samples per second the fit uses after filtering [Hz]."""
HOLDOUT = 0.25
"""The share of each session's end kept back to calibrate the detector."""
EDGE_S = 0.2
"""Time cut from both ends of each filtered stretch [s] (the filter's transients)."""
GAP_FACTOR = 5.0
"""A step longer than this many median steps cuts a session into stretches."""
MIN_MOTION_RAD_S = 0.05
"""A joint counts as moving when its filtered speed exceeds this somewhere [rad/s]."""
MIN_SAMPLES = 200
"""The fewest fitted samples (some 2 s at :data:`IDENT_RATE_HZ`) that identify anything."""
COULOMB_PHI2 = 20.0
"""phi2 [s/rad] of the Coulomb sigmoid fitted on a robot without identified friction."""
NOISE_NM = 0.5
"""The torque residual's assumed noise on the first pass [Nm] (the second uses the
first's per-joint RMS, no less than :data:`MIN_NOISE_NM`)."""
MIN_NOISE_NM = 0.05
DETERMINED = 0.25
"""A parameter is determined when its posterior variance is below this share of its
prior's."""
CORRELATION = 2.0
"""How many fitted samples count as one independent one (filtered, then thinned)."""
N_FRICTION = 3  # per joint: sigmoid amplitude, viscous, armature
N_LINK = len(PARAMETER_NAMES)


@dataclass
class Motion:
    """One session's free motion: ``t`` (N,) [s], ``q`` [rad], ``dq`` [rad/s] and ``tau``
    [Nm] (N, 7), and its ``name`` (for messages)."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    name: str = ""


@dataclass
class Excitation:
    """What the data determine: ``determined`` / ``undetermined`` parameter names,
    ``directions`` how many directions of the whitened regressor the data fix better
    than the prior, ``condition`` the whitened regressor's condition number over them,
    ``samples`` the samples fitted, ``moving`` the joints that moved (1-based),
    ``projected`` links whose fit was projected to be physically consistent, ``rms_nm``
    the fitted residual's RMS per joint [Nm] before (nominal model) and after."""

    determined: list[str]
    undetermined: list[str]
    directions: int
    condition: float
    samples: int
    moving: list[int]
    projected: list[int] = field(default_factory=list)
    rms_before_nm: list[float] = field(default_factory=list)
    rms_after_nm: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        """Return the report as a JSON-ready dictionary."""
        return {"determined": self.determined, "undetermined": self.undetermined,
                "directions": self.directions,
                "condition": round(self.condition, 3) if np.isfinite(self.condition) else None,
                "samples": self.samples, "moving_joints": self.moving,
                "projected_links": self.projected,
                "rms_before_nm": [round(v, 4) for v in self.rms_before_nm],
                "rms_after_nm": [round(v, 4) for v in self.rms_after_nm]}


@dataclass
class Identified:
    """The result: the ``dynamics`` (file content) and the ``excitation`` report."""

    dynamics: ArmDynamics
    excitation: Excitation


def parameter_names() -> list[str]:
    """Return the names of the fitted parameters, in the fit's order: each link's 10
    (``link3.I_zz``), then per joint the friction sigmoid's amplitude, viscous and
    armature (``joint2.viscous``)."""
    links = [f"link{i}.{n}" for i in range(1, N_JOINTS + 1) for n in PARAMETER_NAMES]
    joints = [f"joint{j}.{n}" for j in range(1, N_JOINTS + 1)
              for n in ("friction", "viscous", "armature")]
    return links + joints


def _stretches(t: np.ndarray) -> list[slice]:
    """Return the stretches of ``t`` between gaps (steps over GAP_FACTOR median steps)."""
    step = np.diff(t)
    cut = np.flatnonzero(step > GAP_FACTOR * np.median(step)) + 1
    bounds = [0, *cut.tolist(), len(t)]
    return [slice(a, b) for a, b in itertools.pairwise(bounds)]


def _resample(grid: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Return ``values`` (n, 7) sampled at times ``t`` interpolated linearly at ``grid``."""
    return np.column_stack([np.interp(grid, t, column) for column in values.T])


def prepare(motion: Motion) -> tuple[np.ndarray, ...]:
    """Return the fit's samples of one motion: (q, dq, ddq, tau), each (n, 7), resampled
    on a uniform grid at the median step (a host's time stamps jitter), low-passed
    without phase, differenced, ends cut and thinned (see the module's docstring); empty
    arrays when the motion is too short."""
    from scipy.signal import butter, sosfiltfilt

    parts: list[tuple[np.ndarray, ...]] = []
    for piece in _stretches(motion.t):
        t = motion.t[piece]
        if len(t) < 50:
            continue
        step = float(np.median(np.diff(t)))
        rate = 1.0 / step
        edge = int(EDGE_S * rate)
        if len(t) <= 2 * edge + 20 or 0.45 * rate <= CUTOFF_HZ:
            continue
        grid = t[0] + step * np.arange(int((t[-1] - t[0]) / step) + 1)
        sos = butter(4, CUTOFF_HZ, fs=rate, output="sos")
        q, dq, tau = (sosfiltfilt(sos, _resample(grid, t, x[piece]), axis=0)
                      for x in (motion.q, motion.dq, motion.tau))
        ddq = np.gradient(dq, step, axis=0)
        keep = slice(edge, len(grid) - edge, max(1, round(rate / IDENT_RATE_HZ)))
        parts.append(tuple(x[keep] for x in (q, dq, ddq, tau)))
    if not parts:
        return tuple(np.zeros((0, N_JOINTS)) for _ in range(4))
    return tuple(np.concatenate(column) for column in zip(*parts, strict=True))


def _friction_shape(setup: RobotSetup) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the friction sigmoid's fixed (phi2, phi3) and the prior amplitude phi1."""
    friction = get_robot(setup.robot).friction
    if friction is None:
        return np.full(N_JOINTS, COULOMB_PHI2), np.zeros(N_JOINTS), np.zeros(N_JOINTS)
    return friction.phi2.copy(), friction.phi3.copy(), friction.phi1.copy()


def _sigmoid_shape(dq: np.ndarray, phi2: np.ndarray, phi3: np.ndarray) -> np.ndarray:
    """The friction sigmoid with unit amplitude, zero at rest."""
    return 0.5 * (np.tanh(0.5 * phi2 * (dq + phi3)) - np.tanh(0.5 * phi2 * phi3))


def prior_scales(nominal: np.ndarray) -> np.ndarray:
    """Return the prior's standard deviation of every fitted parameter
    (:func:`parameter_names`' order) around the ``nominal`` values: 30 % of a link's
    mass (at least 0.1 kg), its mass times 5 cm for a first moment, 30 % of its largest
    inertia entry (at least 0.005 kg m^2) for an inertia; 1 Nm for friction amplitudes,
    1 Nm s/rad viscous, 0.05 kg m^2 armature."""
    scales = np.empty_like(nominal)
    for i in range(N_JOINTS):
        link = nominal[i * N_LINK:(i + 1) * N_LINK]
        mass = max(abs(link[0]), 0.3)
        scales[i * N_LINK] = max(0.3 * abs(link[0]), 0.1)
        scales[i * N_LINK + 1:i * N_LINK + 4] = 0.05 * mass
        scales[i * N_LINK + 4:(i + 1) * N_LINK] = max(0.3 * np.abs(link[4:]).max(), 0.005)
    joints = scales[N_JOINTS * N_LINK:].reshape(N_JOINTS, N_FRICTION)
    joints[:] = (1.0, 1.0, 0.05)
    return scales


class _Normal:
    """Per-joint normal equations with a free constant per session and joint (a torque
    sensor's offset, which moves between sessions): sums of Y_j^T Y_j, Y_j^T tau_j and
    tau_j^2 over each session's samples, centred on the session's means, for the
    regressor row Y_j of joint j. The sessions' means are kept to recover the
    offsets."""

    def __init__(self, size: int) -> None:
        self.a = np.zeros((N_JOINTS, size, size))
        self.b = np.zeros((N_JOINTS, size))
        self.c = np.zeros(N_JOINTS)
        self.n = 0
        self.means: list[tuple[np.ndarray, np.ndarray]] = []
        self._rows = np.zeros((N_JOINTS, size))
        self._tau = np.zeros(N_JOINTS)
        self._n = 0

    def add(self, rows: np.ndarray, tau: np.ndarray) -> None:
        """Add samples of the current session: ``rows`` (n, 7, size) regressor rows,
        ``tau`` (n, 7) [Nm]."""
        self.a += np.einsum("njp,njq->jpq", rows, rows)
        self.b += np.einsum("njp,nj->jp", rows, tau)
        self.c += (tau ** 2).sum(axis=0)
        self._rows += rows.sum(axis=0)
        self._tau += tau.sum(axis=0)
        self._n += len(tau)

    def end_session(self) -> None:
        """Centre the current session's sums on its means (sum of (y - m)(y - m)^T =
        sum of y y^T - n m m^T) and start the next."""
        if self._n:
            rows, tau = self._rows / self._n, self._tau / self._n
            self.a -= self._n * np.einsum("jp,jq->jpq", rows, rows)
            self.b -= self._n * rows * tau[:, None]
            self.c -= self._n * tau ** 2
            self.n += self._n
            self.means.append((rows, tau))
        self._rows, self._tau, self._n = np.zeros_like(self._rows), np.zeros(N_JOINTS), 0

    @staticmethod
    def merge(parts: Sequence[_Normal]) -> _Normal:
        """Return the normal equations of the sessions of ``parts`` together."""
        merged = _Normal(parts[0].a.shape[1])
        for part in parts:
            merged.a += part.a
            merged.b += part.b
            merged.c += part.c
            merged.n += part.n
            merged.means += part.means
        return merged

    def without(self, part: _Normal, first: int) -> _Normal:
        """Return these merged normal equations less those of ``part``, whose sessions'
        means begin at index ``first`` of :attr:`means`: a leave-one-session-out fit's,
        in time linear in the sessions (merging the others anew is quadratic)."""
        out = _Normal(self.a.shape[1])
        out.a, out.b, out.c = self.a - part.a, self.b - part.b, self.c - part.c
        out.n = self.n - part.n
        out.means = self.means[:first] + self.means[first + len(part.means):]
        return out

    def rms(self, theta: np.ndarray) -> np.ndarray:
        """The RMS per joint [Nm] of the residual tau - Y theta, each session's mean
        removed."""
        sq = (self.c - 2 * self.b @ theta + np.einsum("p,jpq,q->j", theta, self.a, theta))
        return np.sqrt(np.maximum(sq, 0.0) / max(self.n, 1))

    def offset(self, theta: np.ndarray) -> np.ndarray:
        """Return the torque offset per joint [Nm] the model keeps: the mean of the
        sessions' own offsets (each session's mean residual). The model's constant part
        cannot be told from a session's offset, so it is kept; but with three sessions
        or more, a joint whose offsets scatter more than their mean (twice its standard
        error) gets 0: offsets that come and go with the sessions, as a torque sensor's
        bias after a restart, are no property of the arm."""
        each = np.array([tau - rows @ theta for rows, tau in self.means])
        mean = each.mean(axis=0)
        if len(each) < 3:
            return mean
        error = each.std(axis=0, ddof=1) / np.sqrt(len(each))
        return np.where(np.abs(mean) > 2.0 * error, mean, 0.0)


def _rows(model: pin.Model, data: pin.Data, q: np.ndarray, dq: np.ndarray,
          ddq: np.ndarray, phi2: np.ndarray, phi3: np.ndarray) -> np.ndarray:
    """Return the regressor rows (n, 7, 91) of samples (q, dq, ddq) (n, 7)."""
    n = len(q)
    size = N_JOINTS * (N_LINK + N_FRICTION)
    rows = np.zeros((n, N_JOINTS, size))
    for k in range(n):
        rows[k, :, :N_JOINTS * N_LINK] = pin.computeJointTorqueRegressor(
            model, data, q[k], dq[k], ddq[k])
    base = N_JOINTS * N_LINK
    joint = np.arange(N_JOINTS)
    rows[:, joint, base + N_FRICTION * joint] = _sigmoid_shape(dq, phi2, phi3)
    rows[:, joint, base + N_FRICTION * joint + 1] = dq
    rows[:, joint, base + N_FRICTION * joint + 2] = ddq
    return rows


def _solve(normal: _Normal, weights: np.ndarray, prior: np.ndarray, scales: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the regularised estimate, the matrix of its quadratic cost (information
    plus prior) and the whitened information matrix S A S."""
    a = np.einsum("j,jpq->pq", weights, normal.a) / CORRELATION
    b = np.einsum("j,jp->p", weights, normal.b) / CORRELATION
    lhs = a + np.diag(1.0 / scales ** 2)
    theta = np.linalg.solve(lhs, b + prior / scales ** 2)
    return theta, lhs, scales[:, None] * a * scales[None, :]


_STRICT_LOWER = np.tril_indices(4, -1)
"""The entries below the diagonal of a 4x4 matrix, in the order of the log-Cholesky
coordinates' last six."""


def _cholesky_factors(link: np.ndarray) -> np.ndarray:
    """Return the 10 log-Cholesky coordinates of a consistent link (its pseudo-inertia,
    nudged to be positive definite, = L L^T: log of L's diagonal, then its lower part)."""
    pseudo = pseudo_inertia(link)
    lower = np.linalg.cholesky(pseudo + 1e-9 * max(np.trace(pseudo), 1e-9) * np.eye(4))
    return np.concatenate([np.log(np.diag(lower)), lower[_STRICT_LOWER]])


def _lower_factor(factors: np.ndarray) -> np.ndarray:
    """Return the lower-triangular L of log-Cholesky coordinates."""
    lower = np.diag(np.exp(factors[:4]))
    lower[_STRICT_LOWER] = factors[4:]
    return lower


def _from_factors(factors: np.ndarray) -> np.ndarray:
    """Return the 10 parameters of log-Cholesky coordinates (always consistent)."""
    lower = _lower_factor(factors)
    return from_pseudo_inertia(lower @ lower.T)


def _factors_jacobian(factors: np.ndarray) -> np.ndarray:
    """Return d(parameters)/d(factors) (10x10) of :func:`_from_factors` at ``factors``,
    exactly: the parameters are linear in P = L L^T, and dP = dL L^T + L dL^T, where a
    diagonal coordinate moves L_ii by L_ii and a lower one its entry by 1."""
    lower = _lower_factor(factors)
    moves = np.zeros((N_LINK, 4, 4))
    diagonal = np.arange(4)
    moves[diagonal, diagonal, diagonal] = np.diag(lower)
    moves[np.arange(4, N_LINK), *_STRICT_LOWER] = 1.0
    spread = moves @ lower.T
    return from_pseudo_inertia(spread + spread.transpose(0, 2, 1)).T


def _consistent_fit(theta: np.ndarray, cost: np.ndarray, nominal: np.ndarray
                    ) -> tuple[np.ndarray, list[int]]:
    """Return the physically consistent parameters nearest (in the fit's own cost,
    (x - theta)^T cost (x - theta)) to the unconstrained fit ``theta``, and the links
    (0-based) that the constraint moved.

    The links that the fit leaves inconsistent are parameterised by the log-Cholesky
    factors of their pseudo-inertia (Rucker and Wensing 2022), so every iterate is
    consistent; the other parameters, linear, are eliminated in closed form (the
    Schur complement of the cost), and the rest is a small nonlinear least-squares
    problem, solved by Levenberg-Marquardt from those links' nominal values. Moving
    those links moves the others (the eliminated parameters follow them): a link that
    this leaves inconsistent joins them and the fit is solved again."""
    bad: list[int] = []
    fitted = theta
    while True:
        more = [i for i in range(N_JOINTS)
                if i not in bad and not consistent(fitted[i * N_LINK:(i + 1) * N_LINK])]
        if not more:
            return fitted, sorted(bad)
        bad = sorted(bad + more)
        fitted = _fit_links(theta, cost, nominal, bad)


def _fit_links(theta: np.ndarray, cost: np.ndarray, nominal: np.ndarray, bad: list[int]
               ) -> np.ndarray:
    """Return :func:`_consistent_fit`'s solution with the links ``bad`` parameterised by
    their log-Cholesky factors."""
    held = np.zeros(len(theta), bool)
    for i in bad:
        held[i * N_LINK:(i + 1) * N_LINK] = True
    free = ~held
    coupling = np.linalg.solve(cost[np.ix_(free, free)], cost[np.ix_(free, held)])
    schur = cost[np.ix_(held, held)] - cost[np.ix_(held, free)] @ coupling
    root = np.linalg.cholesky(0.5 * (schur + schur.T)).T  # schur = root^T root
    target = theta[held]

    def params(factors: np.ndarray) -> np.ndarray:
        return np.concatenate([_from_factors(f) for f in factors.reshape(-1, N_LINK)])

    def jacobian(factors: np.ndarray) -> np.ndarray:
        jac = np.zeros((len(factors), len(factors)))
        for k, f in enumerate(factors.reshape(-1, N_LINK)):
            jac[k * N_LINK:(k + 1) * N_LINK, k * N_LINK:(k + 1) * N_LINK] = (
                _factors_jacobian(f))
        return root @ jac

    starts = [nominal[i] if consistent(nominal[i])
              else _project(theta[i * N_LINK:(i + 1) * N_LINK]) for i in bad]
    factors = np.concatenate([_cholesky_factors(x) for x in starts])
    residual = root @ (params(factors) - target)
    damping = 1e-3
    for _ in range(200):
        jac = jacobian(factors)
        normal = jac.T @ jac
        # least squares, not solve: a factor the cost no longer feels (a vanishing
        # diagonal of the Cholesky factor) leaves the damped matrix singular
        step = np.linalg.lstsq(normal + damping * np.diag(np.diag(normal) + 1e-12),
                               -jac.T @ residual, rcond=None)[0]
        with np.errstate(over="ignore", invalid="ignore"):  # a wild step: rejected below
            trial = root @ (params(factors + step) - target)
            better = bool(np.isfinite(trial).all() and trial @ trial < residual @ residual)
        if better:
            gain = residual @ residual - trial @ trial
            factors, residual, damping = factors + step, trial, damping / 3
            if gain < 1e-10 * (1.0 + residual @ residual):
                break
        else:
            damping *= 4
            if damping > 1e10:
                break
    out = theta.copy()
    out[held] = params(factors)
    out[free] = theta[free] - coupling @ (out[held] - target)
    return out


def _project(link: np.ndarray) -> np.ndarray:
    """Return one link's parameters with the pseudo-inertia's eigenvalues clipped to be
    positive (at 1e-6 of the largest): a start for a link whose nominal values are not
    consistent either."""
    values, vectors = np.linalg.eigh(pseudo_inertia(link))
    floor = 1e-6 * max(values[-1], 1e-9)
    return from_pseudo_inertia((vectors * np.maximum(values, floor)) @ vectors.T)


def _payload(model: RobotModel, nominal: np.ndarray, identified: np.ndarray) -> Payload:
    """Return what the identification put at the flange: link 7's identified minus
    nominal parameters, at the flange (see :class:`~contactkit.robots.dynamics.Payload`)."""
    delta = identified - nominal
    mass = float(delta[0])
    flange = model.model.frames[model.frame_id(model.spec.flange)].placement
    rotation, origin = flange.rotation, flange.translation
    inertia = pseudo_inertia(delta)
    inertia = np.trace(inertia[:3, :3]) * np.eye(3) - inertia[:3, :3]  # about joint origin
    if abs(mass) < 1e-6:
        return Payload(mass, (0.0, 0.0, 0.0), (0.0,) * 6)
    com = delta[1:4] / mass
    skew = np.array([[0, -com[2], com[1]], [com[2], 0, -com[0]], [-com[1], com[0], 0]])
    at_com = rotation.T @ (inertia + mass * skew @ skew) @ rotation
    com_flange = rotation.T @ (com - origin)
    return Payload(mass, cast("tuple[float, float, float]", tuple(float(v) for v in com_flange)),
                   tuple(float(at_com[i, j]) for i, j in
                         ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))))


def _session_normal(motion: Motion, regress: pin.Model, data: pin.Data, phi2: np.ndarray,
                    phi3: np.ndarray, size: int) -> tuple[_Normal, np.ndarray]:
    """Return one motion's normal equations (:class:`_Normal`, one session) and which
    joints moved in it (7,) bool."""
    q, dq, ddq, tau = prepare(motion)
    normal = _Normal(size)
    for start in range(0, len(q), 2000):
        chunk = slice(start, start + 2000)
        normal.add(_rows(regress, data, q[chunk], dq[chunk], ddq[chunk], phi2, phi3),
                   tau[chunk])
    normal.end_session()
    moving = (np.abs(dq).max(axis=0) > MIN_MOTION_RAD_S if len(q)
              else np.zeros(N_JOINTS, bool))
    return normal, moving


class _Sessions:
    """The sessions' normal equations (:func:`_session_normal`'s ``parts``), merged
    once: all of them (:meth:`merged`) or all but one (:meth:`others`)."""

    def __init__(self, parts: Sequence[tuple[_Normal, np.ndarray]]) -> None:
        self.parts = list(parts)
        self.total = _Normal.merge([normal for normal, _ in self.parts])
        self.moving_count = np.sum([moving for _, moving in self.parts], axis=0)
        self.first = np.cumsum([0, *(len(normal.means) for normal, _ in self.parts)])

    def merged(self) -> tuple[_Normal, np.ndarray]:
        """Return every session's normal equations together, and the joints any moved."""
        return self.total, self.moving_count > 0

    def others(self, i: int) -> tuple[_Normal, np.ndarray]:
        """Return the normal equations of every session but the ``i``-th, and the joints
        they moved."""
        normal, moving = self.parts[i]
        return (self.total.without(normal, int(self.first[i])),
                self.moving_count - moving > 0)


def _fit(sessions: tuple[_Normal, np.ndarray], prior: np.ndarray, scales: np.ndarray,
         nominal_links: np.ndarray, pull: float = 1.0, project: bool = True
         ) -> tuple[np.ndarray, _Normal, Excitation]:
    """Fit the sessions' merged normal equations and the joints they moved
    (:class:`_Sessions`) with the prior's scales ``scales`` times ``pull`` (below 1 a
    stronger pull toward the nominal model): return the parameters used (armature and
    viscous friction not negative), those normal equations and the :class:`Excitation`
    report (what the data determine against the prior's own ``scales``). Raises
    InputError (one line) when the motion determines nothing. Without ``project`` the
    fit is not made physically consistent (:func:`_consistent_fit`: the costly step;
    for :func:`_choose_pull`)."""
    normal, moving = sessions
    if normal.n < MIN_SAMPLES:
        raise InputError(f"too little free motion to identify from ({normal.n / IDENT_RATE_HZ:.1f}"
                         f" s after filtering; at least {MIN_SAMPLES / IDENT_RATE_HZ:.0f} s of "
                         "moving joints needed)")
    if not moving.any():
        raise InputError(f"no joint moves faster than {MIN_MOTION_RAD_S} rad/s: identifying "
                         "needs free motion of the joints (record the arm moving)")
    rms_before = normal.rms(prior)
    weights = np.full(N_JOINTS, 1.0 / NOISE_NM ** 2)
    theta, _, _ = _solve(normal, weights, prior, pull * scales)
    weights = 1.0 / np.maximum(normal.rms(theta), MIN_NOISE_NM) ** 2
    theta, cost, information = _solve(normal, weights, prior, pull * scales)
    information = information / pull ** 2  # whitened by the prior's own scales
    theta, projected = (_consistent_fit(theta, cost, nominal_links) if project
                        else (theta, []))
    eig = np.linalg.eigvalsh(information)
    variance = np.diag(np.linalg.inv(information + np.eye(len(prior))))
    names = parameter_names()
    determined = [n for n, v in zip(names, variance, strict=True) if v < DETERMINED]
    strong = eig[eig > 1.0]
    condition = float(np.sqrt(strong.max() / strong.min())) if strong.size else float("inf")
    if not determined:
        raise InputError("the motion determines no parameter: move more joints, faster and "
                         "over a wider range (an exciting trajectory)")
    theta_used = theta.copy()
    base = N_JOINTS * N_LINK
    theta_used[base + 1::N_FRICTION] = np.maximum(theta[base + 1::N_FRICTION], 0.0)
    theta_used[base + 2::N_FRICTION] = np.maximum(theta[base + 2::N_FRICTION], 0.0)
    excitation = Excitation(
        determined=determined, undetermined=[n for n in names if n not in determined],
        directions=int(strong.size), condition=condition, samples=normal.n,
        moving=[int(j) + 1 for j in np.flatnonzero(moving)],
        projected=[i + 1 for i in projected],
        rms_before_nm=rms_before.tolist(),
        rms_after_nm=normal.rms(theta_used).tolist())
    return theta_used, normal, excitation


def _head(motion: Motion) -> Motion:
    """The motion less its last :data:`HOLDOUT` share (the single session's fit)."""
    split = round(len(motion.t) * (1.0 - HOLDOUT))
    return Motion(motion.t[:split], motion.q[:split], motion.dq[:split], motion.tau[:split],
                  motion.name)


def _tail(motion: Motion) -> Motion:
    """The motion's last :data:`HOLDOUT` share (the single session's held-out part)."""
    split = round(len(motion.t) * (1.0 - HOLDOUT))
    return Motion(motion.t[split:], motion.q[split:], motion.dq[split:], motion.tau[split:],
                  motion.name)


def identify(motions: Sequence[Motion], setup: RobotSetup, *,
             provenance: dict | None = None, calibrate_detector: bool = True,
             outliers: bool = False,
             progress: Callable[[int, int], None] | None = None) -> Identified:
    """Identify the dynamics of ``setup``'s arm (its nominal model the prior) from
    ``motions``, free motion with nobody touching the arm. ``provenance`` is stored with
    the result (sessions, hashes); ``calibrate_detector`` calibrates the detector on
    held-out motion: with two sessions or more, each session's residual with the model
    identified from the others (leave-one-session-out), and the final fit uses every
    session whole; with one session, its last :data:`HOLDOUT` with the model fitted to
    the rest (see the module's docstring); with ``outliers``, what stands out of the
    held-out residuals is left out of that calibration
    (:func:`~contactkit.features.detector.drop_outliers`: for motion cut out of sessions
    with contact, which may hold a touch the detector missed). ``progress(done,
    total)`` counts motions: one step as each one's regressor is summed, and with the
    leave-one-session-out calibration one more as each one's held-out fit is made.

    Returns the :class:`Identified`. Raises InputError (one line) when the motion
    determines nothing: no joint moving, or too little of it."""
    setup = replace(setup, dynamics=None)
    model = RobotModel(setup)
    regress = pin.Model(model.model)
    regress.armature[:] = 0.0
    data = regress.createData()
    phi2, phi3, phi1 = _friction_shape(setup)
    nominal_links = np.array([regress.inertias[j].toDynamicParameters()
                              for j in range(1, N_JOINTS + 1)])
    prior = np.concatenate([nominal_links.ravel(),
                            np.column_stack([phi1, np.zeros((N_JOINTS, 2))]).ravel()])
    scales = prior_scales(prior)
    started = time.perf_counter()
    whole = len(motions) >= 2
    steps = len(motions) * (2 if whole and calibrate_detector else 1)

    def normals(pieces: Sequence[Motion], report: bool = True
                ) -> list[tuple[_Normal, np.ndarray]]:
        parts = []
        for done, piece in enumerate(pieces, 1):
            parts.append(_session_normal(piece, regress, data, phi2, phi3, len(prior)))
            if progress is not None and report:
                progress(done, steps)
        return parts

    def fit(sessions: tuple[_Normal, np.ndarray], pull: float, project: bool = True
            ) -> tuple[np.ndarray, _Normal, Excitation]:
        return _fit(sessions, prior, scales, nominal_links, pull, project)

    def arm(fitted: tuple[np.ndarray, _Normal, Excitation]) -> ArmDynamics:
        return _arm_dynamics(fitted[0], fitted[1], model, phi2, phi3, nominal_links)

    parts = _Sessions(normals(motions if whole else [_head(m) for m in motions]))
    folds: list[tuple[Motion, ArmDynamics]] = []
    pull = 1.0
    if whole:
        pull = _choose_pull(parts.parts,
                            lambda i, k: fit(parts.others(i), k, project=False)[0])
    if whole and calibrate_detector:
        for i, motion in enumerate(motions):
            try:
                folds.append((motion, arm(fit(parts.others(i), pull))))
            except InputError as err:  # the other sessions alone determine nothing
                log.info("%s left out of the detector's calibration: %s", motion.name,
                         err.problem)
            if progress is not None:
                progress(len(motions) + i + 1, steps)
        if not folds:
            log.info("no session's residual with the others' fit: the detector is "
                     "calibrated on each session's last %.0f %%", 100 * HOLDOUT)
            whole, pull = False, 1.0
            parts = _Sessions(normals([_head(m) for m in motions], report=False))
    final = fit(parts.merged(), pull)
    dynamics, excitation = arm(final), final[2]
    method = _method(LEAVE_ONE_OUT if whole else TAIL) | {"prior_pull": pull}
    doc = dict(provenance or {})
    doc.update(excitation=excitation.to_dict(), method=method,
               fit_seconds=round(time.perf_counter() - started, 3))
    dynamics = replace(dynamics, provenance=json.dumps(doc, sort_keys=True))
    if calibrate_detector:
        source: dict = {"held_out": method["held_out"]}
        if whole:
            held_out = folds
            source["sessions"] = len(folds)
        else:
            held_out = [(_tail(m), dynamics) for m in motions]
            source["share"] = HOLDOUT
        dynamics = replace(dynamics, detector=_detector(held_out, setup, source, outliers))
    return Identified(dynamics, excitation)


PULLS = (0.125, 0.25, 0.5, 1.0, 2.0)
"""The prior's strengths tried with two sessions or more: factors on its scales
(:func:`prior_scales`); below 1 a stronger pull toward the nominal model."""


def _choose_pull(parts: Sequence[tuple[_Normal, np.ndarray]],
                 fit: Callable[[int, float], np.ndarray]) -> float:
    """Return the prior's strength (of :data:`PULLS`) whose leave-one-session-out fits
    (``fit(i, pull)``, the parameters fitted to every session of ``parts`` but the
    ``i``-th) predict the left-out sessions best: the least squared residual of their
    fitted samples, summed over sessions and joints (a session the others alone do not
    identify counts for no pull). A tie goes to 1, the prior's own scales."""
    errors = np.zeros(len(PULLS))
    for i, (normal, _) in enumerate(parts):
        try:
            row = [float(normal.n * (normal.rms(fit(i, pull)) ** 2).sum()) for pull in PULLS]
        except InputError:
            continue
        errors += row
    tie = np.isclose(errors, errors.min(), rtol=1e-9)
    return 1.0 if 1.0 in PULLS and tie[PULLS.index(1.0)] else PULLS[int(np.argmin(errors))]


def _arm_dynamics(theta: np.ndarray, normal: _Normal, model: RobotModel, phi2: np.ndarray,
                  phi3: np.ndarray, nominal_links: np.ndarray) -> ArmDynamics:
    """Return the :class:`ArmDynamics` of fitted parameters ``theta`` (their torque offset
    from the sessions' means in ``normal``), without provenance."""
    links = theta[:N_JOINTS * N_LINK].reshape(N_JOINTS, N_LINK)
    joints = theta[N_JOINTS * N_LINK:].reshape(N_JOINTS, N_FRICTION)
    return ArmDynamics(
        robot=model.spec.name, with_hand=model.with_hand,
        inertias=tuple(tuple(float(v) for v in link) for link in links),
        armature_kgm2=tuple(float(v) for v in joints[:, 2]),
        friction=tuple(tuple(float(v) for v in values) for values in
                       (joints[:, 0], phi2, phi3, joints[:, 1], normal.offset(theta))),
        payload=_payload(model, nominal_links[-1], links[-1]))


LEAVE_ONE_OUT = "leave-one-session-out"
"""The held-out motion with two sessions or more: each session, with the others' fit."""
TAIL = "last share of the session"
"""The held-out motion with one session: its last :data:`HOLDOUT`."""


def _method(held_out: str) -> dict:
    method = {"cutoff_hz": CUTOFF_HZ, "ident_rate_hz": IDENT_RATE_HZ, "held_out": held_out,
              "prior": "nominal model", "determined_variance_ratio": DETERMINED}
    if held_out == TAIL:
        method["holdout"] = HOLDOUT
    return method


def _detector(held_out: Sequence[tuple[Motion, ArmDynamics]], setup: RobotSetup,
              source: dict, outliers: bool = False) -> str | None:
    """Return the detector calibrated on the held-out motions, each with the model
    identified without it (its thresholds growing with speed, acceleration and each
    joint's dynamic torque scale, and beyond the largest scale the motions reached;
    its settings' JSON text, ``source`` recorded in it),
    or None (with a warning) when they are too short. With ``outliers``, the samples
    that stand out are left out first (:func:`~contactkit.features.detector.drop_outliers`;
    the share dropped is recorded)."""
    from contactkit.features.detector import (
        DYNAMIC_FEATURE,
        OUTLIER_FACTOR,
        OUTLIER_WINDOW_S,
        DetectorConfig,
        calibrate,
        calibration_samples,
        drop_outliers,
    )
    from contactkit.features.timeseries import TimeseriesChain

    parts = []
    for motion, dynamics in held_out:
        if len(motion.t) < 2:
            continue
        chain = TimeseriesChain(robot=replace(setup, dynamics=dynamics),
                                names=["r", DYNAMIC_FEATURE])
        features = chain.compute(motion.t, motion.q, motion.dq, motion.tau)
        parts.append(calibration_samples(motion.t, features["r"], motion.dq,
                                         dyn=features[DYNAMIC_FEATURE]))
    if outliers:
        parts, dropped = drop_outliers(parts)
        source = source | {"outliers": {"factor": OUTLIER_FACTOR, "window_s": OUTLIER_WINDOW_S,
                                        "dropped_share": round(dropped, 4)}}
    try:
        config = calibrate(parts, DetectorConfig(), source=source)
    except InputError as err:
        log.warning("no detector calibrated with the identified model: %s", err.problem)
        return None
    robot = held_out[0][1].robot
    return json.dumps(replace(config, robot=robot).to_dict(), sort_keys=True)


def _sha256(path: Path) -> str:
    """Return the SHA-256 (hex) of a file's bytes."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def free_motion(path: Path, robot: str | None = None) -> tuple[Motion, RobotSetup]:
    """Read one session's free motion (t, q, dq, tau only) and the arm it names (or
    ``robot`` in its place, ``--robot``). Raises InputError naming the file for a file
    that is not a session, or a session with contact: an action other than none
    without a contact column, or a contact column that is true anywhere."""
    session = _read_session(path)
    if session.has("contact"):
        touched = int(session.column("contact").astype(bool).sum())
        if touched:
            raise InputError(f"session has contact ({touched} samples): identification "
                             "needs free motion with nobody touching the arm", path)
    elif session.meta.action != "none":
        raise InputError(f"session has a {session.meta.action!r} contact and no contact "
                         "column: identification needs free motion", path)
    return (Motion(session.t, session.q, session.dq, session.tau, str(path)),
            _nominal_arm(session, robot, path))


def _read_session(path: Path) -> Session:
    """Read a session; InputError naming the file for a dataset's index or a file that
    is not a session."""
    from contactkit.schemas import read_session
    from contactkit.schemas.dataset import INDEX_NAME

    if path.name == INDEX_NAME:
        raise InputError("a dataset's index, not a session", path)
    return read_session(path)


def _nominal_arm(session: Session, robot: str | None, path: Path) -> RobotSetup:
    """Return the arm a session names (or ``robot`` in its place): its name and hand
    only, not the dynamics an earlier identification stored."""
    return replace(session.meta.with_robot(robot).robot_setup(path), dynamics=None)


AROUND_BEFORE_S = 0.5
"""Motion left out before each contact the detector finds (:func:`motion_around_contacts`)
[s]: the detector decides an onset once the touch has built up over its threshold."""
AROUND_AFTER_S = 1.0
"""Motion left out after each contact's release [s]: the arm settles after a shove, and
a hand leaves slowly."""


def motion_around_contacts(path: Path, detector: DetectorConfig, robot: str | None = None
                           ) -> tuple[Motion, RobotSetup]:
    """Read one session's motion outside its contacts (t, q, dq, tau) and the arm it
    names (or ``robot``): every contact ``detector`` finds with the arm's nominal model
    is cut out, from :data:`AROUND_BEFORE_S` before its onset to :data:`AROUND_AFTER_S`
    after its release (to the end when it is not released). The session's labels and
    contact column are not read: this is for recordings whose touches nobody marked, or
    to identify the arm a dataset was recorded on from the dataset itself. InputError
    naming the file for a file that is not a session, or when no motion is left."""
    from contactkit.features.detector import DYNAMIC_FEATURE, detect
    from contactkit.features.timeseries import TimeseriesChain

    session = _read_session(path).complete()
    setup = _nominal_arm(session, robot, path)
    chain = TimeseriesChain(robot=setup)
    config = detector.for_robot(chain.model.spec)
    features = chain.compute(session.t, session.q, session.dq, session.tau,
                             config.chain_features)
    found = detect(session.t, features["r"], session.dq, config,
                   features.get(DYNAMIC_FEATURE))
    t = session.t
    keep = np.ones(len(t), dtype=bool)
    for onset, release in found.intervals:  # the release sample is the first without
        last = len(t) - 1 if release is None else release - 1
        keep &= (t < t[onset] - AROUND_BEFORE_S) | (t > t[last] + AROUND_AFTER_S)
    if not keep.any():
        raise InputError("no motion outside the contacts the detector found", path)
    return Motion(t[keep], session.q[keep], session.dq[keep], session.tau[keep],
                  str(path)), setup


def identify_sessions(paths: Sequence[str | Path], robot: str | None = None, *,
                      around_contacts: DetectorConfig | None = None,
                      problems: list[tuple[str, str]] | None = None,
                      progress: Callable[[int, int], None] | None = None) -> Identified:
    """Identify the arm of the free-motion sessions ``paths`` (:func:`identify`), with
    the arm ``robot`` names instead of the sessions' own when given. With
    ``around_contacts`` (a detector's settings), every session is used, outside the
    contacts that detector finds (:func:`motion_around_contacts`), and samples that
    stand out of the held-out residuals are left out of the detector's calibration
    (``identify(outliers=True)``).

    A file that is not a session, or (without ``around_contacts``) a session with
    contact, is left out and appended to ``problems`` as ``(file, why)`` (without
    ``problems`` its InputError is raised). Raises InputError (one line) when no session
    is left, when the sessions are of different arms (or with and without the hand), or
    when the motion determines nothing. The provenance names each session with its
    SHA-256 and samples. ``progress(done, total)`` counts the sessions as they are
    read, then :func:`identify`'s steps (the total is first :func:`progress_steps`,
    what it is when every session is used)."""
    from contactkit import __version__

    motions: list[Motion] = []
    setups: dict[RobotSetup, str] = {}
    used = []
    read = len(paths)
    for done, name in enumerate(paths):
        if progress is not None:
            progress(done, progress_steps(read))
        path = Path(name)
        try:
            if around_contacts is None:
                motion, setup = free_motion(path, robot)
            else:
                motion, setup = motion_around_contacts(path, around_contacts, robot)
        except DATA_ERRORS as err:
            if problems is None:
                raise
            problems.append((str(path), problem_text(err)))
            continue
        motions.append(motion)
        setups.setdefault(setup, str(path))
        used.append({"file": path.name, "sha256": _sha256(path), "samples": len(motion.t),
                     "duration_s": round(float(motion.t[-1] - motion.t[0]), 3)})
    if not motions:
        why = "" if not problems else f": {Path(problems[0][0]).name}: {problems[0][1]}" + (
            f" (and {len(problems) - 1} more)" if len(problems) > 1 else "")
        if around_contacts is not None:
            raise InputError(f"no session to identify from{why}")
        raise InputError("no free-motion session to identify from (sessions with action "
                         f"none, or a contact column that is all false){why}")
    if len(setups) > 1:
        (first, a), (second, b) = list(setups.items())[:2]
        raise InputError(f"sessions of different arms: {a} is {_arm(first)}, {b} is "
                         f"{_arm(second)}: identify each arm on its own")
    setup = next(iter(setups))
    provenance: dict[str, object] = {
        "sessions": used, "tool": f"contactkit {__version__}",
        "created_utc": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")}
    if around_contacts is not None:
        provenance["around_contacts"] = {"before_s": AROUND_BEFORE_S,
                                         "after_s": AROUND_AFTER_S,
                                         "detector": around_contacts.source}
    fitting = None if progress is None else (
        lambda done, total: progress(read + done, read + total))
    return identify(motions, setup, provenance=provenance, outliers=around_contacts is not None,
                    progress=fitting)


def progress_steps(sessions: int) -> int:
    """Return the steps :func:`identify_sessions` counts for ``sessions`` sessions that
    are all used: each one read, its regressor summed and its held-out fit made."""
    return 3 * sessions


def _arm(setup: RobotSetup) -> str:
    return f"{setup.robot} {'with' if setup.with_hand else 'without'} hand"
