"""The simulated Panda as a capture source."""

from __future__ import annotations

import hashlib
import json
import secrets
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from contactkit.recorder.metadata import session_meta
from contactkit.recorder.sources.base import ProtocolChoices, Source
from contactkit.schemas import InputError, SessionMeta, joint_columns

if TYPE_CHECKING:
    from contactkit.recorder.sim.simulator import SessionSpec, SimConfig
    from contactkit.recorder.trajectory import Trajectory

# The simulator (pinocchio, scipy) is imported where a session is planned or run: the
# command line imports every source to list its options.

SIM_COLUMNS = ["t", *joint_columns("q"), *joint_columns("dq"), *joint_columns("tau"),
               *joint_columns("q_d"), *joint_columns("dq_d"), "f_ext_x", "f_ext_y", "f_ext_z",
               "contact", "robot_mode"]


def sim_session_id(spec: SessionSpec, config: SimConfig, trajectory: str | None = None
                   ) -> str:
    """Return a session id determined by the spec and configuration (same seed, same id),
    and by the followed trajectory's SHA-256 when there is one."""
    doc = json.dumps({"spec": spec.as_dict(), "config": config.to_dict(),
                      **({} if trajectory is None else {"trajectory": trajectory})},
                     sort_keys=True)
    return hashlib.sha256(doc.encode()).hexdigest()[:16]


