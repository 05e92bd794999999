"""Exciting trajectories to identify an arm's dynamics from (``recorder excite``).

Each joint follows a finite Fourier series (Swevers et al., IEEE T-RA 1997), periodic
with period T = 1 / f [s] (the duration holds a whole number of periods)::

    q_j(t) = q0_j + sum_{k=1..K} a_jk sin(k w t) + b_jk (cos(k w t) - 1),   w = 2 pi / T

so q(0) = q0, the pose the user gives. Linear conditions on the coefficients put the
arm at rest at t = 0 and at every period's end: dq = 0 (sum_k k a_jk = 0), ddq = 0
(sum_k k^2 b_jk = 0), and jerk 0 (sum_k k^3 a_jk = 0), so it starts and stops
smoothly. The optimiser moves in the null space of those conditions: 2K - 3 free
numbers per joint.

**Limits.** With A_jk = sqrt(a_jk^2 + b_jk^2), every instant (not only the samples) has
|q_j - q0_j + sum_k b_jk| <= sum_k A_jk, |dq_j| <= w sum_k k A_jk, |ddq_j| <= w^2
sum_k k^2 A_jk and |jerk_j| <= w^3 sum_k k^3 A_jk. The optimiser keeps these bounds
within the arm's limits less a margin (:data:`LIMIT_MARGIN` of the velocity,
acceleration and jerk limits, :data:`POSITION_MARGIN_RAD` from each position limit),
so no sample at any rate can leave them; the written samples are checked again.

**Clearance.** Every link's collision surface (:mod:`contactkit.robots.surfaces`,
points spread over it; link 7 with the hand) stays :data:`TABLE_MARGIN_M` above the
table (the base's plane z = 0) and every pair of links three or more joints apart
:data:`SELF_MARGIN_M` from each other (closer pairs share a short link whose joints'
limits keep them apart: their meshes are 2-7 cm apart in every pose). The
optimisation checks 30 instants per period on 16 points a link; the result is checked
at every 1 kHz sample against the table (every vertex of the surfaces) and at 100 Hz
between links (48 points a link), and shrunk toward the pose until it passes.

**Criterion.** The condition number of the base-parameter regressor: pinocchio's
joint-torque regressor (10 inertial parameters per link, the hand and payload in link
7's), with per-joint friction columns (viscous dq_j, Coulomb sign(dq_j) and a constant
offset), stacked over :data:`CRITERION_SAMPLES` instants of one period, restricted to
the base columns: a largest set of independent columns, chosen once per arm by QR
with column pivoting on random states. SLSQP (scipy) minimises its logarithm from a
random start (``seed``) within a time budget. (Starting from the best of 20 random
starts did worse: on the Panda from pose A, seeds 0-3, 460-960 against 340-920.)

Units: q [rad], dq [rad/s], ddq [rad/s^2], jerk [rad/s^3], t [s], f [Hz], lengths [m].
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import rerun as rr
import rerun.blueprint as rrb
from scipy.linalg import null_space, qr
from scipy.optimize import minimize
from threadpoolctl import threadpool_limits

from contactkit.errors import InputError
from contactkit.recorder.trajectory import MAX_DURATION_S, Trajectory
from contactkit.robots import N_JOINTS, RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.robots.surfaces import link_surface, viewer_urdf_file
from contactkit.util.atomic import atomic_write
from contactkit.util.progress import ProgressCallback
from contactkit.viewer import layout

RATE_HZ = 1000.0
LIMIT_MARGIN = 0.1
"""The share of each velocity, acceleration and jerk limit the trajectory leaves unused."""
POSITION_MARGIN_RAD = 0.1
"""How far the trajectory stays from each joint's position limits [rad]."""
TABLE_MARGIN_M = 0.05
"""How far every link's surface stays above the table [m]."""
SELF_MARGIN_M = 0.05
"""How far links three or more joints apart stay from each other [m]."""
SELF_PAIRS = tuple((i, j) for i in range(1, N_JOINTS + 1) for j in range(i + 3, N_JOINTS + 1))
CRITERION_SAMPLES = 60
"""Instants of one period the criterion is evaluated at (every other one: the clearance)."""
OPTIMISATION_POINTS, CHECK_POINTS, ALL_POINTS = 16, 48, 10**6
"""Surface points per link while optimising, and when checking the result between links;
every vertex when checking it against the table."""
MAX_ITERATIONS = 100
START_FRACTION = 0.5
"""The random start uses this share of the (margined) limits."""
DURATION_RANGE_S = (2.0, MAX_DURATION_S)
BASE_HZ_RANGE = (0.02, 2.0)
HARMONICS_RANGE = (3, 12)


