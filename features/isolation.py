"""Contact isolation and identification from the observer residual: which link was
touched, where on its collision surface, and the force vector.

A single point force F [N] at point p on link k gives the joint torque

    r = J_k(q, p)^T F = Jv^T F + Jw^T (p x F)        (Nm; joints after k see nothing)

with Jv, Jw the linear and angular rows of link k's frame Jacobian. The estimator is a
least-squares search over precomputed samples of each link's collision surface (the
meshes the simulator uses, about ``spacing_m`` apart), in the link frame so that the
samples never move, followed by a local refinement:

1. Per update one ``computeJointJacobians`` gives every link's Jacobian. Per sample
   point, the normal equations of F are in closed form: b = A^T r = a + c x p is
   linear in p and the Gram matrix A^T A (A = Jv^T + Jw^T S(p)) quadratic, so its six
   entries for all samples are one product of the samples' monomials with
   coefficients computed once per link; the 3x3 solve is elementwise (cofactors).
2. The force must push into the surface, within ``cone_deg`` of the inward normal.
   Where the free least-squares force does not, the best force on ``CONE_RAYS`` rays
   of the cone's boundary or along the normal is taken instead (the optimum of a
   convex problem whose free optimum lies outside the cone is on its boundary), but
   only for samples whose free error could still beat the link's best.
3. The ``REFINE_LINKS`` links with the smallest errors are refined from their best
   sample: the same fit on a 7 x 7 grid in the sample's face plane, one spacing
   either side, then on grids a third and a ninth as wide around the best point
   (about 1 mm apart at the end), which removes most of the sampling error.
4. The link is the lowest one whose squared error exceeds the smallest (on link m)
   by at most ``tie_nm``^2 per link between them: a link-k contact is generically
   also explained by a point on link k + 1 whose force line meets joint k + 1's axis,
   and each more distal link absorbs one more joint's noise, so the proximal
   explanation wins unless the distal one is better by more than noise. With fewer
   than five loaded joints (links 1-4) the torques leave the point undetermined along
   a curve: the reported point is the sample nearest the middle of the link's samples
   within ``tie_nm`` of its best, the least-risk guess.

The confidence compares the chosen link's error with the best other link's:
1 - (e_chosen + noise) / (e_other + noise), clipped to 0..1, with ``noise_nm`` the
residual noise; ``ambiguous`` when it is below ``ambiguous_below``. A residual below
``min_residual_nm`` or a best link without a collision surface gives an estimate with
no point and no force and a ``status`` that says why (not an error).

Units: q [rad], r [Nm], points [m], forces [N], errors [Nm].
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Protocol

import numpy as np
import pinocchio as pin

from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.robots.surfaces import LinkSurface, link_surface

N_JOINTS = 7
CONE_RAYS = 8
REFINE_LINKS = 3
MIN_DETERMINED = 5
GRID_SIDE, GRID_PASSES = 7, 3
GRID_POINTS = GRID_SIDE * GRID_SIDE
DEFAULT_SPACING_M = 0.03
DEFAULT_CONE_DEG = 60.0
RIDGE = 1e-9
TINY = 1e-12  # m^2, keeps a point whose Jacobian vanishes (on joint 1's axis) finite
OK, NO_SURFACE, TOO_SMALL = "ok", "no-surface", "too-small"


class Surface(Protocol):
    """A link's collision surface in the link frame: triangles ``vertices`` (n, 3, 3)
    [m], unit outward ``normals`` (n, 3) and ``areas`` (n,) [m^2]."""

    vertices: np.ndarray
    normals: np.ndarray
    areas: np.ndarray


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
    and two unit tangents (n, 3) each; per point the unit force directions on the
    boundary of its friction cone and the inward normal, ``rays`` (3, n, CONE_RAYS +
    1) (components first). All in the link frame."""

    points: np.ndarray
    normals: np.ndarray
    tangents: tuple[np.ndarray, np.ndarray]
    rays: np.ndarray


