"""Timeseries features (thesis Table 3.3 and section B.1.1), batch and streaming.

Every feature is computed per sample, from samples up to and including that one
(causal), so one engine, :class:`TimeseriesChain`, serves a whole session at once
(vectorised), a long session or a live source chunk by chunk, and a live robot one
sample at a time, with the same numbers (to about 1e-12).

=========  ======================  ========  =====================================
name       columns                 unit      definition
=========  ======================  ========  =====================================
**sensor-based**
q          q_1..q_7                rad       measured joint position
dq         dq_1..dq_7              rad/s     measured joint velocity
tau        tau_1..tau_7            Nm        measured joint torque (gravity incl.)
ddq        ddq_1..ddq_7            rad/s^2   backward difference of dq on the actual
                                             time steps (0 at the first sample)
p_int      p_int_1..p_int_7        W         internal power dq * tau
**model-based**
r          r_1..r_7                Nm        momentum-observer residual
                                             (:mod:`contactkit.features.observer`)
g          g_1..g_7                Nm        gravity torque g(q)
tau_inv    tau_inv_1..tau_inv_7    Nm        inverse dynamics M ddq + C dq + g with
                                             no external force
p_ext      p_ext_1..p_ext_7        W         external power r * dq (Table 3.3; the
                                             appendix's "residual times torque" is a
                                             typo: power is torque times velocity)
**workspace**
f          f_x f_y f_z             N         force of the wrench (J^T)^+ r at the
                                             wrench frame, world axes
m          m_x m_y m_z             Nm        moment of that wrench
fm_norm    f_norm m_norm           N, Nm     magnitudes of force and moment
**detector** (computed when named, not among the chain's default features)
tau_dyn    tau_dyn_1..tau_dyn_7    Nm        the model's dynamic torque scale
                                             |M(q) ddq_f + C(q, dq) dq| + T_g |dg/dt|
                                             per joint (below)
=========  ======================  ========  =====================================

``tau_dyn`` scales the residual's model error in motion for the contact detector
(:mod:`contactkit.features.detector`): a mass or inertia off by a fraction d gives an
error of about d (M ddq + C dq) on each joint, and a gravity torque off by d g(q)
changes with the pose faster than the detector's baseline follows it, leaving about
d T_g dg/dt with T_g = :data:`GRAVITY_LAG_S` (the baseline's time constant while the
arm moves). ddq_f is ddq low-passed with the observer's 20 ms time constant, as the
detector's acceleration measure (ddq_f_k = (ddq_f_{k-1} + K (dq_k - dq_{k-1})) /
(1 + K h_k), K = 50 1/s, 0 at a stream's first sample), M ddq_f + C dq is
rnea(q, dq, ddq_f) - g(q), and dg/dt = (dg/dq) dq exactly (pinocchio's gravity
derivatives).

The wrench solves J^T w = r in the damped least-squares sense,
w = (J J^T + lambda^2 I)^-1 J r with lambda = 0.01, J the 6x7 Jacobian of the end
effector (hand TCP, or flange without hand) or of a chosen link, world-aligned.
Damping keeps it finite at singular poses; away from them it changes w by well
under 1 %. A chunk longer than :data:`SHORT_CHUNK` takes its Jacobians from
:class:`contactkit.features.kinematics.FrameKinematics`, vectorised over the chunk,
where the arm's joints allow (those of the Panda and the FR3 do); pinocchio's, sample
by sample, agree with them to rounding, and the wrenches to about 1e-13 relative (up
to about 1e-12 for a link frame that only a few joints move, whose Jacobian's
missing directions the damping fills).

After a gap, a step longer than :data:`contactkit.features.timing.RESTART_STEP_S`
(0.1 s), the chain restarts as at the start of a session: the observer's momentum
estimate is set to the measured momentum again (r = 0 at the first sample after the
gap) and ddq is 0 there. The rule needs only the step itself, so a session at once,
chunk by chunk and sample by sample restart at the same samples.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pinocchio as pin

from contactkit.errors import InputError, input_error_about
from contactkit.features.kinematics import FrameKinematics
from contactkit.features.names import ALL_TIMESERIES, GROUPS, KNOWN
from contactkit.features.names import MODEL as MODEL  # re-exported: chain_cache's names
from contactkit.features.names import SENSOR as SENSOR
from contactkit.features.names import WORKSPACE as WORKSPACE
from contactkit.features.observer import (
    DDQ_FILTER_GAIN,
    ObserverConfig,
    filtered_rate,
    observer_coefficients,
    solve_recurrence,
)
from contactkit.features.timing import RESTART_STEP_S, restarts
from contactkit.robots import FrictionModel, RobotSetup
from contactkit.robots.dynamics import ArmDynamics, ArmOverride, with_dynamics
from contactkit.robots.model import RobotModel
from contactkit.schemas.metadata import SessionMeta
from contactkit.schemas.session import SampleBatch

UNITS = {"q": "rad", "dq": "rad/s", "tau": "Nm", "ddq": "rad/s^2", "p_int": "W", "r": "Nm",
         "g": "Nm", "tau_inv": "Nm", "p_ext": "W", "f": "N", "m": "Nm", "fm_norm": "N, Nm",
         "tau_dyn": "Nm"}
GRAVITY_LAG_S = 0.5
"""s: the lag that turns the rate of a gravity error into a residual error in
``tau_dyn``: the detector's baseline time constant while the arm moves."""
DAMPING = 0.01
_DAMPED = DAMPING**2 * np.eye(6)
_WRENCH = frozenset(("f", "m", "fm_norm"))
_RESIDUAL = frozenset(("r", "p_ext"))
_ZEROS = np.zeros(7)
_ZEROS.flags.writeable = False
SHORT_CHUNK = 16
"""Chunks of at most this many samples (a live stream's) run pinocchio's inverse
dynamics sample by sample: its batch call costs more to set up than it saves."""