@dataclass(frozen=True)
class ExcitationSettings:
    """What ``recorder excite`` is asked for: ``duration_s`` [s] (rounded to a whole
    number of periods of ``base_hz`` [Hz]), ``harmonics`` K, the random start's ``seed``
    and the optimisation's time budget ``budget_s`` [s]."""

    duration_s: float = 20.0
    harmonics: int = 5
    base_hz: float = 0.1
    seed: int = 0
    budget_s: float = 20.0

    def __post_init__(self) -> None:
        low, high = DURATION_RANGE_S
        if not low <= self.duration_s <= high:
            raise InputError(f"duration must be {low:g} to {high:g} s, got {self.duration_s}")
        low, high = BASE_HZ_RANGE
        if not low <= self.base_hz <= high:
            raise InputError(f"base frequency must be {low:g} to {high:g} Hz, got "
                             f"{self.base_hz}")
        low, high = HARMONICS_RANGE
        if not low <= self.harmonics <= high:
            raise InputError(f"harmonics must be {low} to {high}, got {self.harmonics}")
        if self.duration_s * self.base_hz < 0.5:
            raise InputError(f"a duration of {self.duration_s:g} s holds no period of "
                             f"{self.base_hz:g} Hz: raise --base-frequency or --duration")

    @property
    def periods(self) -> int:
        """How many periods the trajectory repeats."""
        return max(1, round(self.duration_s * self.base_hz))

    @property
    def omega(self) -> float:
        """The base angular frequency w [rad/s] of a whole number of periods."""
        return 2.0 * np.pi * self.periods / self.duration_s


@dataclass(frozen=True)
class FourierTrajectory:
    """One trajectory of the form in the module docstring: pose ``q0`` (7,) [rad],
    coefficients ``a`` and ``b`` (7, K) [rad], base angular frequency ``omega``
    [rad/s], ``duration_s`` [s]."""

    q0: np.ndarray
    a: np.ndarray
    b: np.ndarray
    omega: float
    duration_s: float

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, ...]:
        """Return (q, dq, ddq, jerk), each (N, 7), at times ``t`` (N,) [s]."""
        k = np.arange(1, self.a.shape[1] + 1) * self.omega
        phase = np.asarray(t, dtype=float)[:, None] * k
        sin, cos = np.sin(phase), np.cos(phase)
        a, b = self.a.T, self.b.T
        q = self.q0 + sin @ a + (cos - 1.0) @ b
        dq = (cos * k) @ a - (sin * k) @ b
        ddq = -(sin * k**2) @ a - (cos * k**2) @ b
        jerk = -(cos * k**3) @ a + (sin * k**3) @ b
        return q, dq, ddq, jerk

    def bounds(self) -> tuple[np.ndarray, ...]:
        """Return the bounds of the module docstring, each (7,): lowest and highest
        position [rad], largest |dq| [rad/s], |ddq| [rad/s^2] and |jerk| [rad/s^3]."""
        k = np.arange(1, self.a.shape[1] + 1) * self.omega
        amplitude = np.sqrt(self.a**2 + self.b**2 + 1e-18)
        centre, half = self.q0 - self.b.sum(axis=1), amplitude.sum(axis=1)
        return (centre - half, centre + half, amplitude @ k, amplitude @ k**2,
                amplitude @ k**3)

    def sampled(self, robot: str, rate_hz: float = RATE_HZ) -> Trajectory:
        """Return the trajectory sampled at ``rate_hz`` [Hz], exactly at rest at the pose
        at both ends."""
        t = np.arange(round(self.duration_s * rate_hz) + 1) / rate_hz
        q, dq, ddq, _ = self.evaluate(t)
        for row in (0, -1):
            q[row], dq[row], ddq[row] = self.q0, 0.0, 0.0
        return Trajectory(t=t, q=q, dq=dq, ddq=ddq, robot=robot)