@dataclass(frozen=True)
class PointSet:
    """Candidate contact points in blocks (one link each): points (n, 3) [m] and unit
    outward normals (n, 3) in their link's frame, the friction-cone ``rays`` (3, n, R)
    of each point, block boundaries ``starts`` (blocks + 1,), the squared cosine of the
    cone's half-angle, and the products of each ray's components (6, n, R; computed
    when not given)."""

    points: np.ndarray
    normals: np.ndarray
    rays: np.ndarray
    starts: np.ndarray
    cone_cos2: float
    ray_products: np.ndarray | None = None

    def __post_init__(self) -> None:
        d = self.rays
        derived = {"columns": np.ascontiguousarray(self.points.T),
                   "normal_columns": np.ascontiguousarray(self.normals.T),
                   "monomials": _monomials(self.points).T.copy(),
                   "owner": np.repeat(np.arange(len(self.starts) - 1), np.diff(self.starts))}
        if self.ray_products is None:
            derived["ray_products"] = np.stack([d[0] ** 2, d[1] ** 2, d[2] ** 2,
                                                2 * d[0] * d[1], 2 * d[0] * d[2],
                                                2 * d[1] * d[2]])
        for name, value in derived.items():
            object.__setattr__(self, name, value)


def _fit(a: np.ndarray, c: np.ndarray, coeffs: np.ndarray, rr: float, points: PointSet
         ) -> tuple[np.ndarray, np.ndarray]:
    """Return each candidate point's residual error [Nm] (n,) and force [N] (n, 3, link
    frame): the least-squares force if it lies in the friction cone, else the best one
    on the cone's rays. Per block (its link): ``a`` = Jv r and ``c`` = Jw r (blocks, 3)
    and the Gram coefficients (blocks, 10, 6) of :func:`_gram_coefficients`, with Jv,
    Jw the link's Jacobian rows in its frame; ``rr`` = |r|^2 [Nm^2]. Points whose
    constrained error cannot beat their block's best feasible one keep that bound as
    their error (they are never the block's best)."""
    owner, starts = points.owner, points.starts
    a, c = a[owner].T, c[owner].T                                   # (3, n)
    px, py, pz = points.columns
    bx = a[0] + c[1] * pz - c[2] * py
    by = a[1] + c[2] * px - c[0] * pz
    bz = a[2] + c[0] * py - c[1] * px
    g = np.empty((6, len(owner)))
    for i in range(len(coeffs)):
        s = slice(starts[i], starts[i + 1])
        g[:, s] = np.einsum("me,mn->en", coeffs[i], points.monomials[:, s])
    ridge = RIDGE * (g[0] + g[1] + g[2]) + TINY
    g00, g11, g22, g01, g02, g12 = g[0] + ridge, g[1] + ridge, g[2] + ridge, g[3], g[4], g[5]
    c00, c11, c22 = g11 * g22 - g12 * g12, g00 * g22 - g02 * g02, g00 * g11 - g01 * g01
    c01, c02, c12 = g02 * g12 - g01 * g22, g01 * g12 - g02 * g11, g01 * g02 - g00 * g12
    inv_det = 1.0 / (g00 * c00 + g01 * c01 + g02 * c02)
    fx = (c00 * bx + c01 * by + c02 * bz) * inv_det
    fy = (c01 * bx + c11 * by + c12 * bz) * inv_det
    fz = (c02 * bx + c12 * by + c22 * bz) * inv_det
    gain = bx * fx + by * fy + bz * fz
    nx, ny, nz = points.normal_columns
    inward = -(nx * fx + ny * fy + nz * fz)
    feasible = (inward > 0) & (inward * inward >= points.cone_cos2
                               * (fx * fx + fy * fy + fz * fz))
    # the best feasible gain per block bounds which infeasible points can still win
    bound = np.maximum.reduceat(np.where(feasible, gain, -np.inf), starts[:-1])
    outside = np.flatnonzero(~feasible & (gain > bound[owner]))
    if len(outside):
        dx, dy, dz = points.rays[:, outside]
        bd = dx * bx[outside, None] + dy * by[outside, None] + dz * bz[outside, None]
        prods, go = points.ray_products[:, outside], g[:, outside, None]
        dgd = (prods[0] * go[0] + prods[1] * go[1] + prods[2] * go[2]
               + prods[3] * go[3] + prods[4] * go[4] + prods[5] * go[5])
        ray_gain = np.where(bd > 0, bd * bd / dgd, 0.0)
        best = np.argmax(ray_gain, axis=1)
        rows = np.arange(len(best))
        scale = np.maximum(bd[rows, best], 0.0) / dgd[rows, best]
        fx[outside], fy[outside], fz[outside] = (dx[rows, best] * scale,
                                                 dy[rows, best] * scale,
                                                 dz[rows, best] * scale)
        gain[outside] = ray_gain[rows, best]
    rest = ~feasible
    rest[outside] = False
    gain[rest] = np.minimum(gain[rest], bound[owner[rest]])
    err = np.sqrt(np.maximum(rr - gain, 0.0))
    return np.where(np.isfinite(err), err, np.inf), np.stack([fx, fy, fz], axis=1)


