"""Simulated arm (a Panda by default, an FR3 with ``--robot fr3``): the default source
when no robot is attached.

Which arm is simulated comes from :mod:`contactkit.robots`: its URDF's inertias, its
joint, velocity and torque limits, and its friction. An FR3 simulation uses the FR3's
own inertias and limits, *no* joint friction (none is identified for the FR3, and on
the real FR3 recordings the link-side torque sensors show none that a model removes:
the residual matches the robot's own estimate without it), the same armature, and
the Panda's sensor-noise statistics: the only ones measured on a held pose, from
torque sensors of the same design.

Physics (thesis section 5.3.1, extended):

* Forward dynamics with pinocchio's articulated-body algorithm, integrated with
  semi-implicit Euler. The controller runs at the output rate times
  m = ceil(1000 Hz / rate), so at 1 kHz or faster as on the real robot (600 Hz
  output gives 1.2 kHz control, as in the thesis), and every m-th control tick is
  recorded. Its torque is held over ``substeps`` integration steps per tick
  (default 5: 5 kHz at 1 kHz output; the thesis used 1.2 kHz x 10).
* Control: gravity compensation with the *nominal* model plus joint PID, torque
  and torque-rate limits of the Franka datasheet enforced. The plant's joints 1-4
  carry the motors' reflected rotor inertia (armature, 0.1 kg m^2), and the torque
  sensors, between motors and links, measure the motor torque less what accelerates
  the rotors. A joint's integrator holds while its torque is saturated (anti-windup):
  without it, a hard shove that saturates the shoulder motors left the arm in a
  growing oscillation.
* The plant differs from the nominal model the observer uses, as a real robot's
  does: link masses, inertias and centres of mass are perturbed (a fixed "robot
  instance" chosen by ``robot_seed``, the same for every session of a dataset, as
  a lab records a dataset on one robot), and joint friction follows the identified
  model of Gaz et al. with amplitudes scaled per joint.
* An identified arm (``SimConfig.dynamics``, ``--dynamics FILE``, the format of
  ``recorder identify``) replaces that random instance: the file is the instance's
  truth. The plant's links carry the file's inertial parameters, its joints the file's
  friction and, beside the motors' armature, the file's (which the torque sensors see,
  unlike the motors'); ``robot_seed`` and the perturbation spreads then play no part
  (no perturbation around the file). The controller keeps the robot's nominal model,
  as a real arm's does, and the observer whatever model it is given.
* Those plant defaults (masses and inertias +-15 %, centres of mass +-1 cm,
  friction amplitudes +-40 %) were chosen so that the simulated robot shows
  free-motion observer residuals of the same size as the real robot: in the
  ``free-motion`` preset's motion, the residual's RMS while moving is 0.54-1.13 times
  the real Gaz log's per joint (``tests/recorder/test_sim_calibration.py`` holds it within
  +-50 %; with +-10 % joints 1-4 were at 0.48-0.55), and tracking the log's own
  trajectory within a factor of 3 (``tests/suites/test_features_real.py``). With the
  thesis-like +-5 % the simulated residuals were 2-2.5x too small on joints 1-4.
* Sensors: white noise on q, dq and tau at the levels measured on the real Panda
  recordings (:mod:`contactkit.recorder.sim.noise`; the velocity noise grows with speed, from
  its level on the real arm holding a pose), a per-session torque bias, optional
  time-stamp jitter and dropped samples.
* Contacts: :mod:`contactkit.recorder.sim.forces` (any link, any direction, person-dependent).
* Reflex stop: a joint driven past its velocity limit or out of its range (a strong
  shove on the wrist can do both) stops the arm as a real Franka's reflex does. The
  arm brakes every joint to rest at its acceleration limit and holds there, with the
  brakes taking whatever torque the person still applies (the torque sensors measure
  it); the commanded motion is abandoned (``q_d`` holds, ``dq_d`` is 0). The
  ``robot_mode`` column says 2 (move) before and 4 (reflex) from the stop on, as
  libfranka's does, and :attr:`ArmSimulator.reflexes` what triggered it.

Sessions are stepped in lockstep in batches, with ``pin.abaInParallel`` over the
batch, which amortises Python overhead (see ``benchmarks/bench_simulator.py``).
Each session draws its noise from its own random streams, so its data depend only
on its seed and the configuration, not on the batch it ran in.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from contactkit.features.limits import ROBOT_MODE_REFLEX
from contactkit.recorder.protocol import (
    check_action,
    check_condition,
    check_duration,
    default_timing,
    motion_duration_s,
    pose_q,
)
from contactkit.recorder.sim.forces import Contact, Persona, sample_contact
from contactkit.recorder.sim.motion import MotionPlan, free_motion_plan
from contactkit.recorder.sim.noise import SensorNoise, default_noise
from contactkit.robots import (
    N_JOINTS,
    FrictionModel,
    RobotSetup,
    canonical_robot_name,
    get_robot,
)
from contactkit.robots.dynamics import ArmDynamics, check_arm
from contactkit.robots.model import RobotModel
from contactkit.robots.surfaces import link_surface
from contactkit.schemas import InputError, joint_columns

KP = (600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0)  # Nm/rad
KD = (50.0, 50.0, 50.0, 40.0, 7.0, 6.0, 1.5)  # Nm s/rad, about critical damping
KI = (300.0, 300.0, 300.0, 300.0, 125.0, 75.0, 25.0)  # Nm/(rad s)
# The motors' rotor inertia reflected through the gears, on the plant side of the torque
# sensors [kg m^2]. Without it, joints 1 and 3 turning against each other at q2 = 0 (pose
# E) have 0.019 kg m^2 of inertia, too little for KD = 50 Nm s/rad at 1 kHz: the arm
# oscillated at the control's Nyquist frequency (0.45 Nm on joints 1 and 3, where the real
# Panda shows 0.09). The wrist joints are left without: their holding noise matched.
ARMATURE_KGM2 = (0.1, 0.1, 0.1, 0.1, 0.0, 0.0, 0.0)
ROBOT_MODE_MOVE = 2
"""libfranka's ``RobotMode::kMove``: a controller runs (the ``robot_mode`` column)."""