@dataclass(frozen=True)
class Excitation:
    """The result: the trajectory, its criterion (the base-parameter regressor's
    condition number) at the random start and at the end, the regressor's base-parameter count,
    and the optimiser's iterations and time [s]."""

    trajectory: FourierTrajectory
    condition_start: float
    condition: float
    base_parameters: int
    iterations: int
    seconds: float
    shrunk: float = 1.0


class _OutOfTime(Exception):
    """Raised from the optimiser's callback when the time budget is spent."""


def _null_spaces(harmonics: int) -> tuple[np.ndarray, np.ndarray]:
    """Return bases (K, K - 2) of the sine and (K, K - 1) of the cosine coefficients
    with dq = jerk = 0 and ddq = 0 at t = 0."""
    k = np.arange(1, harmonics + 1, dtype=float)
    return null_space(np.vstack([k, k**3])), null_space((k**2)[None])


def regressor_rows(model: RobotModel, q: np.ndarray, dq: np.ndarray,
                   ddq: np.ndarray) -> np.ndarray:
    """Return the stacked regressor (7 N, 10 n_links + 21) at N states: pinocchio's
    joint-torque regressor, then per joint viscous (dq_j), Coulomb (sign dq_j) and
    offset (1) columns."""
    n = len(q)
    rows = np.empty((n, N_JOINTS, model.model.nv * 10 + 3 * N_JOINTS))
    eye = np.eye(N_JOINTS)
    inertial = model.model.nv * 10
    for i in range(n):
        rows[i, :, :inertial] = pin.computeJointTorqueRegressor(model.model, model.data,
                                                                q[i], dq[i], ddq[i])
    rows[:, :, inertial:inertial + N_JOINTS] = dq[:, :, None] * eye
    rows[:, :, inertial + N_JOINTS:inertial + 2 * N_JOINTS] = np.sign(dq)[:, :, None] * eye
    rows[:, :, inertial + 2 * N_JOINTS:] = eye
    return rows.reshape(n * N_JOINTS, -1)


@cache
def base_columns(setup: RobotSetup) -> np.ndarray:
    """Return the indices of a largest set of independent regressor columns of ``setup``'s
    arm (:func:`regressor_rows`): QR with column pivoting on 200 random states (fixed
    seed), columns whose pivot exceeds 1e-8 of the largest."""
    model = RobotModel(setup)
    rng = np.random.default_rng(12345)
    limits = model.limits
    low = np.where(np.isfinite(limits.q_min), limits.q_min, -np.pi)
    high = np.where(np.isfinite(limits.q_max), limits.q_max, np.pi)
    q = rng.uniform(low, high, (200, N_JOINTS))
    dq = rng.normal(0.0, 1.0, (200, N_JOINTS))
    ddq = rng.normal(0.0, 3.0, (200, N_JOINTS))
    _, r, pivots = qr(regressor_rows(model, q, dq, ddq), mode="economic", pivoting=True)
    diagonal = np.abs(np.diag(r))
    return np.sort(pivots[:int((diagonal > 1e-8 * diagonal[0]).sum())])


