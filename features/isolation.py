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
   samples and the middle one (see 4): Gauss-Newton steps on the force and the point moved within its face's
   plane (by at most one spacing), which removes most of the sampling error.
4. The link is the lowest one whose error is within ``tie_nm`` of the smallest: a
   link-k contact is generically also explained by a point on link k + 1 whose force
   line meets joint k + 1's axis, and the proximal explanation is the generic one.
   The sample it starts from is the one nearest the middle of the link's samples
   within ``tie_nm`` of its best: with fewer than five loaded joints the torques leave
   the point undetermined along a curve, and its middle is the least-risk guess.

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
from typing import Protocol

import numpy as np
import pinocchio as pin

N_JOINTS = 7
CONE_RAYS = 8
REFINE_LINKS = 3
REFINE_STEPS = 6
REFINE_STARTS = 3
MIN_DETERMINED = 5
DEFAULT_SPACING_M = 0.03
DEFAULT_CONE_DEG = 60.0
RIDGE = 1e-9
DAMPING = 1e-6
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
    """What the estimator needs of a robot model: pinocchio ``model`` and ``data`` and
    the frame id of link 1..7."""

    model: pin.Model
    data: pin.Data

    def frame_id(self, link: int) -> int:
        """Return the pinocchio frame id of link 1..7."""