def columns_of(name: str) -> list[str]:
    """Return the per-sample column names of a timeseries feature."""
    if name == "f":
        return ["f_x", "f_y", "f_z"]
    if name == "m":
        return ["m_x", "m_y", "m_z"]
    if name == "fm_norm":
        return ["f_norm", "m_norm"]
    if name not in KNOWN:
        raise KeyError(name)
    return [f"{name}_{i}" for i in range(1, 8)]


def expand(names: tuple[str, ...] | list[str]) -> list[str]:
    """Expand group names (sensor, model, workspace) into feature names, keeping order."""
    out: list[str] = []
    for name in names:
        for item in GROUPS.get(name, (name,)):
            if item not in KNOWN:
                raise KeyError(item)
            if item not in out:
                out.append(item)
    return out


@dataclass(frozen=True)
class ChainConfig:
    """Feature-chain settings: the observer and the wrench frame ("ee" for the end
    effector, or a link 1..7). Which arm, and whether it carries its hand, comes from
    each session's metadata (:meth:`SessionMeta.robot_setup`), unless ``robot`` names
    the model to use instead (``--robot``: a session recorded before its arm was
    named, or a comparison of models), and ``dynamics`` the arm's identified dynamics
    (``--dynamics``, :mod:`contactkit.robots.dynamics`). An
    :class:`~contactkit.robots.dynamics.ArmOverride` given as ``robot`` sets both."""

    observer: ObserverConfig = field(default_factory=ObserverConfig)
    wrench_frame: str | int = "ee"
    robot: str | ArmOverride | None = None
    dynamics: ArmDynamics | None = None

    def __post_init__(self) -> None:
        if isinstance(self.robot, ArmOverride):  # --robot and --dynamics as one value
            object.__setattr__(self, "dynamics", self.robot.dynamics or self.dynamics)
            object.__setattr__(self, "robot", self.robot.robot)

    def robot_setup(self, meta: SessionMeta, path: str | Path | None = None) -> RobotSetup:
        """Return the arm the chain models for a session with metadata ``meta``: the
        session's own, or :attr:`robot` in its place, with the identified
        :attr:`dynamics` (``--dynamics``) when given. Raises InputError naming ``path``
        for an unknown robot, a URDF that is not the session's, or dynamics of another
        arm."""
        try:
            assert not isinstance(self.robot, ArmOverride)  # unpacked in __post_init__
            setup = meta.with_robot(self.robot).robot_setup(path)
            return setup if self.dynamics is None else with_dynamics(setup, self.dynamics)
        except InputError as err:
            raise input_error_about(err, path) from err

    def model(self, robot: RobotSetup) -> RobotModel:
        """Return the dynamics model the chain uses for ``robot``."""
        return RobotModel(robot)