@dataclass(frozen=True)
class SimConfig:
    """Simulator settings shared by every session of a run.

    ``rate_hz`` output and control rate [Hz]; ``substeps`` integration steps per
    output sample; ``robot_seed`` selects the simulated robot instance (plant
    parameters); ``mass_perturbation`` relative spread of link masses/inertias;
    ``com_perturbation_m`` spread of centres of mass [m]; ``friction_spread``
    relative spread of friction amplitudes; ``armature_kgm2`` the motors' inertia
    reflected to each joint [kg m^2]; ``noise_scale`` multiplies the sensor noise;
    ``jitter_s`` uniform time-stamp jitter [s]; ``drop_prob`` probability of losing a
    sample; ``dynamics`` an identified arm to simulate instead of a random instance of
    the nominal one (its robot and hand must be this configuration's; None: the
    instance of ``robot_seed``).
    """

    rate_hz: float = 1000.0
    substeps: int = 5
    robot: str = "panda"
    with_hand: bool = True
    robot_seed: int = 0
    mass_perturbation: float = 0.15
    com_perturbation_m: float = 0.01
    friction_spread: float = 0.4
    noise_scale: float = 1.0
    jitter_s: float = 0.0
    drop_prob: float = 0.0
    operator_variability: float = 1.0
    armature_kgm2: tuple[float, ...] = ARMATURE_KGM2
    noise: SensorNoise = field(default_factory=default_noise)
    dynamics: ArmDynamics | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "robot", canonical_robot_name(self.robot))
        if self.dynamics is not None:
            check_arm(self.dynamics, self.setup, self.dynamics.source or None)
        if not 1.0 <= self.rate_hz <= 10_000.0:
            raise InputError(f"rate must be between 1 and 10000 Hz, got {self.rate_hz}")
        if self.substeps < 1:
            raise InputError(f"substeps must be at least 1, got {self.substeps}")
        if not 0.0 <= self.jitter_s < 0.5 / self.rate_hz:
            raise InputError(f"jitter must be in [0, half a sample period), got "
                             f"{self.jitter_s} s")
        if len(self.armature_kgm2) != N_JOINTS or not all(
                0.0 <= b <= 10.0 for b in self.armature_kgm2):
            raise InputError(f"armature needs {N_JOINTS} values in [0, 10] kg m^2, got "
                             f"{self.armature_kgm2}")
        if not 0.0 <= self.drop_prob < 1.0:
            raise InputError(f"drop probability must be in [0, 1), got {self.drop_prob}")

    def to_dict(self) -> dict:
        """Return the configuration as JSON-ready values (for session metadata, session
        ids and cache keys): with identified dynamics, their values that the plant
        uses (:func:`simulated_dynamics`); without, no ``dynamics`` entry at all, so a
        nominal configuration's document, and what is keyed by it, stay as they were."""
        doc = asdict(replace(self, dynamics=None))
        del doc["dynamics"]
        if self.dynamics is not None:
            doc["dynamics"] = simulated_dynamics(self.dynamics)
        return doc

    @property
    def setup(self) -> RobotSetup:
        """The simulated arm: robot and hand."""
        return RobotSetup(self.robot, self.with_hand)


