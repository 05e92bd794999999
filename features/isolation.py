"""Contact isolation and identification from the observer residual: which link was
touched, where on its collision surface, and the force vector.

A single point force F [N] at point p on link k gives the joint torque

    r = J_k(q, p)^T F = Jv^T F + Jw^T (p x F)        (Nm; joints after k see nothing)

with Jv, Jw the linear and angular rows of link k's frame Jacobian. The estimator is a
weighted least-squares search over precomputed samples of each link's collision
surface (the meshes the simulator uses, about ``spacing_m`` apart), in the link frame
so that the samples never move, followed by a local refinement. Each joint's torque
is divided by its noise, sqrt(``joint_noise_nm``^2 + (``threshold_share`` x the
contact detector's threshold)^2): the residual at rest is about eight times noisier
on the shoulder joints than on the wrist, and an unweighted fit lets the shoulder's
noise hide the wrist's evidence; the threshold (0.3 Nm at rest, growing with speed
and acceleration where the model is wrong) stands for model error.

1. Per update one ``computeJointJacobians`` gives every link's Jacobian. Per sample
   point, the normal equations of F are in closed form: b = A^T r = a + c x p is
   linear in p and the Gram matrix A^T A (A = Jv^T + Jw^T S(p)) quadratic, so b and
   the Gram matrix's six entries for all samples of all links are one batched
   product of the samples' monomials (1, x, y, z, xx, ..., yz; precomputed) with
   per-link coefficients, themselves one product of [J J^T, J r] with a constant
   matrix; the 3x3 solves are elementwise (Cholesky). A link's error is at least
   the residual on the joints after it; links whose bound leaves them no chance are
   not searched (all are, when the decision turns out to need one of them).
2. The force must push into the surface, within ``cone_deg`` of the inward normal.
   On the samples, a force outside the cone explains nothing (error |r|); on the
   refinement grids, where the free least-squares force lies outside the cone and
   could still beat the link's best feasible one, the best force along the cone's
   boundary ray nearest to it is taken (the optimum of a convex problem whose free
   optimum lies outside the cone is on its boundary).
3. The ``REFINE_LINKS`` links with the smallest errors are refined from their best
   sample on the ``GRIDS`` in the sample's face plane (one spacing either side, then
   one step of that grid either side: 2 mm apart at the end), which removes most of
   the sampling error. A grid's monomials are a per-sample matrix (precomputed for
   the first) times those of the plane coordinates.
4. The link is the lowest one whose squared error exceeds the smallest (on link m)
   by at most ``tie``^2 per link between them (errors in noise units): a link-k
   contact is generically also explained by a point on link k + 1 whose force line
   meets joint k + 1's axis, and each more distal link absorbs one more joint's
   noise, so the proximal explanation wins unless the distal one is better by more
   than noise. With fewer than five loaded joints (links 1-4) the torques leave the
   point undetermined along a curve: the reported point is the sample nearest the
   middle of the link's samples within ``tie`` of its best, the least-risk guess.

The confidence compares the chosen link's error e with the best other link's, in
noise units: 1 - (e + 1) / (e_other + 1), clipped to 0..1; ``ambiguous`` when it is
below ``ambiguous_below``. A residual below ``min_residual_nm`` or a best link without
a collision surface gives an estimate with no point and no force and a ``status``
that says why (not an error).

Units: q [rad], r [Nm], points [m], forces [N], reported errors [Nm].
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np
import pinocchio as pin

from contactkit.features.detector import MIN_NOISE
from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.robots.spec import N_JOINTS
from contactkit.robots.surfaces import LinkSurface, link_surface

REFINE_LINKS = 3
PRUNE_SHARE = 0.25
MIN_DETERMINED = 5
GRIDS = ((11, 1.0), (7, 0.2))
"""Refinement grids: points per side and half-width [sample spacings]; each is centred
on the previous one's best point and spans one step of it either side."""
DEFAULT_SPACING_M = 0.03
DEFAULT_CONE_DEG = 60.0
RIDGE = 1e-9
TINY = 1e-12  # m^2, keeps a point whose Jacobian vanishes (on joint 1's axis) finite
OK, NO_SURFACE, TOO_SMALL = "ok", "no-surface", "too-small"
REST_NOISE_NM = (0.077, 0.068, 0.05, 0.043, 0.009, 0.01, 0.009)
"""Standard deviation [Nm] of the simulated Panda's residual at rest, per joint, 0.3 s
after a baseline of 50 ms (10 contact-free thesis-static sessions of seed 7)."""


class Surface(Protocol):
    """A link's collision surface in the link frame: triangles ``vertices`` (n, 3, 3)
    [m], unit outward ``normals`` (n, 3) and ``areas`` (n,) [m^2]."""

    @property
    def vertices(self) -> np.ndarray: ...
    @property
    def normals(self) -> np.ndarray: ...
    @property
    def areas(self) -> np.ndarray: ...


SurfaceProvider = Callable[[int], Surface | None]
"""Link 1..7 -> its collision surface, or None for a link without one."""


class ArmModel(Protocol):
    """What the estimator needs of a robot model: its pinocchio ``model`` and the frame
    id of link 1..7."""

    model: pin.Model

    def frame_id(self, link: int) -> int:
        """Return the pinocchio frame id of link 1..7."""


@dataclass(frozen=True)
class SurfaceSamples:
    """Sample points (n, 3) [m] on a link's surface, their unit outward normals (n, 3)
    and two unit tangents (n, 3) each, in the link frame."""

    points: np.ndarray
    normals: np.ndarray
    tangents: tuple[np.ndarray, np.ndarray]


