"""Timeseries features (thesis Table 3.3 and section B.1.1), batch and streaming.

Every feature is computed per sample, from samples up to and including that one
(causal), so the batch path (whole session, vectorised) and the streaming path
(one sample at a time, as on a live robot) give the same numbers.

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
=========  ======================  ========  =====================================

The wrench solves J^T w = r in the damped least-squares sense,
w = (J J^T + lambda^2 I)^-1 J r with lambda = 0.01, J the 6x7 Jacobian of the end
effector (hand TCP, or flange without hand) or of a chosen link, world-aligned.
Damping keeps it finite at singular poses; away from them it changes w by well
under 1 %.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from contactkit.errors import InputError
from contactkit.features.names import ALL_TIMESERIES, GROUPS
from contactkit.features.names import MODEL as MODEL  # re-exported: chain_cache's names
from contactkit.features.names import SENSOR as SENSOR
from contactkit.features.names import WORKSPACE as WORKSPACE
from contactkit.features.observer import (
    ObserverConfig,
    RecurrenceStep,
    observer_coefficients,
    solve_recurrence,
)
from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.schemas.session import SessionMeta

UNITS = {"q": "rad", "dq": "rad/s", "tau": "Nm", "ddq": "rad/s^2", "p_int": "W", "r": "Nm",
         "g": "Nm", "tau_inv": "Nm", "p_ext": "W", "f": "N", "m": "Nm", "fm_norm": "N, Nm"}
DAMPING = 0.01


def columns_of(name: str) -> list[str]:
    """Return the per-sample column names of a timeseries feature."""
    if name == "f":
        return ["f_x", "f_y", "f_z"]
    if name == "m":
        return ["m_x", "m_y", "m_z"]
    if name == "fm_norm":
        return ["f_norm", "m_norm"]
    if name not in ALL_TIMESERIES:
        raise KeyError(name)
    return [f"{name}_{i}" for i in range(1, 8)]


def expand(names: tuple[str, ...] | list[str]) -> list[str]:
    """Expand group names (sensor, model, workspace) into feature names, keeping order."""
    out: list[str] = []
    for name in names:
        for item in GROUPS.get(name, (name,)):
            if item not in ALL_TIMESERIES:
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
    named, or a comparison of models)."""

    observer: ObserverConfig = field(default_factory=ObserverConfig)
    wrench_frame: str | int = "ee"
    robot: str | None = None

    def robot_setup(self, meta: SessionMeta, path: str | Path | None = None) -> RobotSetup:
        """Return the arm the chain models for a session with metadata ``meta``: the
        session's own, or :attr:`robot` in its place. Raises InputError naming ``path``
        for an unknown robot or a URDF that is not the session's."""
        try:
            return meta.with_robot(self.robot).robot_setup(path)
        except InputError as err:
            raise InputError(err.problem, path or err.path) from err

    def model(self, robot: RobotSetup) -> RobotModel:
        """Return the dynamics model the chain uses for ``robot``."""
        return RobotModel(robot)


def _frame_id(model: RobotModel, wrench_frame: str | int) -> int:
    return model.frame_id(model.end_effector if wrench_frame == "ee" else wrench_frame)