def simulated_dynamics(dynamics: ArmDynamics) -> dict[str, Any]:
    """Return what of identified ``dynamics`` the simulated plant uses, as JSON-ready
    values: robot, hand, link parameters, armature, friction, and the file's checksum
    (which names the whole file, its provenance and detector too)."""
    doc = dynamics.to_dict()
    return {key: doc[key] for key in ("robot", "with_hand", "links", "armature_kgm2",
                                      "friction", "checksum")}


def load_simulated_arm(path: str | Path, setup: RobotSetup, robot_seed: int | None
                       ) -> ArmDynamics:
    """Return the identified dynamics in the file ``path`` for simulating the arm
    ``setup`` (``--dynamics`` of ``capture --source sim`` and ``simulate``): every check
    of ``--dynamics`` elsewhere (the file's, and its detector settings'), and the arm
    and hand. InputError (one line) for a file that fails one, or when ``robot_seed``
    (not None) also picks a random instance of the nominal arm."""
    if robot_seed is not None:
        raise InputError("--robot-seed picks a random instance of the nominal arm, "
                         "--dynamics simulates an identified one: give one of them")
    from contactkit.features.detector import dynamics_detector
    from contactkit.robots.dynamics import load_dynamics

    dynamics = load_dynamics(path, setup)
    dynamics_detector(dynamics)
    return dynamics


@dataclass(frozen=True)
class SessionSpec:
    """Everything that determines one simulated session (with the :class:`SimConfig`).

    Joint vectors in rad, speed in rad/s, times in s.
    """

    seed: int
    condition: str
    action: str
    pose: str
    q_start: tuple[float, ...]
    duration_s: float
    planned_at_s: float
    motion_start_s: float
    motion_duration_s: float
    operator: str = "sim"
    target_pose: str | None = None
    q_target: tuple[float, ...] | None = None
    speed_rad_s: float | None = None
    link: int | None = None
    contact: Contact | None = None
    motion: MotionPlan | None = None

    def as_dict(self) -> dict:
        """Return the spec as JSON-ready values."""
        doc = asdict(self)
        doc["contact"] = None if self.contact is None else self.contact.as_dict()
        doc["motion"] = None if self.motion is None else self.motion.as_dict()
        return doc


def control_ticks(rate_hz: float) -> int:
    """Return how many control ticks run per output sample (control at >= 1 kHz)."""
    return max(1, int(np.ceil(1000.0 / rate_hz - 1e-9)))


def n_samples(spec: SessionSpec, rate_hz: float) -> int:
    """Return the number of output samples of a session at ``rate_hz`` (t = 0 included)."""
    return round(spec.duration_s * rate_hz) + 1


def plan_session(*, seed: int, condition: str, action: str, pose: str,
                 target_pose: str | None = None, speed_rad_s: float | None = None,
                 link: int | None = None, planned_at_s: float | None = None,
                 duration_s: float | None = None, operator: str = "sim",
                 pose_jitter_rad: float = 0.0, robot: RobotSetup | None = None,
                 operator_variability: float = 1.0) -> SessionSpec:
    """Turn capture choices into a fully determined :class:`SessionSpec`.

    Random choices (pose jitter, contact link when ``link`` is None, contact point,
    direction, profile and onset delay) come from ``seed``. Raises InputError for an
    unknown pose/action/condition, a link outside 1..7, a non-positive duration or
    a planned time outside the session.
    """
    check_action(action)
    check_condition(condition)
    rng = np.random.default_rng(seed)
    robot = robot or RobotSetup()
    model = RobotModel(robot)
    lo, hi = model.limits.q_min + 0.02, model.limits.q_max - 0.02
    q_start = np.clip(pose_q(pose) + rng.normal(0.0, pose_jitter_rad, N_JOINTS), lo, hi)
    q_target = None
    motion_s = 0.0
    if condition == "dynamic":
        target_pose = target_pose or "D"
        if target_pose.upper() == pose.upper():
            raise InputError(f"target pose {target_pose} is the start pose")
        speed_rad_s = 0.2 if speed_rad_s is None else speed_rad_s
        q_target = np.clip(pose_q(target_pose) + rng.normal(0.0, pose_jitter_rad, N_JOINTS),
                           lo, hi)
        motion_s = motion_duration_s(q_start, q_target, speed_rad_s)
    elif target_pose is not None or speed_rad_s is not None:
        raise InputError("a target pose and a speed need the dynamic condition")
    timing = default_timing(condition, motion_s)
    duration = timing.duration_s if duration_s is None else duration_s
    check_duration(duration)
    planned = timing.planned_at_s if planned_at_s is None else planned_at_s
    if not 0.0 <= planned < duration:
        raise InputError(f"planned interaction time {planned} s is outside the session "
                         f"(0 to {duration} s)")
    if link is not None and not 1 <= link <= N_JOINTS:
        raise InputError(f"unknown link {link} (expected 1..{N_JOINTS})")
    contact = None
    if action != "none":
        link = int(rng.integers(1, N_JOINTS + 1)) if link is None else link
        rotation = model.frame_placement(q_start, link).rotation
        persona = Persona.from_name(operator, operator_variability)
        contact = sample_contact(rng, action, planned, link, link_surface(robot, link),
                                 rotation, persona)
    return SessionSpec(
        seed=seed, condition=condition, action=action, pose=pose.upper(),
        q_start=tuple(float(x) for x in q_start), duration_s=float(duration),
        planned_at_s=float(planned), motion_start_s=timing.motion_start_s,
        motion_duration_s=timing.motion_duration_s, operator=operator,
        target_pose=None if target_pose is None else target_pose.upper(),
        q_target=None if q_target is None else tuple(float(x) for x in q_target),
        speed_rad_s=speed_rad_s, link=link, contact=contact)