_UNIT_SKEW = np.array([[[0, 0, 0], [0, 0, -1], [0, 1, 0]],
                       [[0, 0, 1], [0, 0, 0], [-1, 0, 0]],
                       [[0, -1, 0], [1, 0, 0], [0, 0, 0]]], dtype=float)
"""S(e_i) for the unit vectors: S(p) = sum_i p_i S(e_i), S(p) F = p x F."""
_ZERO, _ONE, _TWO, _TINY = (np.array(x) for x in (0.0, 1.0, 2.0, TINY))
"""Scalars as 0-d arrays: numpy combines them with an array faster than Python floats."""
_PAIRS = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
"""The Gram entries xx yy zz xy xz yz, and monomials 4..9, as pairs of coordinates."""
_PAIRS_A, _PAIRS_B = (np.array(x) for x in zip(*_PAIRS, strict=True))
_GRID_PRODUCTS = np.zeros((9, 6))
_GRID_PRODUCTS[[0, 1, 2, 3, 4, 5, 6, 7, 8], [0, 1, 2, 1, 3, 5, 2, 5, 4]] = 1.0
"""The products c d of a grid point's coordinates c, d in (1, s, t) (9, row-major) as
its monomials 1, s, t, ss, tt, st (6)."""


class _Cone:
    """The friction cone's half-angle as its cosine, sine and squared cosine, 0-d
    arrays (see ``_ZERO``)."""

    def __init__(self, cos: float, sin: float) -> None:
        self.cos, self.sin, self.cos2 = np.array(cos), np.array(sin), np.array(cos * cos)


def _decide(errors: list[float], tie: float) -> tuple[int, int, int]:
    """Return the link indices (0..6) of the smallest error of ``errors`` [Nm] (7), of
    the link chosen (the lowest whose squared error exceeds the smallest by at most
    ``tie``^2 per link between them) and of the best other link."""
    order = range(len(errors))
    last = min(order, key=errors.__getitem__)
    limit = errors[last] ** 2
    link = next(k for k in order if errors[k] ** 2 <= limit + tie * tie * (last - k))
    return last, link, min((k for k in order if k != link), key=errors.__getitem__)


class _Scratch:
    """Arrays for one shape (m, n) of candidate points, reused from update to update:
    the fit's inputs ``fitted`` (9, m, n) (``into``: the (m, 9, n) view a matmul writes),
    y and ``force`` (3, m, n), and the rows of each (views: unpacking an array into
    its rows costs about as much as a numpy operation)."""

    def __init__(self, m: int, n: int) -> None:
        self.fitted = np.empty((9, m, n))
        self.y, self.force = np.empty((3, m, n)), np.empty((3, m, n))
        self.into = self.fitted.transpose(1, 0, 2)
        self.rows, self.y_rows, self.force_rows = (tuple(a) for a in (self.fitted, self.y,
                                                                      self.force))


def _solve(work: _Scratch) -> tuple[np.ndarray, np.ndarray]:
    """Return the least-squares force [N] (3, m, n) and its gain b^T G^-1 b [Nm^2] (m, n)
    at each candidate point from ``work.fitted`` (9, m, n): b = A^T r (3) and the Gram
    matrix G = A^T A (xx yy zz xy xz yz), by an elementwise Cholesky factorisation G =
    L L^T. The force is ``work.force``."""
    bx, by, bz, g00, g11, g22, g01, g02, g12 = work.rows
    y, force = work.y, work.force
    y0, y1, y2 = work.y_rows
    fx, fy, fz = work.force_rows
    i00 = _ONE / np.sqrt(g00)
    l10, l20 = g01 * i00, g02 * i00
    i11 = _ONE / np.sqrt(g11 - l10 * l10)
    l21 = (g12 - l20 * l10) * i11
    i22 = _ONE / np.sqrt(g22 - l20 * l20 - l21 * l21)
    np.multiply(bx, i00, y0)
    np.multiply(by - l10 * y0, i11, y1)
    np.multiply(bz - l20 * y0 - l21 * y1, i22, y2)
    np.multiply(y2, i22, fz)
    np.multiply(y1 - l21 * fz, i11, fy)
    np.multiply(y0 - l10 * fy - l20 * fz, i00, fx)
    return force, np.add.reduce(y * y, axis=0)


def _coarse_fit(work: _Scratch, rr: np.ndarray, inward: np.ndarray, cone: _Cone
                ) -> tuple[np.ndarray, np.ndarray]:
    """Fit the force at the surface samples (see :func:`_fit`; ``inward`` their unit
    inward normals (3, m, n), zero at padding), without the search along the cone's
    boundary: a sample whose least-squares force does not push into the surface within
    the cone explains nothing (error |r|). Return the squared errors [Nm^2] (m, n) and
    forces [N] (3, m, n)."""
    force, gain = _solve(work)
    push = np.add.reduce(inward * force, axis=0)
    feasible = (push > _ZERO) & (push * push >= cone.cos2 * np.add.reduce(force * force, axis=0))
    return rr - np.where(feasible, gain, _ZERO), force