@dataclass(frozen=True)
class _Needs:
    """What a chain computes for the features it returns (expanded names)."""

    g: bool
    ddq: bool
    tau_inv: bool
    p_int: bool
    r: bool
    p_ext: bool
    wrench: bool
    tau_dyn: bool

    @classmethod
    def of(cls, names: list[str]) -> _Needs:
        """Return what the features ``names`` need."""
        wrench = not _WRENCH.isdisjoint(names)
        r = wrench or not _RESIDUAL.isdisjoint(names)
        tau_dyn = "tau_dyn" in names
        return cls(g=r or tau_dyn or "g" in names, ddq="ddq" in names or "tau_inv" in names,
                   tau_inv="tau_inv" in names, p_int="p_int" in names, r=r,
                   p_ext="p_ext" in names, wrench=wrench, tau_dyn=tau_dyn)


def _frame_id(model: RobotModel, wrench_frame: str | int) -> int:
    return model.frame_id(model.end_effector if wrench_frame == "ee" else wrench_frame)


def _without_gravity(model: pin.Model) -> pin.Model:
    """Return a copy of ``model`` without gravity: its rnea(q, 0, dq) is M(q) dq."""
    inertial = pin.Model(model)
    inertial.gravity = pin.Motion.Zero()
    return inertial


def _joint_constants(gain: np.ndarray, friction: FrictionModel | None
                     ) -> list[tuple[float, float, float, float, float, float]]:
    """Return per joint the observer gain K_O [1/s] and the friction coefficients
    (a, b, c, d, e) of :attr:`FrictionModel.sample_coefficients` (all 0 without friction
    compensation: then a tanh(b (dq + c)) + d + e dq is exactly 0), as floats for the
    per-sample observer step."""
    zeros = [[0.0] * 7] * 5
    return list(zip(gain.tolist(), *(zeros if friction is None
                                     else friction.sample_coefficients), strict=True))


class ChainState(NamedTuple):
    """What the chain carries from one chunk of a stream to the next: the last sample's
    time ``t`` [s], velocity ``dq`` [rad/s] (for ddq), momentum ``p`` [Nm s] and
    residual ``r`` [Nm] (for the observer; None when the chain computed no residual),
    low-passed acceleration ``ddq_f`` [rad/s^2] (for ``tau_dyn``; None when not
    computed), each (7,): an array after a chunk, seven Python floats after a live sample (the
    per-sample step's own numbers, kept without a copy into an array). A named tuple:
    immutable, and built on every live sample at a third of a frozen dataclass's
    cost."""

    t: float
    dq: np.ndarray | list[float]
    p: np.ndarray | list[float] | None = None
    r: np.ndarray | list[float] | None = None
    ddq_f: np.ndarray | list[float] | None = None