class SimSource(Source):
    """The simulated Panda (pinocchio dynamics, the thesis protocol), one session streamed
    in chunks of ``chunk`` samples; with ``dynamics``, an identified arm instead of a
    random instance (the simulator's ``SimConfig.dynamics``; its values go into the
    ``simulator`` metadata and the session id)."""

    name = "sim"
    columns = SIM_COLUMNS
    live = False

    @dataclass(frozen=True)
    class Config:
        """Options of the simulated arm."""

        robot: str = field(default="panda", metadata={
            "help": "The simulated arm: panda, fr3, or another registered robot "
                    "(recorder robots lists them)."})
        rate: float = field(default=1000.0, metadata={
            "help": "Sample rate (the thesis recorded at ~600).", "unit": "Hz"})
        seed: int | None = field(default=None, metadata={
            "help": "Random seed; the same seed gives the same data (default: random, stored "
                    "in the metadata)."})
        robot_seed: int | None = field(default=None, metadata={
            "help": "Simulated robot instance (its true inertia and friction; default 0). "
                    "Not with --dynamics."})
        dynamics: Path | None = field(default=None, metadata={
            "help": "Simulate this identified arm (a file of recorder identify, or of "
                    "recorder simulate --write-dynamics) instead of a random instance of "
                    "the nominal one: its link inertias, friction and armature are the "
                    "plant's, unperturbed. Checked against --robot and --hand."})
        noise_file: Path | None = field(default=None, metadata={
            "help": "Sensor-noise JSON (from recorder stats --deep); default: measured on "
                    "the real Panda reference recording."})
        noise_scale: float = field(default=1.0, metadata={
            "help": "Multiply the sensor noise."})
        jitter_ms: float = field(default=0.0, metadata={
            "help": "Time-stamp jitter, uniform +-.", "unit": "ms"})
        drop_prob: float = field(default=0.0, metadata={
            "help": "Probability of losing a sample."})
        trajectory: Path | None = field(default=None, metadata={
            "help": "Follow this joint trajectory (CSV from recorder excite) with no "
                    "contact (--action none): it sets the motion and the duration."})

    def __init__(self, spec: SessionSpec, config: SimConfig, chunk: int = 10,
                 choices: ProtocolChoices | None = None,
                 trajectory: Trajectory | None = None) -> None:
        self.spec = spec
        self.trajectory = trajectory
        self.config = config
        self.chunk = chunk
        self.choices = choices or ProtocolChoices(
            action=spec.action, pose=spec.pose, condition=spec.condition,
            operator=spec.operator, with_hand=config.with_hand)
        self.planned_at_s = spec.planned_at_s
        self.duration_s = spec.duration_s
        self.nominal_rate_hz = config.rate_hz

    @classmethod
    def from_config(cls, config: SimSource.Config, choices: ProtocolChoices) -> SimSource:
        """Return the simulated session planned from ``choices`` with options ``config``."""
        if config.noise_scale < 0:
            raise InputError(f"noise scale must be >= 0, got {config.noise_scale}")
        if choices.pose is None:
            raise InputError("the simulator needs a start pose")
        from contactkit.recorder.sim.noise import SensorNoise, default_noise
        from contactkit.recorder.sim.simulator import SimConfig, load_simulated_arm, plan_session
        from contactkit.robots import RobotSetup

        dynamics = None if config.dynamics is None else load_simulated_arm(
            config.dynamics, RobotSetup(config.robot, choices.with_hand), config.robot_seed)
        noise = default_noise() if config.noise_file is None else \
            SensorNoise.from_file(config.noise_file)
        sim_config = SimConfig(rate_hz=config.rate, robot=config.robot,
                               with_hand=choices.with_hand,
                               robot_seed=config.robot_seed or 0, noise=noise,
                               noise_scale=config.noise_scale,
                               jitter_s=config.jitter_ms / 1000.0, drop_prob=config.drop_prob,
                               dynamics=dynamics)
        seed = secrets.randbits(63) if config.seed is None else config.seed
        if config.trajectory is not None:
            return cls._following(config.trajectory, sim_config, seed, choices)
        spec = plan_session(seed=seed, condition=choices.condition, action=choices.action,
                            pose=choices.pose, target_pose=choices.target_pose,
                            speed_rad_s=choices.speed_rad_s, link=choices.link,
                            planned_at_s=choices.planned_at_s, duration_s=choices.duration_s,
                            operator=choices.operator or "sim", robot=sim_config.setup)
        return cls(spec, sim_config, choices=choices)

    @classmethod
    def _following(cls, path: Path, config: SimConfig, seed: int,
                   choices: ProtocolChoices) -> SimSource:
        """Return the session that follows the trajectory in file ``path`` (checked for
        the simulated arm) from its first sample, with no contact: the dynamic
        condition, action none, as long as the trajectory."""
        from contactkit.recorder.sim.simulator import plan_session
        from contactkit.recorder.trajectory import read_trajectory

        if choices.action != "none":
            raise InputError(f"a trajectory is recorded without contact: give --action none, "
                             f"not {choices.action}")
        given = [flag for flag, value in (
            ("--target-pose", choices.target_pose), ("--speed", choices.speed_rad_s),
            ("--duration", choices.duration_s), ("--planned-at", choices.planned_at_s),
            ("--link", choices.link)) if value is not None]
        if given:
            raise InputError(f"{given[0]} does not go with --trajectory, which sets the "
                             "motion and the duration")
        trajectory = read_trajectory(path, config.robot)
        duration = trajectory.duration_s
        assert choices.pose is not None  # the caller refuses a missing start pose
        spec = plan_session(seed=seed, condition="static", action="none", pose=choices.pose,
                            planned_at_s=duration / 2.0, duration_s=duration,
                            operator=choices.operator or "sim", robot=config.setup)
        spec = replace(spec, condition="dynamic", q_start=tuple(trajectory.q[0].tolist()),
                       motion_start_s=0.0, motion_duration_s=duration)
        return cls(spec, config, choices=replace(choices, condition="dynamic"),
                   trajectory=trajectory)

    def stream(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield the session's rows, ``chunk`` samples at a time."""
        from contactkit.recorder.sim.simulator import ArmSimulator, TrackingSimulator

        if self.trajectory is None:
            simulator = ArmSimulator(self.config)
        else:
            path = self.trajectory
            simulator = TrackingSimulator(self.config, path.t, path.q, path.dq, path.ddq)
        for _, columns, _ in simulator.run([self.spec], chunk=self.chunk):
            yield columns

    def metadata(self) -> dict[str, Any]:
        """Return source, simulator parameters and seed for the session metadata (and
        the followed trajectory's length and samples' SHA-256)."""
        simulator = {"seed": self.spec.seed, "config": self.config.to_dict(),
                     "session": self.spec.as_dict()}
        if self.trajectory is not None:
            path = self.trajectory
            simulator["trajectory"] = {"samples": len(path.t), "duration_s": path.duration_s,
                                       "robot": path.robot, "sha256": path.sha256()}
        return {"source": self.name, "robot": self.config.robot, "simulator": simulator}

    def session_meta(self) -> SessionMeta:
        """Return the metadata of the simulated session: the spec's resolved choices (the
        jittered pose actually simulated, the drawn link), an id determined by spec and
        configuration, and the simulator's parameters."""
        spec = self.spec
        return session_meta(
            session_id=sim_session_id(spec, self.config, None if self.trajectory is None
                                      else self.trajectory.sha256()), action=spec.action,
            condition=spec.condition, pose=spec.pose, pose_q_rad=spec.q_start,
            target_pose=spec.target_pose, target_q_rad=spec.q_target,
            speed_rad_s=spec.speed_rad_s, link=spec.link, planned_at_s=spec.planned_at_s,
            nominal_rate_hz=self.config.rate_hz, operator=spec.operator,
            notes=self.choices.notes, with_hand=self.config.with_hand, **self.metadata())