def _fit(work: _Scratch, rr: np.ndarray, inward: np.ndarray, cone: _Cone
         ) -> tuple[np.ndarray, np.ndarray]:
    """Fit the force at candidate points, m links x n points each, on one face plane
    per link, and return each point's residual error [Nm] (m, n) and force [N] (3, m,
    n, link frame; ``work.force``).

    ``work.fitted`` (9, m, n): per point b = A^T r (3) and the Gram matrix's entries
    (xx yy zz xy xz yz); ``rr`` = |r|^2 [Nm^2] (0-d); the unit ``inward`` normals (3,
    m, 1) of each link's face; ``cone`` the friction cone's half-angle. The force is
    the least-squares one if it lies in the cone, else the best one along
    the cone's boundary ray nearest to it (in the plane of the normal and the free
    force). That search is made only where a point's free gain beats its link's best
    feasible one; any other point outside the cone cannot be its link's best, and
    its error is given as |r| (its force as the free one)."""
    force, gain = _solve(work)
    push = np.add.reduce(inward * force, axis=0)
    size2 = np.add.reduce(force * force, axis=0)
    feasible = (push > _ZERO) & (push * push >= cone.cos2 * size2)
    gain_in = np.where(feasible, gain, _ZERO)
    search = (gain > np.maximum.reduce(gain_in, axis=1, keepdims=True)).ravel().nonzero()[0]
    if search.size:
        # the few points searched, gathered, and written back through flat views
        # (gain_in is fresh, the force contiguous)
        flat_force = force.reshape(3, -1)
        gain_in.ravel()[search], flat_force[:, search] = _boundary(
            work.fitted.reshape(9, -1).take(search, axis=1),
            inward[:, :, 0].take(search // force.shape[2], axis=1), cone,
            flat_force.take(search, axis=1), push.ravel().take(search), size2.ravel().take(search))
    return np.sqrt(np.maximum(rr - gain_in, _ZERO)), force


def _boundary(v: np.ndarray, inward: np.ndarray, cone: _Cone, force: np.ndarray,
              push: np.ndarray, size2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the gain [Nm^2] (k,) and force [N] (3, k) of the best force along the
    cone's boundary ray nearest to the free least-squares ``force`` (3, k), at k points
    with ``v`` (9, k) (see :func:`_fit`), unit ``inward`` normals (3, k), the free
    force's inward component ``push`` [N] (k,) and squared size ``size2`` [N^2] (k,)."""
    # the boundary ray: cos n_in + sin (the free force's unit component along the face)
    scale = cone.sin / (np.sqrt(np.maximum(size2 - push * push, _ZERO)) + _TINY)
    ray = (force - push * inward) * scale + cone.cos * inward
    pushed = np.maximum(np.add.reduce(v[:3] * ray, axis=0), _ZERO)
    # ray^T G ray from the products of its components (xx yy zz xy xz yz) and G's entries
    terms = ray.take(_PAIRS_A, axis=0) * ray.take(_PAIRS_B, axis=0) * v[3:]
    size = pushed / (np.add.reduce(terms[:3], axis=0) + _TWO * np.add.reduce(terms[3:], axis=0))
    return pushed * size, ray * size


def sample_surface(surface: Surface, spacing_m: float = DEFAULT_SPACING_M) -> SurfaceSamples:
    """Return points on ``surface`` about ``spacing_m`` [m] apart: each triangle is
    split into k^2 similar ones (k from its longest edge) and their centroids are kept,
    deterministic, with the triangle's normal and two tangents."""
    tri = np.asarray(surface.vertices, dtype=float)
    edges = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=2).max(axis=1)
    splits = np.maximum(1, np.ceil(edges / spacing_m).astype(np.int64))
    points, owner, order = [], [], []
    for k in np.unique(splits):
        chosen = np.flatnonzero(splits == k)
        i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
        up, down = (i + j) <= k - 1, (i + j) <= k - 2
        ab = np.concatenate([np.column_stack([(i[up] + 1 / 3) / k, (j[up] + 1 / 3) / k]),
                             np.column_stack([(i[down] + 2 / 3) / k, (j[down] + 2 / 3) / k])])
        t = tri[chosen]
        points.append((t[:, None, 0] + ab[None, :, :1] * (t[:, None, 1] - t[:, None, 0])
                       + ab[None, :, 1:] * (t[:, None, 2] - t[:, None, 0])).reshape(-1, 3))
        owner.append(np.repeat(chosen, len(ab)))
        order.append(np.tile(np.arange(len(ab)), len(chosen)))
    owner_all, order_all = np.concatenate(owner), np.concatenate(order)
    sort = np.lexsort((order_all, owner_all))  # triangle by triangle, as listed
    pts = np.concatenate(points)[sort]
    nrm = np.asarray(surface.normals, dtype=float)[owner_all[sort]]
    pts, keep = _thin(pts, spacing_m)
    nrm = nrm[keep]
    helper = np.where(np.abs(nrm[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(nrm, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(nrm, u)
    return SurfaceSamples(pts, nrm.copy(), (u, v))


def _thin(points: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Keep one point per cubic cell of ``cell_m`` [m] (the first listed); return the
    points and indices."""
    cells = np.floor(points / cell_m).astype(np.int64)
    cells -= cells.min(axis=0)
    size = cells.max(axis=0) + 1
    key = (cells[:, 0] * size[1] + cells[:, 1]) * size[2] + cells[:, 2]
    _, keep = np.unique(key, return_index=True)
    keep = np.sort(keep)
    return points[keep], keep


@dataclass(frozen=True)
class ContactEstimate:
    """One estimate at time ``t_s`` [s]: the touched ``link`` (None without one), the
    contact point in the link frame ``point_link`` and the base frame ``point_base``
    [m], the force on the arm ``force`` [N] (base frame), the residual error [Nm] of
    the link's best fit ``error_nm`` (for links 1-4 that of the best point, not of the
    reported middle one) against the residual's norm ``residual_nm`` [Nm], the best
    other link ``runner_up`` and its error [Nm] (NaN where it was not refined),
    ``confidence`` (0..1, from the noise-weighted errors), ``ambiguous``, and
    ``status``: ok, no-surface (the best link has no collision surface: link known, no
    point or force) or too-small (the residual is too small to isolate)."""

    t_s: float
    status: str
    link: int | None = None
    point_link: np.ndarray | None = None
    point_base: np.ndarray | None = None
    force: np.ndarray | None = None
    error_nm: float = float("nan")
    residual_nm: float = 0.0
    runner_up: int | None = None
    runner_up_error_nm: float = float("nan")
    confidence: float = 0.0
    ambiguous: bool = True

    def to_dict(self) -> dict:
        """Return the estimate as JSON-ready values (lists of 3 numbers, rounded to
        0.1 mm, 0.01 N and 1e-4 Nm; None where there is no value)."""
        def vec(x: np.ndarray | None, digits: int) -> list[float] | None:
            return None if x is None else [round(float(v), digits) for v in x]

        def num(x: float, digits: int) -> float | None:
            return None if not np.isfinite(x) else round(float(x), digits)

        return {"t_s": round(self.t_s, 6), "status": self.status, "link": self.link,
                "point_link_m": vec(self.point_link, 4), "point_base_m": vec(self.point_base, 4),
                "force_n": vec(self.force, 2), "confidence": round(self.confidence, 4),
                "ambiguous": self.ambiguous, "error_nm": num(self.error_nm, 4),
                "residual_nm": num(self.residual_nm, 4), "runner_up": self.runner_up,
                "runner_up_error_nm": num(self.runner_up_error_nm, 4)}


@dataclass(frozen=True)
class IsolatorConfig:
    """Estimator settings: sample spacing [m], friction-cone half-angle [deg], the
    smallest residual norm it isolates [Nm], the residual's noise at rest per joint
    ``joint_noise_nm`` (7) [Nm] and the share of the detector's threshold added to it
    in quadrature for model error (together they weigh the joints; errors are in
    units of them), the error margin per link within which the more proximal link
    wins (``tie``, noise units, in quadrature) and the confidence below which an
    estimate is ambiguous. Set on 112 detected contacts of simulated sessions of
    seeds 7 and 8 (thesis-static, thesis-dynamic, mixed-motion; not the
    evaluation's), link right at the peak, static links 3-7 / all: unweighted with
    the former 0.15 Nm tie 81.5 / 73.2 %; weighted, tie 1.5 / 2 / 3: 90.7 / 73.2,
    88.9 / 76.8, 87.0 / 76.8 %; threshold share 0.05 / 0.1: 92.6 / 72.3, 88.9 /
    76.8 %; a fixed 0.03 Nm instead of the threshold's share 90.7 / 75.9 %. Those
    were measured on the raw residual; the event pipeline now gives the detector's
    low-passed deviation (:mod:`contactkit.classify.events.contact_events`), whose noise
    at rest is 0.013 0.010 0.010 0.008 0.004 0.004 0.005 Nm (joints 1-7, 10 contact-free
    sessions of the default model's ``thesis-static``). Kept after a check on the
    default model's ``thesis-static``, ``thesis-dynamic`` and ``mixed-motion`` (110
    detected contacts, link right at the peak): these settings 97, with that noise
    instead of ``REST_NOISE_NM`` 96 (tie 1.5 / 3: 92 / 98), tie 1.5 / 3 91 / 93."""

    spacing_m: float = DEFAULT_SPACING_M
    cone_deg: float = DEFAULT_CONE_DEG
    min_residual_nm: float = 0.5
    joint_noise_nm: tuple[float, ...] = REST_NOISE_NM
    threshold_share: float = 0.1
    tie: float = 2.0
    ambiguous_below: float = 0.2


class _Coarse(NamedTuple):
    """The fit at the samples of the surface links from row ``first`` (index into the
    links with a surface) on, L of them (padded to the longest, n): squared errors
    ``err`` [Nm^2] (L, n), forces [N] (3, L, n, link frames; the isolator's arrays,
    valid until its next update), each link's best sample ``best`` (L,) and its error
    ``errors`` [Nm] (L,); errors in noise units."""

    first: int
    err: np.ndarray
    forces: np.ndarray
    best: np.ndarray
    errors: np.ndarray


class ContactIsolator:
    """Single-contact isolation and identification (see the module docstring).

    ``model`` is the robot model (pinocchio model, data, ``frame_id``); ``surface``
    gives a link's collision surface (None: the link has none; it is then judged by the
    best wrench at its frame and, if chosen, reported without point and force). Each
    instance owns pinocchio data: one per thread.
    """

    def __init__(self, model: ArmModel, surface: SurfaceProvider,
                 config: IsolatorConfig | None = None) -> None:
        self.config = config = config or IsolatorConfig()
        self.model = model.model
        self.data = self.model.createData()
        self.frames = [model.frame_id(k) for k in range(1, N_JOINTS + 1)]
        self._noise2 = np.square(config.joint_noise_nm)                    # Nm^2
        self.samples: list[SurfaceSamples | None] = []
        for k in range(1, N_JOINTS + 1):
            mesh = surface(k)
            self.samples.append(None if mesh is None else sample_surface(mesh, config.spacing_m))
        parts = [(k, s) for k, s in enumerate(self.samples) if s is not None]
        self._links = np.array([k for k, _ in parts], dtype=np.int64)
        self._surface = {k for k, _ in parts}
        self._bare = [k for k, s in enumerate(self.samples) if s is None]
        self._counts = np.array([len(s.points) for _, s in parts], dtype=np.int64)
        # every link's samples padded to the longest with copies of its first sample
        # whose normal is zero: no force lies in its cone, so its error is |r| and, pads
        # coming last, never a link's best before a real sample (ties go to the first)
        self._width = width = int(self._counts.max()) if parts else 0
        pad = np.arange(width)[None, :] >= self._counts[:, None]          # (L, n)
        fill = [np.minimum(np.arange(width), np.where(np.arange(width) < len(s.points),
                                                      width, 0)) for _, s in parts]

        def padded(get: Callable[[SurfaceSamples], np.ndarray]) -> np.ndarray:
            return np.stack([get(s)[f] for (_, s), f in zip(parts, fill, strict=True)]) \
                if parts else np.zeros((0, 0, 3))

        self._points = padded(lambda s: s.points)                          # (L, n, 3)
        inward = -padded(lambda s: s.normals).transpose(2, 0, 1)          # (3, L, n)
        inward[:, pad] = 0.0
        self._inward = inward.copy()
        self._monomials = _monomials(self._points)                         # (L, 10, n)
        # each sample's first refinement grid p + s u + t v, |s|, |t| <= its half-width;
        # the per-sample tables flat (sample l * n + i) for one take per update
        half = GRIDS[0][1] * config.spacing_m
        self._lifted = _lift(np.stack([self._points, padded(lambda s: s.tangents[0]) * half,
                                       padded(lambda s: s.tangents[1]) * half],
                                      axis=-1)).reshape(-1, 10, 6)         # (L n, 10, 6)
        self._inward_flat = self._inward.reshape(3, -1)                    # (3, L n)
        half = np.radians(config.cone_deg)
        self._cone = _Cone(float(np.cos(half)), float(np.sin(half)))
        self._grids = [_grid_monomials(side) for side, _ in GRIDS]
        # each grid's (s, t) offsets (2, n) and, past the first (centred per link), the
        # buffer of its monomials (REFINE_LINKS, 6, n), row 0 the ones
        self._planes = [grid[1:3] * (h / GRIDS[0][1]) for grid, (_, h) in zip(self._grids, GRIDS,
                                                                             strict=True)]
        self._grid_buffers = {i: np.ones((REFINE_LINKS, 6, grid.shape[1]))
                              for i, grid in enumerate(self._grids) if i}
        self._all_rows = np.arange(len(parts))
        self._link_list = self._links.tolist()
        self._weights_at_rest = self._weights(None)
        self._scratch: dict[tuple[int, int, int], _Scratch] = {}

    def estimate(self, t: float, q: np.ndarray, r: np.ndarray,
                 threshold: np.ndarray | None = None) -> ContactEstimate:
        """Return the estimate for joint positions ``q`` [rad] (7,) and residual ``r``
        [Nm] (7,) (relative to the contact-free baseline) at time ``t`` [s], with the
        contact detector's threshold (7,) [Nm] at that sample (it grows with the
        motion that the model gets wrong; default: the detector's floor at rest)."""
        r = np.asarray(r, dtype=float)
        norm = math.sqrt(float(r @ r))
        if norm < self.config.min_residual_nm:
            return ContactEstimate(t, TOO_SMALL, residual_nm=norm)
        model, data = self.model, self.data
        pin.computeJointJacobians(model, data, np.asarray(q, dtype=float))
        jac = np.empty((N_JOINTS, 6, N_JOINTS))                    # (7, 6, 7) link frames
        for k, fid in enumerate(self.frames):
            jac[k] = pin.getFrameJacobian(model, data, fid, pin.LOCAL)
        # each joint's torque in units of its noise (so are all errors below)
        weights = self._weights_at_rest if threshold is None else self._weights(threshold)
        weighted, rw = jac * weights, r * weights
        rr = float(rw @ rw)
        coeffs = _coefficients(weighted, rw)                       # (7, 9, 10)
        # a link's error is at least the residual on the joints after it: links whose
        # bound leaves them no chance are not searched unless the decision needs them
        bound, seen = [], 0.0
        for x in (rw * rw).tolist():
            seen += x
            bound.append(math.sqrt(max(rr - seen, 0.0)))
        errors = np.array(bound)
        wrenches = {}
        for k in self._bare:
            errors[k], wrenches[k] = _wrench_fit(weighted[k], rw)
        tie = self.config.tie
        limit = PRUNE_SHARE * rr + tie * tie * N_JOINTS
        reach = [k not in self._surface or b * b <= limit for k, b in enumerate(bound)]
        # the bound does not grow along the chain: the links searched are those from
        # the first one within reach on
        first = next((i for i, k in enumerate(self._link_list) if reach[k]),
                     len(self._link_list))
        if not self._link_list:  # no link has a surface: judged by their wrenches alone
            coarse, fits = None, {}
        else:
            coarse = self._coarse(coeffs, rr, first)
            fits = self._search(coarse, coeffs, rr, errors)
        last, link, other = _decide(errors.tolist(), tie)
        if coarse is not None and not (reach[last] and reach[link] and reach[other]):
            coarse = self._coarse(coeffs, rr, 0)
            fits = self._search(coarse, coeffs, rr, errors)
            last, link, other = _decide(errors.tolist(), tie)
        e_link, e_other = float(errors[link]), float(errors[other])
        rival = math.isfinite(e_other)
        # the errors are in noise units: 1 is the noise floor
        confidence = min(max(1.0 - (e_link + 1.0) / (e_other + 1.0), 0.0), 1.0) \
            if rival else 1.0
        rival_error = _torque_error(jac[other], r, fits.get(other), wrenches.get(other))
        common: dict[str, Any] = dict(
            link=link + 1, residual_nm=norm,
            error_nm=_torque_error(jac[link], r, fits.get(link), wrenches.get(link)),
            runner_up=other + 1 if rival else None,
            runner_up_error_nm=rival_error if rival else float("nan"),
            confidence=confidence, ambiguous=confidence < self.config.ambiguous_below)
        if coarse is not None and link in fits and link + 1 < MIN_DETERMINED:
            # the point is undetermined: report the middle one (the error is the best's)
            fits[link] = self._middle(link, coarse)
        if link not in fits:
            return ContactEstimate(t, NO_SURFACE, **common)
        point, force = fits[link]
        placement = pin.updateFramePlacement(model, data, self.frames[link])
        return ContactEstimate(t, OK, point_link=point,
                               point_base=placement.rotation @ point + placement.translation,
                               force=placement.rotation @ force, **common)

    def _weights(self, threshold: np.ndarray | None) -> np.ndarray:
        """Return each joint's weight [1/Nm] (7,): one over its noise, the residual's
        noise at rest and a share of the detector's ``threshold`` [Nm] (7,; None: its
        floor at rest) in quadrature (the threshold stands for model error)."""
        share = self.config.threshold_share * (MIN_NOISE if threshold is None
                                               else np.asarray(threshold, dtype=float))
        return 1.0 / np.sqrt(self._noise2 + share * share)

    def _coarse(self, coeffs: np.ndarray, rr: float, first: int) -> _Coarse:
        """Return the fit at the samples of the surface links from row ``first`` (index
        into the links with a surface) on, from every link's fit coefficients ``coeffs``
        (7, 9, 10) and ``rr`` = |r|^2 [Nm^2] (see :func:`_coarse_fit`)."""
        monomials = self._monomials[first:]
        work = self._work(-1, *monomials.shape[::2])
        np.matmul(coeffs[self._links[first:]], monomials, out=work.into)
        err, forces = _coarse_fit(work, np.array(rr), self._inward[:, first:], self._cone)
        return _Coarse(first, err, forces, err.argmin(axis=1),
                      np.sqrt(np.maximum(np.minimum.reduce(err, axis=1), _ZERO)))

    def _search(self, coarse: _Coarse, coeffs: np.ndarray, rr: float, errors: np.ndarray
                ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Search the surface links of the ``coarse`` fit: set their ``errors`` [Nm] (7,;
        in place) to their coarse fits' and refine the best ones; ``coeffs`` (7, 9, 10)
        are every link's fit coefficients. Return link index -> refined (point [m],
        force [N]) in the link frame."""
        errors[self._links[coarse.first:]] = coarse.errors
        return self._refine(coarse, coeffs, rr, errors)

    def _refine(self, coarse: _Coarse, coeffs: np.ndarray, rr: float, errors: np.ndarray
                ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Refine the best links' points (see the module docstring, step 3) from their
        best samples in the ``coarse`` fit; ``coeffs`` (7, 9, 10) are every link's fit
        coefficients. Update ``errors`` [Nm] (per link) in place and return link index
        -> (point [m], force [N]) in the link frame, for the refined links."""
        links = self._links[coarse.first:]
        order = errors[links].argsort()[:REFINE_LINKS]
        reach = links[order]
        count = len(reach)
        # the grids' points are p0 + s u + t v with (s, t) in units of the first grid's
        # half-width: their monomials are those of (s, t) times a matrix precomputed
        # per sample; each further grid is centred on the previous one's best point
        at = (order + coarse.first) * self._width + coarse.best[order]   # flat samples
        lifted = self._lifted.take(at, axis=0)                            # (m, 10, 6)
        fit_coeffs = coeffs[reach] @ lifted                               # (m, 9, 6)
        inward = self._inward_flat.take(at, axis=1)[:, :, None]          # (3, m, 1)
        centre, rr0 = np.zeros((count, 2, 1)), np.array(rr)
        for i, plane in enumerate(self._planes):
            grid = self._grids[0] if i == 0 else self._centred(i, count, centre)
            work = self._work(i, count, plane.shape[1])
            np.matmul(fit_coeffs, grid, out=work.into)
            local_err, local_force = _fit(work, rr0, inward, self._cone)
            local_best = local_err.argmin(axis=1)
            centre = centre + plane.take(local_best, axis=1).T[:, :, None]
        axes, s, t = lifted[:, 1:4], centre[:, 0], centre[:, 1]          # p0 u v; (m, 1)
        points = axes[:, :, 0] + (axes[:, :, 1] * s + axes[:, :, 2] * t)
        errors[reach] = np.minimum.reduce(local_err, axis=1)
        flat = local_best + self._all_rows[:count] * local_err.shape[1]
        forces = local_force.reshape(3, -1).take(flat, axis=1).T
        return {k: (points[i], forces[i]) for i, k in enumerate(reach.tolist())}

    def _work(self, stage: int, m: int, n: int) -> _Scratch:
        """Return this instance's arrays for m x n candidate points of a ``stage`` (-1:
        the samples, 0, 1, ...: the refinement grids), made once: one stage's results
        stay valid while the next ones run."""
        key = (stage, m, n)
        work = self._scratch.get(key)
        if work is None:
            work = self._scratch[key] = _Scratch(m, n)
        return work

    def _centred(self, i: int, count: int, centre: np.ndarray) -> np.ndarray:
        """Return the monomials 1, s, t, ss, tt, st (count, 6, n) of grid ``i``'s (s, t)
        offsets centred on each link's ``centre`` (count, 2, 1) (first grid's units),
        in grid ``i``'s buffer."""
        grid = self._grid_buffers[i][:count]
        plane = grid[:, 1:3]
        np.add(centre, self._planes[i], out=plane)
        np.multiply(plane, plane, out=grid[:, 3:5])
        np.multiply(plane[:, 0], plane[:, 1], out=grid[:, 5])
        return grid

    def _middle(self, k: int, coarse: _Coarse) -> tuple[np.ndarray, np.ndarray]:
        """Return the point [m] and force [N] (link frame) reported on link index ``k``
        (fewer than 5 loaded joints: the point is undetermined): the sample nearest
        the middle of the link's samples whose ``coarse`` error [Nm] is within ``tie``
        of its best, with its coarse force."""
        row = self._link_list.index(k)
        at = row - coarse.first
        err = coarse.err[at, :self._counts[row]]
        reach = (math.sqrt(max(float(err[coarse.best[at]]), 0.0)) + self.config.tie) ** 2
        close = (err <= reach).nonzero()[0]
        points = self._points[row, close]
        offset = points - np.add.reduce(points, axis=0) / len(close)
        mid = close[int(np.add.reduce(offset * offset, axis=1).argmin())]
        return self._points[row, mid].copy(), coarse.forces[:, at, mid].copy()


def _grid_monomials(side: int) -> np.ndarray:
    """Return the monomials 1, s, t, ss, tt, st (6, side^2) of a square grid of
    ``side`` x ``side`` offsets (s, t) in [-1, 1]^2."""
    s, t = (x.ravel() for x in np.meshgrid(*[np.linspace(-1.0, 1.0, side)] * 2,
                                            indexing="ij"))
    return np.stack([np.ones_like(s), s, t, s * s, t * t, s * t])


def _lift(axes: np.ndarray) -> np.ndarray:
    """Return (..., 10, 6) matrices taking the monomials 1, s, t, ss, tt, st of plane
    coordinates to the monomials (see :func:`_monomials`) of the points p + s u + t v,
    for ``axes`` (..., 3, 3) with columns p, u, v [m]."""
    square = np.einsum("...ac,...bd->...abcd", axes, axes)[..., _PAIRS_A, _PAIRS_B, :, :]
    lifted = np.zeros((*axes.shape[:-2], 10, 6))
    lifted[..., 0, 0] = 1.0
    lifted[..., 1:4, :3] = axes
    lifted[..., 4:, :] = square.reshape(*axes.shape[:-2], 6, 9) @ _GRID_PRODUCTS
    return lifted


def _monomials(points: np.ndarray) -> np.ndarray:
    """Return the monomials 1, x, y, z, xx, yy, zz, xy, xz, yz of points (..., n, 3) as
    (..., 10, n)."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    return np.stack([np.ones_like(x), x, y, z, x * x, y * y, z * z, x * y, x * z, y * z],
                    axis=-2)


def _reference_coefficients(jj: np.ndarray, jr: np.ndarray) -> np.ndarray:
    """Return one link's (9, 10) fit coefficients from J J^T (6, 6) and J r (6,), J =
    [Jv; Jw] (6, 7) its Jacobian in its frame: row i, column m is the coefficient of
    monomial m (see :func:`_monomials`) in b_i (rows 0-2; b = A^T r = a + c x p with
    a = Jv r, c = Jw r) or in the Gram entry (rows 3-8; xx yy zz xy xz yz) of
    G = P + Q S + (Q S)^T + S^T W S, P = Jv Jv^T, Q = Jv Jw^T, W = Jw Jw^T, S = S(p).
    Linear in its inputs; evaluated on unit inputs once to build ``_COEFFICIENT_MAP``."""
    p, qq, w = jj[:3, :3], jj[:3, 3:], jj[3:, 3:]
    a, c = jr[:3], jr[3:]
    terms = [p] + [qq @ s + (qq @ s).T for s in _UNIT_SKEW]
    terms += [_UNIT_SKEW[i].T @ w @ _UNIT_SKEW[j] + (_UNIT_SKEW[j].T @ w @ _UNIT_SKEW[i]
                                                      if i != j else 0.0)
              for i, j in _PAIRS]
    out = np.zeros((9, 10))
    out[:3, 0] = a
    for i in range(3):
        out[:3, 1 + i] = -_UNIT_SKEW[i] @ c                       # c x e_i
    for m, term in enumerate(terms):
        out[3:, m] = [term[i, j] for i, j in _PAIRS]
    return out


def _coefficient_map() -> tuple[np.ndarray, np.ndarray]:
    """Return the (42, 90) matrix taking [J J^T (36), J r (6)] to the (9, 10) fit
    coefficients of :func:`_reference_coefficients`, flattened, with the ridge that
    keeps the Gram matrix invertible folded in: ``RIDGE`` times its trace added to its
    diagonal (linear, in the matrix) and ``TINY`` (the constant, (90,))."""
    basis = np.eye(42)
    linear = np.stack([_reference_coefficients(e[:36].reshape(6, 6), e[36:])
                       for e in basis])                           # (42, 9, 10)
    linear[:, 3:6] += RIDGE * linear[:, 3:6].sum(axis=1, keepdims=True)
    constant = np.zeros((9, 10))
    constant[3:6, 0] = TINY
    return linear.reshape(42, 90), constant.ravel()


_COEFFICIENT_MAP, _COEFFICIENT_CONSTANT = _coefficient_map()


def _coefficients(jac: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Return every link's (9, 10) fit coefficients (see :func:`_coefficient_map`)
    from the links' Jacobians ``jac`` (m, 6, 7, link frames) and the residual ``r``
    [Nm] (7,), as (m, 9, 10)."""
    jj = jac @ jac.transpose(0, 2, 1)
    inputs = np.concatenate([jj.reshape(len(jac), 36), jac @ r], axis=1)
    return (inputs @ _COEFFICIENT_MAP + _COEFFICIENT_CONSTANT).reshape(len(jac), 9, 10)


def _torque_error(jac: np.ndarray, r: np.ndarray, fit: tuple[np.ndarray, np.ndarray] | None,
                  wrench: np.ndarray | None) -> float:
    """Return the residual error [Nm] |r - J^T w| of a link's fit, from its Jacobian
    ``jac`` (6, 7, link frame), the residual ``r`` [Nm] and its (point [m], force [N])
    ``fit`` or else its ``wrench`` [N, Nm]; NaN with neither."""
    if fit is not None:
        (px, py, pz), (fx, fy, fz) = fit[0].tolist(), fit[1].tolist()
        wrench = np.array([fx, fy, fz, py * fz - pz * fy, pz * fx - px * fz, px * fy - py * fx])
    if wrench is None:
        return float("nan")
    miss = r - jac.T @ wrench
    return math.sqrt(float(miss @ miss))


def _wrench_fit(jac: np.ndarray, r: np.ndarray) -> tuple[float, np.ndarray]:
    """Return the residual error of the best wrench at a link frame (no point) and the
    wrench [N, Nm] for a link's (weighted) Jacobian ``jac`` (6, 7) and residual ``r``
    (7,), in the residual's units."""
    w, *_ = np.linalg.lstsq(jac.T, r, rcond=None)
    return float(np.linalg.norm(r - jac.T @ w)), w


DEFAULT_TRACK_HZ = 50.0


class EventTrack:
    """The estimates of one contact event, sample by sample: every ``1 / rate_hz`` s
    from the onset (the hold track), at the decision, and at the peak of |e| (computed
    at the next track tick after a new peak, and when the event ends), so at most two
    estimates per tick. Batch and streaming feed it the same samples in the same order.
    With ``keep`` the hold track's estimates are kept in ``track``; without it
    ``track`` stays empty and only the last one (``last``) is held.
    """

    def __init__(self, isolator: ContactIsolator, onset_s: float,
                 rate_hz: float = DEFAULT_TRACK_HZ, keep: bool = True) -> None:
        self.isolator = isolator
        self.period = 1.0 / rate_hz
        self.next_s = onset_s
        self.keep = keep
        self.track: list[ContactEstimate] = []
        self.last: ContactEstimate | None = None
        """The hold track's latest estimate (None before the first)."""
        self.peak: ContactEstimate | None = None
        self._peak_norm = -1.0
        self._pending: tuple[float, np.ndarray, np.ndarray, np.ndarray | None] | None = None

    def update(self, t: float, q: np.ndarray, e: np.ndarray,
               threshold: np.ndarray | None = None) -> ContactEstimate | None:
        """Feed one sample of the event: time [s], q [rad] (7,), deviation of the
        residual from its contact-free baseline e [Nm] (7,) and the detector's
        threshold [Nm] (7,) (see :meth:`ContactIsolator.estimate`). Return the hold
        track's estimate made at this sample (None when none is due)."""
        norm = math.sqrt(float(e @ e))  # |e|, as np.linalg.norm computes it
        if norm > self._peak_norm:
            self._peak_norm = norm
            self._pending = (t, np.array(q, dtype=float), np.array(e, dtype=float),
                             None if threshold is None else np.array(threshold, dtype=float))
        if t < self.next_s - 1e-12:
            return None
        self.last = made = self.isolator.estimate(t, q, e, threshold)
        if self.keep:
            self.track.append(made)
        while self.next_s <= t + 1e-12:
            self.next_s += self.period
        self._settle_peak()
        return made

    def at(self, t: float, q: np.ndarray, e: np.ndarray,
           threshold: np.ndarray | None = None) -> ContactEstimate:
        """Return the estimate at this sample (time [s], q [rad], e [Nm], threshold
        [Nm]): the track's when it has one for ``t``, else a new one."""
        if self.last is not None and self.last.t_s == t:
            return self.last
        return self.isolator.estimate(t, q, e, threshold)

    def finish(self) -> ContactEstimate | None:
        """Return the estimate at the peak of |e| so far (computing a pending one)."""
        self._settle_peak()
        return self.peak

    def _settle_peak(self) -> None:
        if self._pending is None:
            return
        pending, self._pending = self._pending, None
        self.peak = self.at(*pending)


_ISOLATORS = threading.local()
"""Each thread's isolators by arm and configuration (an isolator's pinocchio data is not
shared between threads)."""


def robot_isolator(robot: RobotSetup, config: IsolatorConfig | None = None) -> ContactIsolator:
    """Return the contact isolator of an arm as mounted (``robot``: the session's robot,
    hand and payload), on its collision surfaces (link 7's includes the hand when it is
    mounted); built once per arm, configuration and thread, so that threads never share
    one (an isolator owns pinocchio data)."""
    built: dict[tuple[RobotSetup, IsolatorConfig | None], ContactIsolator] = (
        _ISOLATORS.__dict__.setdefault("by_arm", {}))
    if (robot, config) not in built:
        def surface(link: int) -> LinkSurface | None:
            found = link_surface(robot, link)
            return None if found.empty else found

        built[robot, config] = ContactIsolator(RobotModel(robot), surface, config)
    return built[robot, config]