def condition_number(model: RobotModel, columns: np.ndarray, q: np.ndarray, dq: np.ndarray,
                     ddq: np.ndarray) -> float:
    """Return the condition number of the base-parameter regressor stacked at the states
    (q, dq, ddq), each (N, 7): the criterion of the module docstring."""
    rows = regressor_rows(model, q, dq, ddq)[:, columns]
    eigen = np.linalg.eigvalsh(rows.T @ rows)  # the squared singular values, ascending
    return float(np.sqrt(eigen[-1] / eigen[0])) if eigen[0] > 0 else float("inf")


def _surface_points(setup: RobotSetup, link: int, count: int) -> np.ndarray:
    """Return ``count`` points (or all, when fewer) of link ``link``'s collision surface
    in its frame [m], spread over it (farthest-point sampling from the lowest vertex)."""
    vertices = np.unique(link_surface(setup, link).vertices.reshape(-1, 3), axis=0)
    if len(vertices) <= count:
        return vertices
    chosen = [int(np.argmin(vertices[:, 2]))]
    distance = np.linalg.norm(vertices - vertices[chosen[0]], axis=1)
    while len(chosen) < count:
        chosen.append(int(np.argmax(distance)))
        distance = np.minimum(distance, np.linalg.norm(vertices - vertices[chosen[-1]], axis=1))
    return vertices[chosen]