CONTACT_TIMING = ("moving", "after-stop", "any")


def plan_free_session(*, seed: int, action: str, pose: str, duration_s: float,
                      link: int | None = None, operator: str = "sim",
                      pose_jitter_rad: float = 0.0, robot: RobotSetup | None = None,
                      operator_variability: float = 1.0,
                      contact_timing: str = "any") -> SessionSpec:
    """Plan a free-motion session (:mod:`contactkit.recorder.sim.motion`) from pose ``pose``.

    The arm holds for 1 s, then moves freely (moves, multi-sine stretches, holds) for
    the rest of ``duration_s`` [s]. A contact (any action but none) is planned while
    the arm moves (``contact_timing`` "moving"), within 0.3 s after a move or sine
    stretch ends ("after-stop"), or either ("any"); its direction is drawn in the
    touched link's frame at the planned time. The condition is ``dynamic``; random
    choices come from ``seed``.
    """
    check_action(action)
    if contact_timing not in CONTACT_TIMING:
        raise InputError(f"unknown contact timing {contact_timing!r} (expected "
                         f"{', '.join(CONTACT_TIMING)})")
    check_duration(duration_s)
    if duration_s < 3.0:
        raise InputError(f"a free-motion session needs at least 3 s, got {duration_s} s")
    rng = np.random.default_rng(seed)
    robot = robot or RobotSetup()
    model = RobotModel(robot)
    lo, hi = model.limits.q_min + 0.02, model.limits.q_max - 0.02
    q_start = np.clip(pose_q(pose) + rng.normal(0.0, pose_jitter_rad, N_JOINTS), lo, hi)
    plan = free_motion_plan(rng, q_start, duration_s, model.limits)
    q_start = np.array(plan.segments[0].q_from)
    latest = duration_s - 1.5
    moving = [(a, min(b, latest)) for a, b in plan.moving_intervals() if a < latest]
    stops = [b for _, b in plan.moving_intervals() if b < latest]
    timing = contact_timing
    if timing == "any":
        timing = ("moving", "after-stop")[int(rng.integers(2))]
    if timing == "after-stop" and stops:
        planned = float(stops[int(rng.integers(len(stops)))] + rng.uniform(0.0, 0.3))
    elif moving:
        start, end = moving[int(rng.integers(len(moving)))]
        planned = float(rng.uniform(start, max(start, end - 0.2)))
    else:
        planned = float(rng.uniform(1.0, latest))
    contact = None
    if action != "none":
        link = int(rng.integers(1, N_JOINTS + 1)) if link is None else link
        q_at = plan.sample(np.array([planned]))[0][0]
        rotation = model.frame_placement(q_at, link).rotation
        persona = Persona.from_name(operator, operator_variability)
        contact = sample_contact(rng, action, planned, link, link_surface(robot, link),
                                 rotation, persona)
    return SessionSpec(
        seed=seed, condition="dynamic", action=action, pose=pose.upper(),
        q_start=tuple(float(x) for x in q_start), duration_s=float(duration_s),
        planned_at_s=planned, motion_start_s=plan.segments[0].duration_s,
        motion_duration_s=float(duration_s - plan.segments[0].duration_s),
        operator=operator, link=link, contact=contact, motion=plan)


class _Batch:
    """Per-session arrays of the sessions still running, stored column-wise (7, B)."""

    def __init__(self, **arrays: np.ndarray) -> None:
        self.arrays = arrays

    def keep(self, mask: np.ndarray) -> None:
        for name, value in self.arrays.items():
            self.arrays[name] = np.asfortranarray(value[..., mask])

    def __getattr__(self, name: str) -> np.ndarray:
        try:
            return self.__dict__["arrays"][name]
        except KeyError as err:
            raise AttributeError(name) from err