def backward_difference(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Return dx/dt by backward differences on the actual steps (0 at the first sample)."""
    out = np.zeros_like(x)
    out[1:] = np.diff(x, axis=0) / np.diff(t)[:, None]
    return out


@dataclass(frozen=True)
class ChainState:
    """What the chain carries from one chunk of a stream to the next: the last sample's
    time ``t`` [s], velocity ``dq`` [rad/s] (for ddq), momentum ``p`` [Nm s] and
    residual ``r`` [Nm] (for the observer; None when the chain computed no residual)."""

    t: float
    dq: np.ndarray
    p: np.ndarray | None = None
    r: np.ndarray | None = None


class TimeseriesChain:
    """Batch chain: all samples of a session at once, or of one chunk of it after the
    :class:`ChainState` of the chunk before (see :class:`ChunkedChain`)."""

    def __init__(self, config: ChainConfig | None = None,
                 robot: RobotSetup | None = None) -> None:
        self.config = config or ChainConfig()
        self.model = self.config.model(robot or RobotSetup())
        self._pool = pin.ModelPool(self.model.model, 1)
        self._gain = self.config.observer.gain_vector()
        self._friction = self.config.observer.friction_model(self.model.spec)

    @classmethod
    def for_session(cls, meta: SessionMeta, config: ChainConfig | None = None,
                    path: str | Path | None = None) -> TimeseriesChain:
        """Return the chain for a session with metadata ``meta`` (its arm, or the one
        ``config.robot`` names; InputError naming ``path`` for an unknown robot)."""
        config = config or ChainConfig()
        return cls(config, config.robot_setup(meta, path))

    def _rnea(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        out = np.zeros_like(q, order="F")
        pin.rneaInParallel(1, self._pool, q, v, a, out)
        return out.T

    def compute(self, t: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray,
                names: list[str] | tuple[str, ...] = ALL_TIMESERIES) -> dict[str, np.ndarray]:
        """Return the requested timeseries features for one session.

        ``t`` (N,) [s]; ``q``, ``dq``, ``tau`` (N, 7). Returns name -> (N, k) array.
        """
        return self.compute_chunk(t, q, dq, tau, names)[0]

    def compute_chunk(self, t: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray,
                      names: list[str] | tuple[str, ...] = ALL_TIMESERIES,
                      before: ChainState | None = None
                      ) -> tuple[dict[str, np.ndarray], ChainState]:
        """Return the requested features of samples that follow ``before`` (the state
        after the previous chunk; None: these are the first samples), and the state
        after them. Arrays as for :meth:`compute`; ``t`` must not be empty."""
        names = expand(names)
        model, data = self.model.model, self.model.data
        n = len(t)
        qf, dqf = np.asfortranarray(q.T), np.asfortranarray(dq.T)
        zeros = np.zeros_like(qf, order="F")
        out: dict[str, np.ndarray] = {"q": q, "dq": dq, "tau": tau}
        need_r = bool({"r", "p_ext", "f", "m", "fm_norm"} & set(names))
        need_wrench = bool({"f", "m", "fm_norm"} & set(names))
        g = self._rnea(qf, zeros, zeros) if need_r or "g" in names else None
        if "g" in names:
            out["g"] = g
        if "ddq" in names or "tau_inv" in names:
            out["ddq"] = _backward_difference_after(t, dq, before)
        if "tau_inv" in names:
            out["tau_inv"] = self._rnea(qf, dqf, np.asfortranarray(out["ddq"].T))
        if "p_int" in names:
            out["p_int"] = dq * tau
        p = r = None
        if need_r:
            p = self._rnea(qf, zeros, dqf) - g
            coriolis = np.empty((n, 7, 7))
            jac = np.empty((n, 6, 7)) if need_wrench else None
            fid = _frame_id(self.model, self.config.wrench_frame)
            for k in range(n):
                coriolis[k] = pin.computeCoriolisMatrix(model, data, q[k], dq[k])
                if need_wrench:
                    jac[k] = pin.computeFrameJacobian(model, data, q[k], fid,
                                                      pin.LOCAL_WORLD_ALIGNED)
            u = tau + np.einsum("kji,kj->ki", coriolis, dq) - g
            if self._friction is not None:
                u -= self._friction.torque(dq)
            if before is None:
                r = solve_recurrence(*observer_coefficients(t, p, u, self._gain))
            else:
                a, b = observer_coefficients(np.r_[before.t, t], np.vstack([before.p, p]),
                                             np.vstack([u[:1], u]), self._gain)
                r = solve_recurrence(a[1:], b[1:], before.r)
            out["r"] = r
            out["p_ext"] = r * dq
            if need_wrench:
                gram = jac @ jac.transpose(0, 2, 1) + DAMPING**2 * np.eye(6)
                wrench = np.linalg.solve(gram, np.einsum("kij,kj->ki", jac, r)[..., None])[..., 0]
                out.update(_wrench_features(wrench))
        after = ChainState(float(t[-1]), dq[-1].copy(), None if p is None else p[-1].copy(),
                           None if r is None else r[-1].copy())
        return {name: out[name] for name in names}, after


def _backward_difference_after(t: np.ndarray, dq: np.ndarray, before: ChainState | None
                               ) -> np.ndarray:
    if before is None:
        return backward_difference(t, dq)
    return backward_difference(np.r_[before.t, t], np.vstack([before.dq, dq]))[1:]


class ChunkedChain:
    """The batch chain over consecutive chunks of one stream (row groups of a long
    session), its state carried from chunk to chunk: the features of the chunks,
    concatenated, equal :class:`TimeseriesChain` on the whole stream (to about 1e-12;
    the observer's closed form splits at other places), with memory bounded by one
    chunk."""

    def __init__(self, config: ChainConfig | None = None, robot: RobotSetup | None = None,
                 names: list[str] | tuple[str, ...] = ALL_TIMESERIES) -> None:
        self.chain = TimeseriesChain(config, robot)
        self.names = expand(names)
        self.model = self.chain.model
        self._state: ChainState | None = None

    def compute(self, t: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray
                ) -> dict[str, np.ndarray]:
        """Return the features (name -> (n, k) array) of the next chunk: ``t`` (n,) [s]
        after the previous chunk's, ``q``, ``dq``, ``tau`` (n, 7). An empty chunk gives
        empty arrays."""
        if len(t) == 0:
            return {name: np.zeros((0, len(columns_of(name)))) for name in self.names}
        out, self._state = self.chain.compute_chunk(t, q, dq, tau, self.names, self._state)
        return out


def _wrench_features(wrench: np.ndarray) -> dict[str, np.ndarray]:
    force, moment = wrench[..., :3], wrench[..., 3:]
    norms = np.stack([np.linalg.norm(force, axis=-1), np.linalg.norm(moment, axis=-1)], axis=-1)
    return {"f": force, "m": moment, "fm_norm": norms}


class OnlineChain:
    """Streaming chain: one sample at a time, the same numbers as :class:`TimeseriesChain`."""

    def __init__(self, config: ChainConfig | None = None,
                 robot: RobotSetup | None = None) -> None:
        self.config = config or ChainConfig()
        self.model = self.config.model(robot or RobotSetup())
        self._fid = _frame_id(self.model, self.config.wrench_frame)
        self._friction = self.config.observer.friction_model(self.model.spec)
        self._observer = RecurrenceStep(self.config.observer.gain_vector())
        self._zeros = np.zeros(7)
        self._last: tuple[float, np.ndarray] | None = None

    def reset(self) -> None:
        """Forget the past: the next sample starts a new session."""
        self._observer = RecurrenceStep(self.config.observer.gain_vector())
        self._last = None

    def update(self, t: float, q: np.ndarray, dq: np.ndarray, tau: np.ndarray
               ) -> dict[str, np.ndarray]:
        """Feed one sample (t [s], q [rad], dq [rad/s], tau [Nm], each (7,)); return every
        timeseries feature at this sample, name -> (k,) array."""
        model, data, z = self.model.model, self.model.data, self._zeros
        g = pin.rnea(model, data, q, z, z).copy()
        p = pin.rnea(model, data, q, z, dq) - g
        ddq = z.copy() if self._last is None else (dq - self._last[1]) / (t - self._last[0])
        self._last = (t, dq.copy())
        tau_inv = pin.rnea(model, data, q, dq, ddq).copy()
        ct_dq = pin.computeCoriolisMatrix(model, data, q, dq).T @ dq
        u = tau + ct_dq - g
        if self._friction is not None:
            u = u - self._friction.torque(dq)
        r = self._observer.update(t, p, u).copy()
        jac = pin.computeFrameJacobian(model, data, q, self._fid, pin.LOCAL_WORLD_ALIGNED)
        wrench = np.linalg.solve(jac @ jac.T + DAMPING**2 * np.eye(6), jac @ r)
        out = {"q": q, "dq": dq, "tau": tau, "ddq": ddq, "p_int": dq * tau, "r": r, "g": g,
               "tau_inv": tau_inv, "p_ext": r * dq}
        out.update(_wrench_features(wrench))
        return out