class Clearance:
    """Distances of an arm's links from the table and from each other, at many states."""

    def __init__(self, model: RobotModel, points_per_link: int) -> None:
        self.model = model
        self.points = [_surface_points(model.setup, link, points_per_link)
                       for link in range(1, N_JOINTS + 1)]

    def _placements(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return the world rotations (7, N, 3, 3) and translations (7, N, 3) [m] of
        links 1..7 at every row of ``q`` (N, 7)."""
        model, data = self.model.model, self.model.data
        frames = [self.model.frame_id(link) for link in range(1, N_JOINTS + 1)]
        rotation = np.empty((N_JOINTS, len(q), 3, 3))
        translation = np.empty((N_JOINTS, len(q), 3))
        for row, values in enumerate(np.asarray(q, dtype=float)):
            pin.framesForwardKinematics(model, data, values)
            for k, frame in enumerate(frames):
                placement = data.oMf[frame]
                rotation[k, row], translation[k, row] = placement.rotation, placement.translation
        return rotation, translation

    def world_points(self, q: np.ndarray) -> list[np.ndarray]:
        """Return each link's surface points in the base frame at every row of ``q``
        (N, 7): a list of 7 arrays (N, n, 3) [m] (empty for a link without surface)."""
        rotation, translation = self._placements(q)
        return [points @ rotation[k].transpose(0, 2, 1) + translation[k][:, None]
                for k, points in enumerate(self.points)]

    def lowest(self, q: np.ndarray) -> np.ndarray:
        """Return the lowest surface point's height above the table [m] at each row of
        ``q`` (N, 7) (heights only: cheap for many points)."""
        rotation, translation = self._placements(q)
        heights = [points @ rotation[k, :, 2, :].T + translation[k, :, 2:3].T
                   for k, points in enumerate(self.points) if len(points)]
        return np.min([h.min(axis=0) for h in heights], axis=0) if heights else \
            np.full(len(q), np.inf)

    def measure(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return, at each row of ``q`` (N, 7), the lowest surface point's height above
        the table [m] and the smallest distance [m] between links three or more joints
        apart (between their surface points)."""
        placed = self.world_points(q)
        heights = [p[..., 2].min(axis=1) for p in placed if p.shape[1]]
        table = np.min(heights, axis=0) if heights else np.full(len(q), np.inf)
        nearest = np.full(len(q), np.inf)
        for i, j in SELF_PAIRS:
            first, second = placed[i - 1], placed[j - 1]
            if not first.shape[1] or not second.shape[1]:
                continue
            squared = ((first**2).sum(-1)[:, :, None] + (second**2).sum(-1)[:, None]
                       - 2.0 * first @ second.transpose(0, 2, 1))
            nearest = np.minimum(nearest, squared.min(axis=(1, 2)))
        return table, np.sqrt(np.maximum(nearest, 0.0))


def check_pose(q0: np.ndarray, model: RobotModel) -> None:
    """Raise one InputError line when pose ``q0`` [rad] is within the position margin of
    a joint limit, or itself too close to the table or between links."""
    limits = model.limits
    low, high = limits.q_min + POSITION_MARGIN_RAD, limits.q_max - POSITION_MARGIN_RAD
    outside = np.flatnonzero((q0 < low) | (q0 > high))
    if outside.size:
        j = int(outside[0])
        raise InputError(f"the start pose's joint {j + 1} ({q0[j]:.4f} rad) is within "
                         f"{POSITION_MARGIN_RAD} rad of its limits ({limits.q_min[j]:.4f} "
                         f"to {limits.q_max[j]:.4f}): choose another pose")
    table, between = Clearance(model, CHECK_POINTS).measure(q0[None])
    if table[0] < TABLE_MARGIN_M:
        raise InputError(f"the start pose brings a link within {TABLE_MARGIN_M} m of the "
                         "table: choose another pose")
    if between[0] < SELF_MARGIN_M:
        raise InputError(f"the start pose brings two links within {SELF_MARGIN_M} m of "
                         "each other: choose another pose")


class _Problem:
    """The optimisation: variables (7 x (2K - 3)) in the null spaces, the criterion and
    the clearance constraints (each >= 0 when met, in margins).

    A variable of 1 alone uses a whole (margined) limit, and a trajectory whose bounds
    would leave a limit is scaled down to meet it (:meth:`trajectory`): the limits hold
    by construction, and only the clearances are constraints."""

    def __init__(self, model: RobotModel, q0: np.ndarray, settings: ExcitationSettings) -> None:
        self.model, self.q0, self.settings = model, q0, settings
        self.sines, self.cosines = _null_spaces(settings.harmonics)
        self.columns = base_columns(model.setup)
        self.clearance = Clearance(model, OPTIMISATION_POINTS)
        limits = model.limits
        keep = 1.0 - LIMIT_MARGIN
        self.room = (limits.q_min + POSITION_MARGIN_RAD - q0,
                     limits.q_max - POSITION_MARGIN_RAD - q0)
        self.rates = (keep * limits.dq_max, keep * limits.ddq_max, keep * limits.jerk_max)
        period = settings.duration_s / settings.periods
        self.t = np.arange(CRITERION_SAMPLES) * period / CRITERION_SAMPLES
        size = N_JOINTS * (self.sines.shape[1] + self.cosines.shape[1])
        self.scale = 1.0 / np.array([self.usage(self._series(unit)) for unit in np.eye(size)])

    def _series(self, z: np.ndarray) -> FourierTrajectory:
        """Return the trajectory of null-space coordinates ``z`` (unscaled, unlimited)."""
        s = self.sines.shape[1]
        z = z.reshape(N_JOINTS, -1)
        return FourierTrajectory(q0=self.q0, a=z[:, :s] @ self.sines.T,
                                 b=z[:, s:] @ self.cosines.T, omega=self.settings.omega,
                                 duration_s=self.settings.duration_s)

    def usage(self, trajectory: FourierTrajectory) -> float:
        """Return the largest share of a (margined) limit ``trajectory``'s bounds use:
        positions as a share of the room between the pose and the limit on that side."""
        low, high, *rates = trajectory.bounds()
        below, above = self.room
        with np.errstate(divide="ignore", invalid="ignore"):
            shares = [np.where(low < self.q0, (low - self.q0) / below, 0.0),
                      np.where(high > self.q0, (high - self.q0) / above, 0.0),
                      *[r / limit for r, limit in zip(rates, self.rates, strict=True)]]
        return float(np.nan_to_num(np.concatenate(shares), nan=np.inf).max())

    def trajectory(self, x: np.ndarray) -> FourierTrajectory:
        """Return the trajectory of variables ``x``, scaled down onto the limits when
        its bounds would leave them."""
        series = self._series(x * self.scale)
        use = self.usage(series)
        if use <= 1.0:
            return series
        return FourierTrajectory(q0=self.q0, a=series.a / use, b=series.b / use,
                                 omega=series.omega, duration_s=series.duration_s)

    def criterion(self, x: np.ndarray) -> float:
        """Return log10 of the condition number at ``x`` (at most 12)."""
        q, dq, ddq, _ = self.trajectory(x).evaluate(self.t)
        return float(np.log10(min(condition_number(self.model, self.columns, q, dq, ddq),
                                  1e12)))

    def clear(self, x: np.ndarray) -> np.ndarray:
        """Return the clearance constraints at the criterion's instants [m / margin]."""
        table, between = self.clearance.measure(self.trajectory(x).evaluate(self.t[::2])[0])
        return np.concatenate([table / TABLE_MARGIN_M - 1.0, between / SELF_MARGIN_M - 1.0])

    def feasible(self, x: np.ndarray) -> bool:
        """Whether ``x`` keeps every clearance (the limits always hold)."""
        return bool((self.clear(x) >= 0).all())

    def start(self, rng: np.random.Generator) -> np.ndarray:
        """Return a random feasible start: a random direction at :data:`START_FRACTION`
        of the tightest limit, shrunk until clear."""
        x = rng.normal(0.0, 1.0, len(self.scale))
        x = x * START_FRACTION / self.usage(self._series(x * self.scale))
        for _ in range(30):
            if self.feasible(x):
                return x
            x = x * 0.7
        raise InputError("no motion around the start pose keeps clear of the table and "
                         "between links: choose another pose")


def excite(robot: RobotSetup, q0: np.ndarray, settings: ExcitationSettings,
           progress: ProgressCallback | None = None) -> Excitation:
    """Return the exciting trajectory for arm ``robot`` from pose ``q0`` [rad]: the
    module docstring's series, optimised for the criterion under the limits and the
    clearances, checked at 1 kHz. ``progress`` gets (iterations done, most iterations).

    Raises InputError for a pose too close to the limits, the table or itself."""
    with threadpool_limits(1):  # small matrices: threads only contend
        return _excite(robot, q0, settings, progress)


def _excite(robot: RobotSetup, q0: np.ndarray, settings: ExcitationSettings,
            progress: ProgressCallback | None) -> Excitation:
    model = RobotModel(robot)
    q0 = np.asarray(q0, dtype=float)
    check_pose(q0, model)
    problem = _Problem(model, q0, settings)
    rng = np.random.default_rng(settings.seed)
    x = problem.start(rng)
    began = time.perf_counter()
    start_value = problem.criterion(x)
    best: dict[str, Any] = {"x": x, "value": start_value, "iterations": 0}

    def follow(xk: np.ndarray) -> None:
        best["iterations"] += 1
        if progress is not None:
            progress(best["iterations"], MAX_ITERATIONS)
        value = problem.criterion(xk)
        if value < best["value"] and problem.feasible(xk):
            best.update(x=xk.copy(), value=value)
        if time.perf_counter() - began > settings.budget_s:
            raise _OutOfTime

    try:
        result = minimize(problem.criterion, x, method="SLSQP", callback=follow,
                          bounds=[(-1.0, 1.0)] * len(x),
                          constraints=[{"type": "ineq", "fun": problem.clear}],
                          options={"maxiter": MAX_ITERATIONS, "ftol": 1e-4})
        if problem.feasible(result.x) and result.fun < best["value"]:
            best.update(x=result.x, value=float(result.fun))
    except _OutOfTime:
        pass
    if progress is not None:
        progress(MAX_ITERATIONS, MAX_ITERATIONS)
    trajectory, shrunk = _checked(problem, best["x"])
    q, dq, ddq, _ = trajectory.evaluate(problem.t)
    return Excitation(trajectory=trajectory, condition_start=10.0**start_value,
                      condition=condition_number(model, problem.columns, q, dq, ddq),
                      base_parameters=len(problem.columns),
                      iterations=best["iterations"], seconds=time.perf_counter() - began,
                      shrunk=shrunk)


def _checked(problem: _Problem, x: np.ndarray) -> tuple[FourierTrajectory, float]:
    """Return the trajectory of ``x``, shrunk toward the pose (by 0.9 at a time) until its
    samples pass :func:`sample_problem`, and the factor it was shrunk by."""
    scale = 1.0
    for _ in range(40):
        trajectory = problem.trajectory(x * scale)
        if sample_problem(trajectory, problem.model) is None:
            return trajectory, scale
        scale *= 0.9
    raise InputError("no exciting motion from the start pose passes the checks: choose "
                     "another pose")


def sample_problem(trajectory: FourierTrajectory, model: RobotModel) -> str | None:
    """Return what makes ``trajectory`` fail at its 1 kHz samples (limits with their
    margins, jerk by finite differences, every surface vertex above the table at every
    sample, links apart at 100 Hz),
    or None when it passes."""
    sampled = trajectory.sampled(model.setup.robot)
    limits = model.limits
    keep = 1.0 - LIMIT_MARGIN
    low, high = limits.q_min + POSITION_MARGIN_RAD, limits.q_max - POSITION_MARGIN_RAD
    if (sampled.q < low).any() or (sampled.q > high).any():
        return "position"
    for what, values, limit in (("velocity", sampled.dq, limits.dq_max),
                                ("acceleration", sampled.ddq, limits.ddq_max),
                                ("jerk", sampled.jerk(), limits.jerk_max)):
        if (np.abs(values) > keep * limit).any():
            return what
    every_vertex, clearance = Clearance(model, ALL_POINTS), Clearance(model, CHECK_POINTS)
    stride = round(RATE_HZ / 100.0)
    for start in range(0, len(sampled.t), 5000):
        q = sampled.q[start:start + 5000]
        if (every_vertex.lowest(q) < TABLE_MARGIN_M).any():
            return "table"
        if (clearance.measure(q[::stride])[1] < SELF_MARGIN_M).any():
            return "links"
    return None


PREVIEW_HZ = 50.0
"""The rate [Hz] of the preview's arm motion and joint curves."""
FRACTIONS = (("q", "position"), ("dq", "velocity"), ("ddq", "acceleration"),
             ("jerk", "jerk"))


def write_preview(path: Path, trajectory: Trajectory, robot: RobotSetup, *,
                  overwrite: bool = False) -> Path:
    """Write a Rerun recording of ``trajectory`` at ``path`` atomically: the arm moving
    in 3-D, the joint curves q [rad], dq [rad/s] and ddq [rad/s^2], and each joint's
    position, velocity, acceleration and jerk as a share of its limit (+-1 the limit,
    +-0.9 the margin), at :data:`PREVIEW_HZ`. Returns the path."""
    limits = RobotModel(robot).limits
    stride = max(1, round(RATE_HZ / PREVIEW_HZ))
    rows = np.arange(0, len(trajectory.t), stride)
    t, sample = trajectory.t[rows], rows
    jerk = np.vstack([trajectory.jerk(), np.zeros((1, N_JOINTS))])
    middle, half = (limits.q_max + limits.q_min) / 2.0, (limits.q_max - limits.q_min) / 2.0
    shares = {"q": (trajectory.q[rows] - middle) / half,
              "dq": trajectory.dq[rows] / limits.dq_max,
              "ddq": trajectory.ddq[rows] / limits.ddq_max,
              "jerk": jerk[rows] / limits.jerk_max}
    rec = rr.RecordingStream("contactkit-excite", recording_id=f"excite-{path.name}")
    with atomic_write(path, overwrite=overwrite, suffix=".rrd") as tmp:
        rec.save(tmp.path, default_blueprint=_preview_blueprint(trajectory.duration_s))
        layout.log_series_styles(rec)
        tree = layout.log_robot_model(rec, viewer_urdf_file(robot))
        rec.send_property("trajectory", rr.AnyValues(robot=robot.robot,
                                                     duration_s=trajectory.duration_s))
        rec.log("excite/ddq", rr.SeriesLines(names=layout.JOINT_NAMES,
                                             colors=layout.JOINT_COLORS), static=True)
        lines = np.tile([1.0, -1.0, 1.0 - LIMIT_MARGIN, LIMIT_MARGIN - 1.0], (len(t), 1))
        for key, _ in FRACTIONS:
            rec.log(f"limits/{key}/share", rr.SeriesLines(names=layout.JOINT_NAMES,
                                                          colors=layout.JOINT_COLORS),
                    static=True)
            rec.log(f"limits/{key}/bounds", rr.SeriesLines(
                names=["limit", "-limit", "margin", "-margin"], colors=[(0, 0, 0)] * 2
                + [(150, 150, 150)] * 2, widths=[1.5, 1.5, 0.75, 0.75]), static=True)
            layout.log_scalar_columns(rec, f"limits/{key}/share", t, sample, shares[key])
            layout.log_scalar_columns(rec, f"limits/{key}/bounds", t, sample, lines)
        layout.log_scalar_columns(rec, layout.Q, t, sample, trajectory.q[rows])
        layout.log_scalar_columns(rec, layout.DQ, t, sample, trajectory.dq[rows])
        layout.log_scalar_columns(rec, "excite/ddq", t, sample, trajectory.ddq[rows])
        layout.log_joint_transforms(rec, tree, t, sample, trajectory.q[rows])
        rec.flush()
        rec.disconnect()
    return path


def _preview_blueprint(duration_s: float) -> rrb.Blueprint:
    """The preview's layout: the arm beside the joint curves and their shares of the
    limits."""
    curves = rrb.Vertical(
        layout.series_view(layout.Q, "joint position q [rad]", duration_s),
        layout.series_view(layout.DQ, "joint velocity dq [rad/s]", duration_s),
        layout.series_view("excite/ddq", "joint acceleration ddq [rad/s^2]", duration_s))
    shares = rrb.Vertical(*[
        layout.series_view(f"limits/{key}", f"{name} / limit (+-1 the limit, +-"
                           f"{1 - LIMIT_MARGIN:g} the margin)", duration_s,
                           axis_y=rrb.ScalarAxis(range=(-1.1, 1.1)))
        for key, name in FRACTIONS])
    return rrb.Blueprint(rrb.Horizontal(layout.robot_view("the arm", [f"+ {layout.ROBOT}/**"]),
                                        curves, shares, column_shares=[2, 2, 2]),
                         rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(state="collapsed"))


def pose_from(pose: str | None, q0: str | None) -> np.ndarray:
    """Return the start pose [rad] from a pose name (A-H) or 7 comma-separated values;
    pose A when neither is given. Raises InputError for both or bad values."""
    from contactkit.recorder.protocol import START_POSE, pose_q

    if pose is not None and q0 is not None:
        raise InputError("give --pose or --q0, not both")
    if q0 is None:
        return pose_q(pose or START_POSE)
    try:
        values = np.array([float(v) for v in q0.split(",")])
    except ValueError as err:
        raise InputError(f"--q0 must be {N_JOINTS} comma-separated numbers [rad], got "
                         f"{q0[:80]!r}") from err
    if values.shape != (N_JOINTS,) or not np.isfinite(values).all():
        raise InputError(f"--q0 must be {N_JOINTS} finite numbers [rad], got {q0[:80]!r}")
    return values