class ArmSimulator:
    """Simulates batches of sessions on one simulated robot instance."""

    def __init__(self, config: SimConfig) -> None:
        self.config = config
        self.nominal = RobotModel(config.setup)
        self.armature = np.array(config.armature_kgm2)[:, None]
        identified = config.dynamics
        self.friction: FrictionModel | None
        if identified is None:
            robot_rng = np.random.default_rng([config.robot_seed, 0xC0FFEE])
            self.plant = self.nominal.perturbed(robot_rng, config.mass_perturbation,
                                                config.com_perturbation_m)
            self.plant.model.armature[:] = config.armature_kgm2
            spread = config.friction_spread
            scale = robot_rng.uniform(1 - spread, 1 + spread, N_JOINTS)
            friction = get_robot(config.robot).friction
            self.friction = None if friction is None else friction.scaled(scale)
        else:
            # the identified arm is the instance: its links, friction and the armature
            # the sensors see, on top of the motors' (which they do not)
            self.plant = RobotModel(replace(config.setup, dynamics=identified))
            self.plant.model.armature[:] = (np.array(config.armature_kgm2)
                                            + np.array(identified.armature_kgm2))
            self.friction = identified.friction_model
        self.plant.data = self.plant.model.createData()
        self._plant_pool = pin.ModelPool(self.plant.model, 1)
        self._nominal_pool = pin.ModelPool(self.nominal.model, 1)
        noise = config.noise
        noise_scale = config.noise_scale
        self.sigma = np.concatenate([np.array(noise.q_sigma_rad), np.ones(N_JOINTS),
                                     np.array(noise.tau_sigma_nm)])[:, None] * noise_scale
        self.noise = noise
        self.noise_scale = noise_scale
        self.bias_scale = np.array(noise.tau_bias_nm) * noise_scale
        self.kp, self.kd, self.ki = (np.array(g)[:, None] for g in (KP, KD, KI))
        self.reflexes: dict[int, dict[str, float | int | str]] = {}
        """What stopped each session of the last :meth:`run` that met a reflex, by spec
        index: the time [s], the joint (1..7), the quantity (``dq`` [rad/s] or ``q``
        [rad]), its value and the limit it passed (the speed limit, or the end of the
        range)."""

    def true_dynamics(self, provenance: dict | None = None) -> ArmDynamics:
        """Return this robot instance's own parameters in the identification's format:
        the perturbed plant's link inertias and its scaled friction, with ``provenance``.
        The armature is 0: the torque sensors sit between the motors and the links, so
        the rotors' inertia is not in what they measure. The observer given these has
        the plant's true model (the floor an identification can reach). An identified
        arm's (``SimConfig.dynamics``) are its file's links, friction and armature."""
        friction = self.friction
        identified = self.config.dynamics
        terms = ((np.zeros(N_JOINTS), np.ones(N_JOINTS), np.zeros(N_JOINTS),
                  np.zeros(N_JOINTS), np.zeros(N_JOINTS)) if friction is None else
                 (friction.phi1, friction.phi2, friction.phi3, friction.viscous,
                  friction.offset))
        model = self.plant.model
        return ArmDynamics(
            robot=self.config.robot, with_hand=self.plant.with_hand,
            inertias=tuple(tuple(float(v) for v in model.inertias[j].toDynamicParameters())
                           for j in range(1, N_JOINTS + 1)),
            armature_kgm2=(0.0,) * N_JOINTS if identified is None else
            identified.armature_kgm2,
            friction=tuple(tuple(float(v) for v in values) for values in terms),
            provenance=json.dumps(dict(provenance or {}, simulator=self.config.to_dict()),
                                  sort_keys=True, default=str))

    def _gravity(self, pool: pin.ModelPool, q: np.ndarray) -> np.ndarray:
        zeros = np.zeros_like(q, order="F")
        out = np.zeros_like(q, order="F")
        pin.rneaInParallel(1, pool, q, zeros, zeros, out)
        return out

    def run(self, specs: list[SessionSpec], chunk: int = 100
            ) -> Iterator[tuple[int, dict[str, np.ndarray], bool]]:
        """Simulate ``specs`` together; yield ``(spec index, columns, finished)``.

        ``columns`` holds the next rows of that session in session-file columns
        (``t``, ``q_*``, ``dq_*``, ``tau_*``, ``q_d_*``, ``dq_d_*``, ``f_ext_*``,
        ``contact``, ``robot_mode``); ``finished`` is true on a session's last chunk.
        Rows come in chunks of ``chunk`` samples. :attr:`reflexes` says which sessions
        met a reflex stop.
        """
        cfg = self.config
        ticks = control_ticks(cfg.rate_hz)
        dt = 1.0 / (cfg.rate_hz * ticks)
        h = dt / cfg.substeps
        count = len(specs)
        q0 = np.asfortranarray(np.array([s.q_start for s in specs]).T)
        q1 = np.asfortranarray(np.array([s.q_target or s.q_start for s in specs]).T)
        t_move = np.array([s.motion_start_s for s in specs])
        t_len = np.array([max(s.motion_duration_s, 1e-9) for s in specs])
        lengths = np.array([n_samples(s, cfg.rate_hz) for s in specs])
        streams = [np.random.default_rng(s.seed).spawn(3) for s in specs]
        bias = np.asfortranarray(np.array([st[0].normal(0.0, self.bias_scale) for st in streams]).T)
        gap = self._gravity(self._plant_pool, q0) - self._gravity(self._nominal_pool, q0)
        batch = _Batch(
            index=np.arange(count), q=q0.copy(order="F"), dq=np.zeros_like(q0, order="F"),
            q0=q0, dq01=np.asfortranarray(q1 - q0), t_move=t_move, t_len=t_len,
            ei=np.asfortranarray(gap / self.ki), tau_prev=self._gravity(self._plant_pool, q0),
            bias=bias, length=lengths, reflex=np.zeros(count, dtype=bool),
            q_hold=np.zeros_like(q0, order="F"))
        self.reflexes = {}
        if any(s.motion is not None for s in specs):
            self._plan_references(batch, specs, int(lengths.max()) * ticks, dt)
        contacts = [s.contact for s in specs]
        k0 = 0
        while batch.index.size:
            steps = min(chunk, int(batch.length.max()) - k0)
            rows = self._advance(batch, contacts, streams, k0, steps, ticks, dt, h)
            finished = batch.length <= k0 + steps
            for col, spec_index in enumerate(batch.index):
                n_keep = min(steps, int(batch.length[col]) - k0)
                columns = {name: values[:n_keep, ..., col] for name, values in rows.items()}
                yield int(spec_index), self._finish_rows(columns, streams[spec_index][2],
                                                         k0), bool(finished[col])
            batch.keep(~finished)
            k0 += steps

    def _advance(self, batch: _Batch, contacts: list[Contact | None],
                 streams: list[list[np.random.Generator]], k0: int, steps: int, ticks: int,
                 dt: float, h: float) -> dict[str, np.ndarray]:
        width = batch.index.size
        noise = np.stack([streams[i][1].standard_normal((steps, ticks, 3 * N_JOINTS))
                          for i in batch.index], axis=-1) * self.sigma
        out = {name: np.empty((steps, N_JOINTS, width)) for name in ("q", "dq", "tau", "q_d",
                                                                       "dq_d")}
        out["f_ext"] = np.zeros((steps, 3, width))
        out["mode"] = np.empty((steps, width), dtype=np.int8)
        active = [(col, contacts[i]) for col, i in enumerate(batch.index)
                  if contacts[i] is not None]
        for j in range(steps):
            for tick in range(ticks):
                t = ((k0 + j) * ticks + tick) * dt
                record = {name: value[j] for name, value in out.items()} if tick == 0 else None
                self._tick(batch, active, noise[j, tick], t, dt, h, record)
        return out

    def _plan_references(self, batch: _Batch, specs: list[SessionSpec], ticks: int,
                         dt: float) -> None:
        """Tabulate every session's commanded trajectory on the control grid of step
        ``dt`` [s] (free-motion plans, and the protocol's for sessions without one)."""
        grid = np.arange(ticks) * dt
        ref_q, ref_dq = (np.array(a) for a in self._protocol_reference(batch, grid[:, None, None]))
        for col, spec in enumerate(specs):
            if spec.motion is not None:
                ref_q[:, :, col], ref_dq[:, :, col] = spec.motion.sample(grid)
        batch.arrays.update(ref_q=ref_q, ref_dq=ref_dq)

    def reference(self, batch: _Batch, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Return the commanded (q_d [rad], dq_d [rad/s]) at time ``t`` [s], each (7, B):
        the session's free-motion plan where it has one, else the protocol's: the start
        pose, then a quintic move to the target (zero velocity and acceleration at both
        ends), then the target."""
        if "ref_q" in batch.arrays:
            dt = 1.0 / (self.config.rate_hz * control_ticks(self.config.rate_hz))
            k = min(round(t / dt), batch.ref_q.shape[0] - 1)
            return batch.ref_q[k], batch.ref_dq[k]
        return self._protocol_reference(batch, t)

    def _protocol_reference(self, batch: _Batch, t: float | np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
        s = np.clip((t - batch.t_move) / batch.t_len, 0.0, 1.0)
        blend = s**3 * (10.0 + s * (-15.0 + 6.0 * s))
        rate = 30.0 * s**2 * (1.0 - s) ** 2 / batch.t_len
        return batch.q0 + batch.dq01 * blend, batch.dq01 * rate

    def feedforward(self, q_d: np.ndarray, dq_d: np.ndarray, t: float) -> np.ndarray | float:
        """Return the torque [Nm] (7, B) the controller adds to gravity compensation and
        the PID at time ``t`` [s] for the commanded (q_d, dq_d): none here."""
        return 0.0

    def _tick(self, batch: _Batch, active: list[tuple[int, Contact]], noise: np.ndarray,
              t: float, dt: float, h: float, record: dict[str, np.ndarray] | None) -> None:
        """One control period: measure, control, apply contacts, integrate sub-steps.

        When ``record`` is given, the measured sample is written into its arrays.
        """
        q, dq = batch.q, batch.dq
        q_d, dq_d = self.reference(batch, t)
        q_m = q + noise[:N_JOINTS]
        dq_m = dq + noise[N_JOINTS:2 * N_JOINTS] * self.noise.dq_sigma(dq) * self.noise_scale
        error = q_d - q_m
        batch.ei[:] = batch.ei + error * dt
        tau_c = (self._gravity(self._nominal_pool, np.asfortranarray(q_m))
                 + self.feedforward(q_d, dq_d, t)
                 + self.kp * error + self.kd * (dq_d - dq_m) + self.ki * batch.ei)
        step_max = self.nominal.limits.dtau_max[:, None] * dt
        tau_c = np.clip(tau_c, batch.tau_prev - step_max, batch.tau_prev + step_max)
        tau_max = self.nominal.limits.tau_max[:, None]
        saturated = np.abs(tau_c) > tau_max
        batch.ei[saturated] -= error[saturated] * dt
        tau_c = np.asfortranarray(np.clip(tau_c, -tau_max, tau_max))
        batch.tau_prev[:] = tau_c
        external = np.zeros_like(tau_c, order="F")
        for col, contact in active:
            magnitude = float(contact.magnitude(t))
            if magnitude > 0.0:
                force = magnitude * np.array(contact.direction)
                jac = self.plant.point_jacobian(q[:, col], contact.link,
                                                np.array(contact.point_local))
                external[:, col] = jac[:3].T @ force
                if record is not None:
                    record["f_ext"][:, col] = force
        drive = np.asfortranarray(tau_c + external)
        q_before, dq_before = q.copy(order="F"), dq.copy(order="F")
        ddq = np.zeros_like(q, order="F")
        for _ in range(self.config.substeps):
            plant = drive if self.friction is None else drive - self.friction.torque(dq)
            pin.abaInParallel(1, self._plant_pool, q, dq, plant, ddq)
            dq += ddq * h
            q += dq * h
        stopped = batch.reflex.copy()
        for col in np.flatnonzero(stopped):
            tau_c[:, col] = self._brake(batch, col, q_before[:, col], dq_before[:, col],
                                        external[:, col], dt)
        if record is not None:
            # The joint torque sensors sit between the motors and the links: they measure
            # the motor torque less what accelerates the rotors over this period.
            tau_sensed = tau_c - self.armature * (dq - dq_before) / dt
            record["q"][:], record["dq"][:] = q_m, dq_m
            record["tau"][:] = tau_sensed + batch.bias + noise[2 * N_JOINTS:]
            record["q_d"][:] = np.where(stopped, batch.q_hold, q_d)
            record["dq_d"][:] = np.where(stopped, 0.0, dq_d)
            record["mode"][:] = np.where(stopped, ROBOT_MODE_REFLEX, ROBOT_MODE_MOVE)
        self._check_reflex(batch, q_d, t + dt)

    def _brake(self, batch: _Batch, col: int, q: np.ndarray, dq: np.ndarray,
               external: np.ndarray, dt: float) -> np.ndarray:
        """Advance session column ``col`` of the batch, stopped by a reflex, over one
        control period of ``dt`` [s] from joint positions ``q`` [rad] and velocities
        ``dq`` [rad/s]: every joint decelerates at its acceleration limit to rest and
        stays there. Return the torque [Nm] motors and brakes transmit to do so against
        the person's joint torques ``external`` [Nm] (the arm's inverse dynamics, rotors
        and friction included)."""
        step = self.nominal.limits.ddq_max * dt
        dq_next = dq - np.clip(dq, -step, step)
        ddq = (dq_next - dq) / dt
        batch.q[:, col] = q + 0.5 * (dq + dq_next) * dt
        batch.dq[:, col] = dq_next
        torque = pin.rnea(self.plant.model, self.plant.data, q, dq, ddq) - external
        return torque if self.friction is None else torque + self.friction.torque(dq)

    def _check_reflex(self, batch: _Batch, q_d: np.ndarray, t: float) -> None:
        """Stop (from the next control period on) every running session whose arm is
        past a joint's velocity limit or out of a joint's range at time ``t`` [s],
        holding its command ``q_d`` [rad] (7, B); note what triggered it in
        :attr:`reflexes`."""
        limits = self.nominal.limits
        speed = np.abs(batch.dq) - limits.dq_max[:, None]
        place = np.maximum(limits.q_min[:, None] - batch.q, batch.q - limits.q_max[:, None])
        beyond = ((speed > 0.0) | (place > 0.0)).any(axis=0) & ~batch.reflex
        for col in np.flatnonzero(beyond):
            if (speed[:, col] > 0.0).any():
                joint = int(np.argmax(speed[:, col]))
                quantity, value, limit = "dq", batch.dq[joint, col], limits.dq_max[joint]
            else:
                joint = int(np.argmax(place[:, col]))
                value = batch.q[joint, col]
                limit = limits.q_max[joint] if value > limits.q_max[joint] else \
                    limits.q_min[joint]
                quantity = "q"
            self.reflexes[int(batch.index[col])] = {
                "t_s": round(t, 6), "joint": joint + 1, "quantity": quantity,
                "value": round(float(value), 4), "limit": round(float(limit), 4)}
            batch.reflex[col] = True
            batch.q_hold[:, col] = q_d[:, col]

    def _finish_rows(self, rows: dict[str, np.ndarray], timing_rng: np.random.Generator,
                     k0: int) -> dict[str, np.ndarray]:
        cfg = self.config
        n = rows["q"].shape[0]
        draws = timing_rng.random((n, 2))
        t = (k0 + np.arange(n)) / cfg.rate_hz + cfg.jitter_s * (2.0 * draws[:, 0] - 1.0)
        keep = draws[:, 1] >= cfg.drop_prob
        if k0 == 0:
            t[0] = 0.0
            keep[0] = True
        columns: dict[str, np.ndarray] = {"t": t[keep]}
        for prefix in ("q", "dq", "tau", "q_d", "dq_d"):
            for name, values in zip(joint_columns(prefix), rows[prefix][keep].T, strict=True):
                columns[name] = np.ascontiguousarray(values)
        f_ext = rows["f_ext"][keep]
        for axis, name in enumerate(("f_ext_x", "f_ext_y", "f_ext_z")):
            columns[name] = np.ascontiguousarray(f_ext[:, axis])
        columns["contact"] = np.linalg.norm(f_ext, axis=1) > 0.0
        columns["robot_mode"] = np.ascontiguousarray(rows["mode"][keep])
        return columns


class TrackingSimulator(ArmSimulator):
    """A simulator whose robot tracks a given trajectory instead of the protocol's.

    ``t_ref`` (M,) [s], ``q_ref`` and ``dq_ref`` (M, 7) are interpolated linearly. Used to
    compare simulated and real free-motion residuals on the same motion, and to follow
    an exciting trajectory (``recorder capture --source sim --trajectory``): with
    ``ddq_ref`` (M, 7) [rad/s^2], the controller adds the nominal model's inertial and
    Coriolis torque of the commanded motion, as a computed-torque feedforward."""

    def __init__(self, config: SimConfig, t_ref: np.ndarray, q_ref: np.ndarray,
                 dq_ref: np.ndarray, ddq_ref: np.ndarray | None = None) -> None:
        super().__init__(config)
        self.t_ref, self.q_ref, self.dq_ref, self.ddq_ref = t_ref, q_ref, dq_ref, ddq_ref

    def _at(self, values: np.ndarray, t: float) -> np.ndarray:
        return np.array([np.interp(t, self.t_ref, values[:, j]) for j in range(N_JOINTS)])

    def reference(self, batch: _Batch, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Return the given (q, dq) at ``t``, the same for every session of the batch."""
        width = batch.index.size
        return (np.tile(self._at(self.q_ref, t)[:, None], (1, width)),
                np.tile(self._at(self.dq_ref, t)[:, None], (1, width)))

    def feedforward(self, q_d: np.ndarray, dq_d: np.ndarray, t: float) -> np.ndarray | float:
        """Return M(q_d) ddq_d + C(q_d, dq_d) dq_d of the nominal model [Nm] (7, B), or
        none without ``ddq_ref``."""
        if self.ddq_ref is None:
            return 0.0
        ddq_d = np.tile(self._at(self.ddq_ref, t)[:, None], (1, q_d.shape[1]))
        out = np.zeros_like(q_d, order="F")
        pin.rneaInParallel(1, self._nominal_pool, np.asfortranarray(q_d),
                           np.asfortranarray(dq_d), np.asfortranarray(ddq_d), out)
        return out - self._gravity(self._nominal_pool, np.asfortranarray(q_d))