@dataclass(frozen=True)
class SurfaceSamples:
    """Sample points (n, 3) [m] on a link's surface, their unit outward normals (n, 3)
    and two unit tangents (n, 3) each; per point the unit force directions on the
    boundary of its friction cone and the inward normal, ``rays`` (3, n, CONE_RAYS +
    1) (components first); the cosine of the cone's half-angle. All in the link
    frame."""

    points: np.ndarray
    normals: np.ndarray
    tangents: tuple[np.ndarray, np.ndarray]
    rays: np.ndarray
    cone_cos: float


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
    return SurfaceSamples(pts, nrm.copy(), (u, v), rays, float(np.cos(half)))


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
    smallest residual norm it isolates [Nm], the error margin within which the lower
    link wins [Nm], the residual noise for the confidence [Nm] and the confidence
    below which an estimate is ambiguous."""

    spacing_m: float = DEFAULT_SPACING_M
    cone_deg: float = DEFAULT_CONE_DEG
    min_residual_nm: float = 0.5
    tie_nm: float = 0.05
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
        sizes = [len(s.points) for _, s in parts]
        self._starts = np.cumsum([0, *sizes])
        self._owner = np.repeat(np.arange(len(parts)), sizes)
        points = np.concatenate([s.points for _, s in parts]) if parts else np.zeros((0, 3))
        self._points = points
        self._columns = np.ascontiguousarray(points.T)
        self._monomials = _monomials(points).T.copy()
        self._normals = np.concatenate([s.normals for _, s in parts]) if parts else points
        self._normal_columns = np.ascontiguousarray(self._normals.T)
        self._tangents = [np.concatenate([s.tangents[i] for _, s in parts]) if parts
                          else points for i in (0, 1)]
        rays = np.concatenate([s.rays for _, s in parts], axis=1) if parts else \
            np.zeros((3, 0, CONE_RAYS + 1))
        self._rays = rays
        self._ray_products = np.stack([rays[0] ** 2, rays[1] ** 2, rays[2] ** 2,
                                       2 * rays[0] * rays[1], 2 * rays[0] * rays[2],
                                       2 * rays[1] * rays[2]])
        self._cone_cos2 = float(np.cos(np.radians(config.cone_deg))) ** 2
        self._cone_tan = float(np.tan(np.radians(config.cone_deg)))

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
        jv, jw = np.empty((N_JOINTS, 3, N_JOINTS)), np.empty((N_JOINTS, 3, N_JOINTS))
        for k, fid in enumerate(self.frames):
            jac = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            rot_t = data.oMf[fid].rotation.T
            jv[k], jw[k] = rot_t @ jac[:3], rot_t @ jac[3:]
        errors = np.full(N_JOINTS, np.inf)
        for k in self._bare:
            errors[k] = _wrench_error(np.vstack([jv[k], jw[k]]), r, rr)
        err, fx, fy, fz = self._sample_errors(jv[self._links], jw[self._links], r, rr)
        if len(err):
            errors[self._links] = np.minimum.reduceat(err, self._starts[:-1])
        fits = self._refine(jv, jw, r, rr, err, np.stack([fx, fy, fz], axis=1), errors)
        best = float(errors.min())
        link = int(np.flatnonzero(errors <= best + self.config.tie_nm)[0]) + 1
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

    def _sample_errors(self, jv: np.ndarray, jw: np.ndarray, r: np.ndarray, rr: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Return every sample's residual error [Nm] and force components [N] (link
        frame), for the links' Jacobian rows ``jv``, ``jw`` (links with surfaces, link
        frame, (m, 3, 7) each). Samples whose constrained error cannot beat their
        link's best feasible one keep their free (lower-bound) error."""
        a, c = jv @ r, jw @ r
        owner, starts = self._owner, self._starts
        a, c = a[owner].T, c[owner].T                               # (3, n)
        px, py, pz = self._columns
        bx = a[0] + c[1] * pz - c[2] * py
        by = a[1] + c[2] * px - c[0] * pz
        bz = a[2] + c[0] * py - c[1] * px
        coeffs = _gram_coefficients(jv, jw)                         # (m, 10, 6)
        g = np.empty((6, len(owner)))
        for i in range(len(jv)):
            s = slice(starts[i], starts[i + 1])
            g[:, s] = np.einsum("me,mn->en", coeffs[i], self._monomials[:, s])
        ridge = RIDGE * (g[0] + g[1] + g[2])
        g00, g11, g22, g01, g02, g12 = g[0] + ridge, g[1] + ridge, g[2] + ridge, g[3], g[4], g[5]
        c00, c11, c22 = g11 * g22 - g12 * g12, g00 * g22 - g02 * g02, g00 * g11 - g01 * g01
        c01, c02, c12 = g02 * g12 - g01 * g22, g01 * g12 - g02 * g11, g01 * g02 - g00 * g12
        inv_det = 1.0 / (g00 * c00 + g01 * c01 + g02 * c02)
        fx = (c00 * bx + c01 * by + c02 * bz) * inv_det
        fy = (c01 * bx + c11 * by + c12 * bz) * inv_det
        fz = (c02 * bx + c12 * by + c22 * bz) * inv_det
        gain = bx * fx + by * fy + bz * fz
        nx, ny, nz = self._normal_columns
        inward = -(nx * fx + ny * fy + nz * fz)
        feasible = (inward > 0) & (inward * inward >= self._cone_cos2
                                   * (fx * fx + fy * fy + fz * fz))
        # the best feasible gain per link bounds which infeasible samples can still win
        bound = np.maximum.reduceat(np.where(feasible, gain, -np.inf), starts[:-1])
        outside = np.flatnonzero(~feasible & (gain > bound[owner]))
        if len(outside):
            dx, dy, dz = self._rays[:, outside]
            bd = dx * bx[outside, None] + dy * by[outside, None] + dz * bz[outside, None]
            prods, go = self._ray_products[:, outside], g[:, outside, None]
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
        rest = np.flatnonzero(~feasible)
        rest = rest[gain[rest] > bound[owner[rest]]] if len(outside) == 0 else \
            np.setdiff1d(rest, outside, assume_unique=True)
        gain[rest] = np.minimum(gain[rest], bound[owner[rest]])
        return np.sqrt(np.maximum(rr - gain, 0.0)), fx, fy, fz

    def _refine(self, jv: np.ndarray, jw: np.ndarray, r: np.ndarray, rr: float,
                err: np.ndarray, force: np.ndarray, errors: np.ndarray
                ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Refine the best links' points (see the module docstring, step 3); update
        ``errors`` [Nm] in place and return link index -> (point [m], force [N]) in the
        link frame, for every link with a surface within reach of the best."""
        tie = self.config.tie_nm
        reach = [int(k) for k in np.argsort(errors)[:REFINE_LINKS]
                 if np.isfinite(errors[k]) and self.samples[k] is not None]
        if not reach:
            return {}
        owner, idx = [], []
        for k in reach:
            i = int(np.searchsorted(self._links, k))
            s0, s1 = self._starts[i], self._starts[i + 1]
            order = s0 + np.argsort(err[s0:s1])[:REFINE_STARTS]
            close = s0 + np.flatnonzero(err[s0:s1] <= errors[k] + tie)
            offset = self._points[close] - self._points[close].mean(axis=0)
            centre = close[int(np.argmin(np.einsum("ni,ni->n", offset, offset)))]
            idx += [centre, *order.tolist()]
            owner += [k] * (len(order) + 1)
        idx, owner = np.array(idx), np.array(owner)
        p0, f = self._points[idx], force[idx]
        u, v, normals = self._tangents[0][idx], self._tangents[1][idx], self._normals[idx]
        jvr, jwr = jv[owner].transpose(0, 2, 1), jw[owner].transpose(0, 2, 1)  # (m, 7, 3)
        limit = self.config.spacing_m
        shift = np.zeros((len(idx), 2))
        for _ in range(REFINE_STEPS):
            p = p0 + shift[:, :1] * u + shift[:, 1:] * v
            free = r - (jvr @ f[..., None])[..., 0] - (jwr @ _cross(p, f)[..., None])[..., 0]
            jac = np.concatenate([jvr + jwr @ _skew(p), jwr @ np.stack(
                [_cross(u, f), _cross(v, f)], axis=2)], axis=2)
            normal = jac.transpose(0, 2, 1) @ jac
            normal += (DAMPING * (1.0 + np.trace(normal, axis1=1, axis2=2)))[:, None, None] \
                * np.eye(5)
            step = np.linalg.solve(normal, jac.transpose(0, 2, 1) @ free[..., None])[..., 0]
            f = _into_cone(f + step[:, :3], normals, self._cone_tan)
            shift = np.clip(shift + step[:, 3:], -limit, limit)
        p = p0 + shift[:, :1] * u + shift[:, 1:] * v
        free = r - (jvr @ f[..., None])[..., 0] - (jwr @ _cross(p, f)[..., None])[..., 0]
        refined = np.sqrt(np.einsum("mj,mj->m", free, free))
        refined = np.where(refined < err[idx], refined, err[idx])
        p, f = np.where(refined[:, None] < err[idx, None], p, p0), \
            np.where(refined[:, None] < err[idx, None], f, force[idx])
        fits = {}
        for k in reach:
            rows = np.flatnonzero(owner == k)
            errors[k] = float(refined[rows].min())
            # with fewer than 5 loaded joints the point is undetermined: keep the middle
            pick = rows[0] if k + 1 < MIN_DETERMINED else rows[int(np.argmin(refined[rows]))]
            fits[k] = (p[pick].copy(), f[pick].copy())
        return fits


_UNIT_SKEW = np.array([[[0, 0, 0], [0, 0, -1], [0, 1, 0]],
                       [[0, 0, 1], [0, 0, 0], [-1, 0, 0]],
                       [[0, -1, 0], [1, 0, 0], [0, 0, 0]]], dtype=float)
"""S(e_i) for the unit vectors: S(p) = sum_i p_i S(e_i), S(p) F = p x F."""
_PAIRS = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
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
    quad = np.einsum("iba,mbc,jcd->mijad", _UNIT_SKEW, ww, _UNIT_SKEW)  # S_i^T W S_j
    coeffs = np.stack([pp, lin[:, 0], lin[:, 1], lin[:, 2], quad[:, 0, 0], quad[:, 1, 1],
                       quad[:, 2, 2], quad[:, 0, 1] + quad[:, 1, 0],
                       quad[:, 0, 2] + quad[:, 2, 0], quad[:, 1, 2] + quad[:, 2, 1]], axis=1)
    return coeffs[:, :, _ROWS, _COLS]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the row-wise cross products of (m, 3) arrays (np.cross without its
    overhead)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _into_cone(f: np.ndarray, normals: np.ndarray, tan: float) -> np.ndarray:
    """Return the forces (m, 3) projected onto their friction cones: around the inward
    normal (-``normals``), tangential part at most ``tan`` times the inward part."""
    inward = -np.einsum("mi,mi->m", f, normals)
    tangential = f + inward[:, None] * normals
    size = np.sqrt(np.einsum("mi,mi->m", tangential, tangential))
    boundary = (inward + tan * size) / (1.0 + tan * tan)
    scale = np.where(size > tan * inward, tan * boundary / np.maximum(size, 1e-300), 1.0)
    along = np.where(size > tan * inward, boundary, inward)
    out = -along[:, None] * normals + scale[:, None] * tangential
    return np.where((tan * size <= -inward)[:, None], 0.0, out)


def _skew(p: np.ndarray) -> np.ndarray:
    """Return the (m, 3, 3) cross-product matrices S(p) of points (m, 3)."""
    return np.einsum("ijk,mi->mjk", _UNIT_SKEW, p)


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