class TimeseriesChain:
    """The feature chain: one engine, chunked, with its state carried along a stream.

    :meth:`feed` takes the next chunk of a stream (any size: a session's row group, a
    source's chunk, or one sample) after the :class:`ChainState` of the chunk before,
    so the features of the chunks, concatenated, equal those of the whole stream at
    once (to about 1e-12; the observer's closed form splits at other places), with
    memory bounded by one chunk. :meth:`update` is the per-sample form (a chunk of one
    sample), :meth:`compute` a whole session at once, from a fresh state. ``names``
    are the features :meth:`feed` and :meth:`update` return (groups allowed)."""

    def __init__(self, config: ChainConfig | None = None, robot: RobotSetup | None = None,
                 names: list[str] | tuple[str, ...] = ALL_TIMESERIES) -> None:
        self.config = config or ChainConfig()
        self.model = self.config.model(robot or RobotSetup())
        self.names = expand(names)
        self._pool = pin.ModelPool(self.model.model, 1)
        self._inertial = _without_gravity(self.model.model)  # rnea(q, 0, dq) = M dq
        self._inertial_data = self._inertial.createData()
        self._inertial_pool = pin.ModelPool(self._inertial, 1)
        self._gain = self.config.observer.gain_vector()
        self._need = _Needs.of(self.names)
        self._friction = self.config.observer.friction_model(self.model)
        self._joint_constants = _joint_constants(self._gain, self._friction)
        self._fid = _frame_id(self.model, self.config.wrench_frame)
        self._kinematics = FrameKinematics.of(self.model.model, self._fid)
        self._state: ChainState | None = None

    @classmethod
    def for_session(cls, meta: SessionMeta, config: ChainConfig | None = None,
                    path: str | Path | None = None,
                    names: list[str] | tuple[str, ...] = ALL_TIMESERIES) -> TimeseriesChain:
        """Return the chain for a session with metadata ``meta`` (its arm, or the one
        ``config.robot`` names; InputError naming ``path`` for an unknown robot)."""
        config = config or ChainConfig()
        return cls(config, config.robot_setup(meta, path), names)

    def reset(self) -> None:
        """Forget the stream: the next chunk starts a new session."""
        self._state = None

    def compute(self, t: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray,
                names: list[str] | tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
        """Return the features ``names`` (default: the chain's) of one whole session,
        from a fresh state; the stream's state is left as it was.

        ``t`` (N,) [s], not empty; ``q`` [rad], ``dq`` [rad/s], ``tau`` [Nm] (N, 7).
        Returns name -> (N, k) array, units as in the table above.
        """
        return self._chunk(t, q, dq, tau, self.names if names is None else expand(names),
                           None)[0]

    def feed(self, batch: SampleBatch) -> dict[str, np.ndarray]:
        """Return the chain's features (name -> (n, k) array) of the next chunk of the
        stream, ``batch`` (its times after the previous chunk's; only ``t``, ``q``,
        ``dq`` and ``tau`` are used), and carry the state to the next chunk. An empty
        chunk gives empty arrays."""
        if len(batch) == 0:
            return {name: np.zeros((0, len(columns_of(name)))) for name in self.names}
        out, self._state = self._chunk(batch.t, batch.q, batch.dq, batch.tau, self.names,
                                       self._state)
        return out

    def update(self, t: float, q: np.ndarray, dq: np.ndarray, tau: np.ndarray
               ) -> dict[str, np.ndarray]:
        """Feed one sample (``t`` [s]; ``q`` [rad], ``dq`` [rad/s], ``tau`` [Nm], each
        (7,)); return the chain's features at it, name -> (k,). The same formulas as a
        chunk of one (to about 1e-15), on 7-vectors: a live robot's per-sample path, so
        what depends only on the names is decided once, at construction."""
        t = float(t)
        q = np.asarray(q, dtype=float).reshape(7)
        dq = np.asarray(dq, dtype=float).reshape(7)
        tau = np.asarray(tau, dtype=float).reshape(7)
        before = self._state
        if before is not None and t - before.t > RESTART_STEP_S:
            before = None  # a gap: the chain restarts here
        h = 0.0 if before is None else t - before.t
        model, data, need = self.model.model, self.model.data, self._need
        out: dict[str, Any] = {"q": q, "dq": dq, "tau": tau}  # g: None unless needed
        g = pin.computeGeneralizedGravity(model, data, q) if need.g else None
        out["g"] = g
        if need.ddq:
            out["ddq"] = np.zeros(7) if before is None else (dq - np.asarray(before.dq)) / h
        if need.tau_inv:
            out["tau_inv"] = pin.rnea(model, data, q, dq, out["ddq"])
        if need.p_int:
            out["p_int"] = dq * tau
        dq_floats = dq.tolist()
        ddq_f = None
        if need.tau_dyn:
            assert g is not None  # tau_dyn needs g (_Needs)
            ddq_f = (_ZEROS if before is None else
                     (np.asarray(before.ddq_f) + DDQ_FILTER_GAIN * (dq - np.asarray(before.dq)))
                     / (1.0 + DDQ_FILTER_GAIN * h))
            out["tau_dyn"] = (np.abs(pin.rnea(model, data, q, dq, ddq_f) - g) + GRAVITY_LAG_S
                              * np.abs(pin.computeGeneralizedGravityDerivatives(
                                  model, data, q) @ dq))
        p = r = None
        if need.r:
            p = pin.rnea(self._inertial, self._inertial_data, q, _ZEROS, dq).tolist()
            # C^T dq as dq C: computeCoriolisMatrix also leaves the joint placements
            # and Jacobians in data, which getFrameJacobian reads below
            coriolis = dq.dot(pin.computeCoriolisMatrix(model, data, q, dq))
            assert g is not None  # r needs g (_Needs)
            r = ([0.0] * 7 if before is None else
                 self._observer_step(h, before, p, tau, g, coriolis, dq_floats))
            out["r"] = r_array = np.array(r)
            if need.p_ext:
                out["p_ext"] = r_array * dq
            if need.wrench:
                jac = pin.getFrameJacobian(model, data, self._fid, pin.LOCAL_WORLD_ALIGNED)
                out.update(_wrench_features(np.linalg.solve(jac @ jac.T + _DAMPED,
                                                            jac @ r_array)))
        self._state = ChainState(t, dq_floats, p, r, ddq_f)
        return {name: out[name] for name in self.names}

    def _observer_step(self, h: float, before: ChainState, p: list[float], tau: np.ndarray,
                       g: np.ndarray, coriolis: np.ndarray, dq: list[float]) -> list[float]:
        """Return the observer's residual r [Nm] (7 floats) one step ``h`` [s] after
        ``before`` (its p and r 7 floats after a live sample, arrays after a chunk),
        from the momentum ``p`` [Nm s], torque ``tau``, gravity ``g`` and C^T dq
        ``coriolis`` [Nm], and velocity ``dq`` [rad/s] (friction's), each 7 values:
        r = (r_before + K_O (p - p_before - h u)) / (1 + K_O h), u = tau + C^T dq - g -
        tau_f (:mod:`contactkit.features.observer`; tau_f as
        :attr:`FrictionModel.sample_coefficients`, zero without compensation), on Python
        floats: one pass over seven joints costs less than the dozen array operations
        it replaces."""
        tanh = math.tanh
        assert before.p is not None and before.r is not None  # kept while r is computed
        return [(r0 + k * (p1 - p0 - h * (tq + c - gq
                                          - (fa * tanh(fb * (v + fc)) + fd + fe * v))))
                / (1.0 + k * h)
                for r0, p0, p1, tq, gq, c, v, (k, fa, fb, fc, fd, fe) in zip(
                    before.r, before.p, p, tau.tolist(), g.tolist(), coriolis.tolist(), dq,
                    self._joint_constants, strict=True)]

    def _rnea(self, q: np.ndarray, v: np.ndarray, a: np.ndarray, *, inertial: bool = False
              ) -> np.ndarray:
        """Return pinocchio's inverse dynamics tau(q, v, a) [Nm] of each sample, (n, 7),
        with gravity, or without it when ``inertial`` (then rnea(q, 0, dq) is the
        momentum M dq [Nm s]): a short chunk sample by sample, a longer one in one
        call."""
        if len(q) <= SHORT_CHUNK:
            model, data = ((self._inertial, self._inertial_data) if inertial
                           else (self.model.model, self.model.data))
            return np.array([pin.rnea(model, data, q[k], v[k], a[k]) for k in range(len(q))])
        out = np.zeros((7, len(q)), order="F")
        pin.rneaInParallel(1, self._inertial_pool if inertial else self._pool,
                           np.asfortranarray(q.T), np.asfortranarray(v.T),
                           np.asfortranarray(a.T), out)
        return out.T

    def _chunk(self, t: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray,
               names: list[str], before: ChainState | None
               ) -> tuple[dict[str, np.ndarray], ChainState]:
        """Return the features ``names`` (expanded) of samples that follow ``before``
        (None: these are the first samples), and the state after them."""
        model, data = self.model.model, self.model.data
        n = len(t)
        gaps = restarts(t, None if before is None else before.t)
        if gaps.size and gaps[0] == 0:  # a gap before the chunk: it starts a new stream
            before, gaps = None, gaps[1:]
        zeros = np.zeros_like(q)
        out: dict[str, Any] = {"q": q, "dq": dq, "tau": tau}  # g: None unless needed
        need = _Needs.of(names)
        g = self._rnea(q, zeros, zeros) if need.g else None
        out["g"] = g
        if need.ddq:
            ddq = out["ddq"] = np.zeros_like(dq)
            ddq[1:] = (dq[1:] - dq[:-1]) / (t[1:] - t[:-1])[:, None]
            if before is not None:
                ddq[0] = (dq[0] - before.dq) / (t[0] - before.t)
            ddq[gaps] = 0.0
        if need.tau_inv:
            out["tau_inv"] = self._rnea(q, dq, out["ddq"])
        if need.p_int:
            out["p_int"] = dq * tau
        ddq_f = None
        if need.tau_dyn:
            assert g is not None  # tau_dyn needs g (_Needs)
            ddq_f = self._ddq_filtered(t, dq, gaps, before)
            out["tau_dyn"] = self._dynamic_scale(q, dq, ddq_f, g)
        p = r = None
        if need.r:
            p = self._rnea(q, zeros, dq, inertial=True)
            coriolis = np.empty((n, 7, 7))
            # a long chunk's Jacobians come vectorised after the loop, where the arm allows
            per_sample = need.wrench and (n <= SHORT_CHUNK or self._kinematics is None)
            jac = np.empty((n, 6, 7)) if per_sample else None
            for k in range(n):
                coriolis[k] = pin.computeCoriolisMatrix(model, data, q[k], dq[k])
                if jac is not None:  # per sample: the Coriolis pass has placed every joint
                    # and its Jacobian
                    jac[k] = pin.getFrameJacobian(model, data, self._fid,
                                                  pin.LOCAL_WORLD_ALIGNED)
            u = tau + np.einsum("kji,kj->ki", coriolis, dq) - g
            if self._friction is not None:
                u -= self._friction.torque(dq)
            r = self._residual(t, p, u, gaps, before)
            out["r"] = r
            if need.p_ext:
                out["p_ext"] = r * dq
            if need.wrench:
                if jac is not None:
                    wrench = damped_wrench(jac, r)
                else:  # not per sample: the arm has its kinematics
                    assert self._kinematics is not None
                    wrench = _cholesky_wrench(self._kinematics.jacobian_rows(q), r)
                out.update(_wrench_features(wrench))
        after = ChainState(float(t[-1]), dq[-1].copy(), None if p is None else p[-1].copy(),
                           None if r is None else r[-1].copy(),
                           None if ddq_f is None else ddq_f[-1].copy())
        return {name: out[name] for name in names}, after

    def _ddq_filtered(self, t: np.ndarray, dq: np.ndarray, gaps: np.ndarray,
                      before: ChainState | None) -> np.ndarray:
        """Return ddq low-passed with :data:`DDQ_FILTER_GAIN` [rad/s^2] (n, 7) at samples
        with times ``t`` [s] and velocities ``dq`` [rad/s] that follow ``before`` (None:
        the first sample starts the stream, at 0), restarted (0) at the samples ``gaps``
        (> 0) that follow a gap."""
        out = np.zeros_like(dq)
        for start, stop in itertools.pairwise([0, *gaps.tolist(), len(t)]):
            carried = before if start == 0 else None
            lo = start if carried is not None else start + 1  # a fresh stream's first: 0
            if stop <= lo:
                continue
            if carried is None:
                t_prev, dq_prev, f_prev = t[lo - 1], dq[lo - 1], None
            else:
                t_prev, dq_prev, f_prev = carried.t, np.asarray(carried.dq), carried.ddq_f
            h = np.diff(t[lo - 1:stop] if lo > start else np.r_[t_prev, t[lo:stop]])[:, None]
            velocity = np.concatenate((np.asarray(dq_prev, dtype=float)[None], dq[lo:stop]))
            out[lo:stop] = filtered_rate(h, np.diff(velocity, axis=0), f_prev)
        return out

    def _dynamic_scale(self, q: np.ndarray, dq: np.ndarray, ddq_f: np.ndarray,
                       g: np.ndarray) -> np.ndarray:
        """Return ``tau_dyn`` [Nm] (n, 7): |M ddq_f + C dq| + T_g |(dg/dq) dq| of each
        sample (see the module docstring), from q [rad], dq [rad/s], the low-passed
        ddq_f [rad/s^2] and gravity g [Nm] (n, 7)."""
        model, data = self.model.model, self.model.data
        rate = np.array([pin.computeGeneralizedGravityDerivatives(model, data, q[k]) @ dq[k]
                         for k in range(len(q))]).reshape(len(q), 7)
        return np.abs(self._rnea(q, dq, ddq_f) - g) + GRAVITY_LAG_S * np.abs(rate)

    def _residual(self, t: np.ndarray, p: np.ndarray, u: np.ndarray, gaps: np.ndarray,
                  before: ChainState | None) -> np.ndarray:
        """Return the observer residual r [Nm] (n, 7) of samples with times ``t`` [s],
        momenta ``p`` [Nm s] and ``u`` [Nm] (n, 7) that follow ``before``, restarted (r =
        0) at the samples ``gaps`` (> 0) that follow a gap."""
        if not gaps.size:
            start = None
            if before is not None:
                assert before.p is not None  # kept while r is computed
                start = (before.t, before.p)
            return solve_recurrence(*observer_coefficients(t, p, u, self._gain, start),
                                    None if before is None else before.r)
        r = np.empty_like(p)
        for start, stop in itertools.pairwise([0, *gaps.tolist(), len(t)]):
            piece = slice(start, stop)
            r[piece] = self._residual(t[piece], p[piece], u[piece], gaps[:0],
                                      before if start == 0 else None)
        return r


def damped_wrench(jac: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Return the damped least-squares wrench w = (J J^T + lambda^2 I)^-1 J r [N, Nm]
    (n, 6) of each sample, from Jacobians ``jac`` (n, 6, 7) and residuals ``r`` [Nm]
    (n, 7).

    numpy's batched solvers pay about a microsecond per 6x6 system, so a long chunk
    solves by a Cholesky factorisation written out over the 6x6 entries, each a
    vector of n samples; a short one (a live stream's) calls ``np.linalg.solve``. The
    two agree to about 1e-12 relative (the matrix is symmetric positive definite, its
    condition bounded by the damping)."""
    if len(jac) <= SHORT_CHUNK:
        gram = jac @ jac.transpose(0, 2, 1) + _DAMPED
        return np.linalg.solve(gram, np.einsum("kij,kj->ki", jac, r)[..., None])[..., 0]
    return _cholesky_wrench(np.ascontiguousarray(jac.transpose(1, 2, 0)), r)


def _cholesky_wrench(rows: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Return the damped wrench of :func:`damped_wrench` [N, Nm] (n, 6) from the
    Jacobians' rows ``rows`` (6, 7, n) and residuals ``r`` [Nm] (n, 7), by the
    Cholesky factorisation written out over the 6x6 entries."""
    rhs = np.einsum("ijk,jk->ik", rows, np.ascontiguousarray(r.T))  # J r, (6, n)
    low: list[list[np.ndarray]] = [[] for _ in range(6)]  # Cholesky factor L, row by row
    for i in range(6):
        for j in range(i + 1):
            s = np.einsum("jk,jk->k", rows[i], rows[j])  # (J J^T)_ij
            if i == j:
                s += DAMPING**2
            for k in range(j):
                s -= low[i][k] * low[j][k]
            low[i].append(np.sqrt(s) if i == j else s / low[j][j])
    y: list[np.ndarray] = []  # L y = J r
    for i in range(6):
        s = rhs[i].copy()
        for k in range(i):
            s -= low[i][k] * y[k]
        y.append(s / low[i][i])
    w: list[np.ndarray] = [np.empty(0)] * 6  # L^T w = y
    for i in reversed(range(6)):
        s = y[i]
        for k in range(i + 1, 6):
            s = s - low[k][i] * w[k]
        w[i] = s / low[i][i]
    return np.stack(w, axis=1)


def _wrench_features(wrench: np.ndarray) -> dict[str, np.ndarray]:
    squares = (wrench * wrench).reshape(*wrench.shape[:-1], 2, 3)
    norms = np.sqrt(np.add.reduce(squares, axis=-1))  # as np.linalg.norm, without its checks
    return {"f": wrench[..., :3], "m": wrench[..., 3:], "fm_norm": norms}