def sample_surface(surface: Surface, spacing_m: float = DEFAULT_SPACING_M,
                   cone_deg: float = DEFAULT_CONE_DEG) -> SurfaceSamples:
    """Return points on ``surface`` about ``spacing_m`` [m] apart: each triangle is
    split into k^2 similar ones (k from its longest edge) and their centroids are kept,
    deterministic, with the triangle's normal and the cone rays of half-angle
    ``cone_deg`` [deg] around the inward normal."""
    points, normals = [], []
    for tri, normal in zip(surface.vertices, surface.normals, strict=True):
        edge = max(np.linalg.norm(tri[1] - tri[0]), np.linalg.norm(tri[2] - tri[1]),
                   np.linalg.norm(tri[0] - tri[2]))
        k = max(1, int(np.ceil(edge / spacing_m)))
        i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
        up = (i + j) <= k - 1
        down = (i + j) <= k - 2
        bary = [np.column_stack([(i[up] + 1 / 3) / k, (j[up] + 1 / 3) / k]),
                np.column_stack([(i[down] + 2 / 3) / k, (j[down] + 2 / 3) / k])]
        ab = np.concatenate(bary)
        points.append(tri[0] + ab[:, :1] * (tri[1] - tri[0]) + ab[:, 1:] * (tri[2] - tri[0]))
        normals.append(np.broadcast_to(normal, (len(ab), 3)))
    pts, nrm = np.concatenate(points), np.concatenate(normals)
    pts, keep = _thin(pts, spacing_m)
    nrm = nrm[keep]
    helper = np.where(np.abs(nrm[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(nrm, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(nrm, u)
    phi = np.arange(CONE_RAYS) * 2 * np.pi / CONE_RAYS
    half = np.radians(cone_deg)
    side = np.cos(phi)[None, :, None] * u[:, None] + np.sin(phi)[None, :, None] * v[:, None]
    rays = -np.cos(half) * nrm[:, None] + np.sin(half) * side
    rays = np.concatenate([rays, -nrm[:, None]], axis=1).transpose(2, 0, 1).copy()
    return SurfaceSamples(pts, nrm.copy(), (u, v), rays)


def _thin(points: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Keep one point per cubic cell of ``cell_m`` [m]; return the points and indices."""
    cells = np.floor(points / cell_m).astype(np.int64)
    _, keep = np.unique(cells, axis=0, return_index=True)
    keep = np.sort(keep)
    return points[keep], keep


@dataclass(frozen=True)
class ContactEstimate:
    """One estimate at time ``t_s`` [s]: the touched ``link`` (None without one), the
    contact point in the link frame ``point_link`` and the base frame ``point_base``
    [m], the force on the arm ``force`` [N] (base frame), the fit's residual error
    ``error_nm`` [Nm] against the residual's norm ``residual_nm`` [Nm], the best other
    link ``runner_up`` and its error [Nm], ``confidence`` (0..1), ``ambiguous``, and
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
    smallest residual norm it isolates [Nm], the error margin per link within which
    the more proximal link wins [Nm, in quadrature], the residual noise for the
    confidence [Nm] and the confidence below which an estimate is ambiguous.
    ``tie_nm`` = 0.15: on residuals of random contacts on links 1-7 with 0.1 Nm noise
    per joint (benchmarks/bench_isolation.py's), 0.05 / 0.15 / 0.2 / 0.3 named the
    link in 73 / 82 / 81 / 77 % of 300; at the peak of the 104 detected contacts of
    the default model's simulated sessions (not the evaluation's), 0 / 0.05 / 0.1 /
    0.15 / 0.25 named it in 61 / 66 / 76 / 80 / 70 % (too distal at 0, too proximal
    at 0.25)."""

    spacing_m: float = DEFAULT_SPACING_M
    cone_deg: float = DEFAULT_CONE_DEG
    min_residual_nm: float = 0.5
    tie_nm: float = 0.15
    noise_nm: float = 0.1
    ambiguous_below: float = 0.2


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
        self.samples: list[SurfaceSamples | None] = []
        for k in range(1, N_JOINTS + 1):
            mesh = surface(k)
            self.samples.append(None if mesh is None else sample_surface(
                mesh, config.spacing_m, config.cone_deg))
        parts = [(k, s) for k, s in enumerate(self.samples) if s is not None]
        self._links = np.array([k for k, _ in parts], dtype=np.int64)
        self._bare = [k for k, s in enumerate(self.samples) if s is None]
        empty = np.zeros((0, 3))
        self._points = np.concatenate([s.points for _, s in parts]) if parts else empty
        self._normals = np.concatenate([s.normals for _, s in parts]) if parts else empty
        self._tangents = [np.concatenate([s.tangents[i] for _, s in parts]) if parts
                          else empty for i in (0, 1)]
        rays = np.concatenate([s.rays for _, s in parts], axis=1) if parts else \
            np.zeros((3, 0, CONE_RAYS + 1))
        self._set = PointSet(self._points, self._normals, rays,
                             np.cumsum([0, *(len(s.points) for _, s in parts)]),
                             float(np.cos(np.radians(config.cone_deg))) ** 2)
        self._grid_halves = [config.spacing_m / 3.0 ** i for i in range(GRID_PASSES)]

    def estimate(self, t: float, q: np.ndarray, r: np.ndarray) -> ContactEstimate:
        """Return the estimate for joint positions ``q`` [rad] (7,) and residual ``r``
        [Nm] (7,) (relative to the contact-free baseline) at time ``t`` [s]."""
        r = np.asarray(r, dtype=float)
        norm = float(np.linalg.norm(r))
        if norm < self.config.min_residual_nm:
            return ContactEstimate(t, TOO_SMALL, residual_nm=norm)
        model, data, rr = self.model, self.data, norm * norm
        pin.computeJointJacobians(model, data, np.asarray(q, dtype=float))
        pin.updateFramePlacements(model, data)
        jac = np.stack([pin.getFrameJacobian(model, data, fid, pin.LOCAL)
                        for fid in self.frames])                   # link frames
        jv, jw = jac[:, :3], jac[:, 3:]
        errors = np.full(N_JOINTS, np.inf)
        for k in self._bare:
            errors[k] = _wrench_error(np.vstack([jv[k], jw[k]]), r, rr)
        terms = (jv @ r, jw @ r, _gram_coefficients(jv, jw))
        links = self._links
        err, force = _fit(*(x[links] for x in terms), rr, self._set)
        if len(err):
            errors[links] = np.minimum.reduceat(err, self._set.starts[:-1])
        fits = self._refine(terms, rr, err, force, errors)
        last = int(np.argmin(errors))
        allowance = self.config.tie_nm ** 2 * (last - np.arange(N_JOINTS))
        squared = errors * errors
        link = int(np.flatnonzero(squared <= squared[last] + allowance)[0]) + 1
        others = np.delete(errors, link - 1)
        other = int(np.argmin(others))
        e_link, e_other = float(errors[link - 1]), float(others[other])
        noise = self.config.noise_nm
        confidence = float(np.clip(1.0 - (e_link + noise) / (e_other + noise), 0.0, 1.0)) \
            if np.isfinite(e_other) else 1.0
        common = dict(link=link, error_nm=e_link, residual_nm=norm,
                      runner_up=other + 1 + (other + 1 >= link) if np.isfinite(e_other)
                      else None, runner_up_error_nm=e_other, confidence=confidence,
                      ambiguous=confidence < self.config.ambiguous_below)
        if link - 1 not in fits:
            return ContactEstimate(t, NO_SURFACE, **common)
        point, force = fits[link - 1]
        placement = data.oMf[self.frames[link - 1]]
        return ContactEstimate(t, OK, point_link=point,
                               point_base=placement.rotation @ point + placement.translation,
                               force=placement.rotation @ force, **common)

    def _refine(self, terms: tuple[np.ndarray, np.ndarray, np.ndarray], rr: float,
                err: np.ndarray, force: np.ndarray, errors: np.ndarray
                ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Refine the best links' points (see the module docstring, step 3) from the
        samples' errors ``err`` [Nm] and forces [N]; ``terms`` are every link's inputs
        to :func:`_fit`. Update ``errors`` [Nm] (per link) in place and return link
        index -> (point [m], force [N]) in the link frame, for the refined links."""
        tie = self.config.tie_nm
        reach = [int(k) for k in np.argsort(errors)[:REFINE_LINKS]
                 if np.isfinite(errors[k]) and self.samples[k] is not None]
        if not reach:
            return {}
        owner, idx, middle = [], [], {}
        for k in reach:
            i = int(np.searchsorted(self._links, k))
            s0, s1 = self._set.starts[i], self._set.starts[i + 1]
            idx.append(s0 + int(np.argmin(err[s0:s1])))
            owner.append(k)
            if k + 1 < MIN_DETERMINED:
                close = s0 + np.flatnonzero(err[s0:s1] <= errors[k] + tie)
                offset = self._points[close] - self._points[close].mean(axis=0)
                centre = close[int(np.argmin(np.einsum("ni,ni->n", offset, offset)))]
                middle[k] = (self._points[centre].copy(), force[centre].copy())
        idx = np.array(idx)
        points, chosen, fit_err = self._points[idx], force[idx], err[idx]
        for half in self._grid_halves:
            grid = self._local_set(idx, points, half)
            local_err, local_force = _fit(*(x[owner] for x in terms), rr, grid)
            at = grid.starts[:-1] + np.argmin(local_err.reshape(-1, GRID_POINTS), axis=1)
            better = local_err[at] < fit_err
            fit_err = np.where(better, local_err[at], fit_err)
            points = np.where(better[:, None], grid.points[at], points)
            chosen = np.where(better[:, None], local_force[at], chosen)
        fits = {}
        for m, k in enumerate(owner):
            errors[k] = float(fit_err[m])
            # with fewer than 5 loaded joints the point is undetermined: keep the middle
            fits[k] = middle.get(k, (points[m].copy(), chosen[m].copy()))
        return fits

    def _local_set(self, idx: np.ndarray, points: np.ndarray, half: float) -> PointSet:
        """Return a ``GRID_SIDE`` x ``GRID_SIDE`` grid of points of half-width ``half``
        [m] in the face plane of each sample ``idx``, around ``points`` (m, 3)."""
        u, v = self._tangents[0][idx], self._tangents[1][idx]
        grid = (points[:, None] + _GRID[None, :, :1] * half * u[:, None]
                + _GRID[None, :, 1:] * half * v[:, None]).reshape(-1, 3)
        rows = np.repeat(idx, GRID_POINTS)
        return PointSet(grid, self._normals[rows], self._set.rays[:, rows],
                        np.arange(0, len(grid) + 1, GRID_POINTS), self._set.cone_cos2,
                        self._set.ray_products[:, rows])


_UNIT_SKEW = np.array([[[0, 0, 0], [0, 0, -1], [0, 1, 0]],
                       [[0, 0, 1], [0, 0, 0], [-1, 0, 0]],
                       [[0, -1, 0], [1, 0, 0], [0, 0, 0]]], dtype=float)
"""S(e_i) for the unit vectors: S(p) = sum_i p_i S(e_i), S(p) F = p x F."""
_PAIRS = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
_GRID = np.stack(np.meshgrid(*[np.linspace(-1.0, 1.0, GRID_SIDE)] * 2, indexing="ij"),
                 axis=-1).reshape(-1, 2)
"""Offsets of a refinement grid in units of its half-width, (GRID_POINTS, 2)."""
_ROWS, _COLS = (np.array(x) for x in zip(*_PAIRS, strict=True))


def _monomials(points: np.ndarray) -> np.ndarray:
    """Return (n, 10) monomials of the points: 1, x, y, z, xx, yy, zz, xy, xz, yz."""
    x, y, z = points.T
    return np.column_stack([np.ones(len(points)), x, y, z, x * x, y * y, z * z,
                            x * y, x * z, y * z])


def _gram_coefficients(jv: np.ndarray, jw: np.ndarray) -> np.ndarray:
    """Return (m, 10, 6) coefficients for m links' Jacobian rows ``jv``, ``jw`` (m, 3,
    7): a point p's Gram entries (xx yy zz xy xz yz) are ``_monomials(p) @`` them, for
    G = P + Q S + (Q S)^T + S^T W S with P = Jv Jv^T, Q = Jv Jw^T, W = Jw Jw^T and
    S = S(p)."""
    pp = np.einsum("maj,mbj->mab", jv, jv)
    qq = np.einsum("maj,mbj->mab", jv, jw)
    ww = np.einsum("maj,mbj->mab", jw, jw)
    lin = np.einsum("mab,ibc->miac", qq, _UNIT_SKEW)              # Q S(e_i)
    lin = lin + lin.transpose(0, 1, 3, 2)
    quad = np.einsum("miac,jcd->mijad", np.einsum("iba,mbc->miac", _UNIT_SKEW, ww),
                     _UNIT_SKEW)                                   # S_i^T W S_j
    coeffs = np.stack([pp, lin[:, 0], lin[:, 1], lin[:, 2], quad[:, 0, 0], quad[:, 1, 1],
                       quad[:, 2, 2], quad[:, 0, 1] + quad[:, 1, 0],
                       quad[:, 0, 2] + quad[:, 2, 0], quad[:, 1, 2] + quad[:, 2, 1]], axis=1)
    return coeffs[:, :, _ROWS, _COLS]


def _wrench_error(jac: np.ndarray, r: np.ndarray, rr: float) -> float:
    """Return the residual error [Nm] of the best wrench at a link frame (no point)."""
    w, *_ = np.linalg.lstsq(jac.T, r, rcond=None)
    return float(np.sqrt(max(rr - float(r @ (jac.T @ w)), 0.0)))


DEFAULT_TRACK_HZ = 50.0


class EventTrack:
    """The estimates of one contact event, sample by sample: every ``1 / rate_hz`` s
    from the onset (the hold track), at the decision, and at the peak of |e| (computed
    at the next track tick after a new peak, and when the event ends), so at most two
    estimates per tick. Batch and streaming feed it the same samples in the same order.
    """

    def __init__(self, isolator: ContactIsolator, onset_s: float,
                 rate_hz: float = DEFAULT_TRACK_HZ) -> None:
        self.isolator = isolator
        self.period = 1.0 / rate_hz
        self.next_s = onset_s
        self.track: list[ContactEstimate] = []
        self.peak: ContactEstimate | None = None
        self._peak_norm = -1.0
        self._pending: tuple[float, np.ndarray, np.ndarray] | None = None

    def update(self, t: float, q: np.ndarray, e: np.ndarray) -> None:
        """Feed one sample of the event: time [s], q [rad] (7,), deviation of the
        residual from its contact-free baseline e [Nm] (7,)."""
        norm = float(np.linalg.norm(e))
        if norm > self._peak_norm:
            self._peak_norm = norm
            self._pending = (t, np.array(q, dtype=float), np.array(e, dtype=float))
        if t >= self.next_s - 1e-12:
            self.track.append(self.isolator.estimate(t, q, e))
            while self.next_s <= t + 1e-12:
                self.next_s += self.period
            self._settle_peak()

    def at(self, t: float, q: np.ndarray, e: np.ndarray) -> ContactEstimate:
        """Return the estimate at this sample (time [s], q [rad], e [Nm]): the track's
        when it has one for ``t``, else a new one."""
        if self.track and self.track[-1].t_s == t:
            return self.track[-1]
        return self.isolator.estimate(t, q, e)

    def finish(self) -> ContactEstimate | None:
        """Return the estimate at the peak of |e| so far (computing a pending one)."""
        self._settle_peak()
        return self.peak

    def _settle_peak(self) -> None:
        if self._pending is None:
            return
        t, q, e = self._pending
        self._pending = None
        self.peak = self.at(t, q, e)


@cache
def robot_isolator(robot: RobotSetup, config: IsolatorConfig | None = None) -> ContactIsolator:
    """Return the contact isolator of an arm as mounted (``robot``: the session's robot,
    hand and payload), on its collision surfaces (link 7's includes the hand when it is
    mounted); built once per arm and configuration."""
    def surface(link: int) -> LinkSurface | None:
        found = link_surface(robot, link)
        return None if found.empty else found

    return ContactIsolator(RobotModel(robot), surface, config)
