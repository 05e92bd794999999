"""Simulated datasets: presets in the thesis's proportions, generated in parallel.

Presets (thesis Table 5.3, the simulated datasets, with the thesis's sampling
choices of section 5.3.3 and what it listed as future work):

* ``thesis-static``: 1233 sessions, poses A-H in turn, the four actions balanced,
  pose joints jittered by N(0, 0.1 rad), contact on a random link 1-7.
* ``thesis-dynamic``: 1380 sessions, from pose A to B-H in turn, average joint
  speed U(0.1, 0.5) rad/s (the thesis simulated 0.01-0.5; below 0.1 rad/s a
  session lasts minutes), the four actions balanced, random link.
* ``smoke``: 8 static sessions (poses A and B x four actions) for tests and demos.
* ``default-static`` (96) and ``default-dynamic`` (56, 0.2-0.5 rad/s), at 500 Hz:
  the training data of replay's default model.
* ``aug-real`` (256) and ``aug-sim`` (512), static at 500 Hz: the two roles of the
  augmentation experiment (``classify experiment augmentation``). They differ as a
  lab's real data differ from its simulation: another robot instance (robot seed 7
  against 0, so other true inertias and friction: model mismatch between the two),
  people 1.5 times as variable in strength and tempo, and contacts on every link
  where the simulation, like the thesis's, only touches the distal links 5-7.
* ``free-motion`` (96, no contact) and ``mixed-motion`` (128, the four actions
  balanced), 8 s at 500 Hz: what a real arm does when nobody touches it (issue 13).
  After a 1 s hold each session moves freely from a jittered pose A-H: quintic
  point-to-point moves to random poses, multi-sine stretches like the exciting
  trajectories of robot identification, stops and holds, with joints at up to 85 %
  of their velocity limits (the real Gaz log reaches 1.8 rad/s, 83 %) and within
  70 % of their acceleration limits (:mod:`contactkit.recorder.sim.motion`). In
  ``mixed-motion`` the contact comes while the arm moves or within 0.3 s after it
  stops, with free motion around it. Both simulate in a few minutes on 2 cores.

Every session's choices come from ``(seed, session number)``, so re-running a
preset produces the same files, and sessions already on disk are skipped. Five
simulated operators (``sim-op-1`` .. ``sim-op-5``) take turns, each with their own
strength and tempo, so evaluations can group by operator.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from contactkit.features.limits import limit_violation
from contactkit.recorder.metadata import session_filename
from contactkit.recorder.protocol import START_POSE
from contactkit.recorder.sim.presets import PRESETS, Preset
from contactkit.recorder.sim.simulator import (
    ArmSimulator,
    SessionSpec,
    SimConfig,
    plan_free_session,
    plan_session,
)
from contactkit.recorder.sources.sim import SIM_COLUMNS, SimSource
from contactkit.robots import DEFAULT_ROBOT, RobotSetup, get_robot
from contactkit.schemas import InputError, write_session
from contactkit.schemas.dataset import IndexResult, rebuild_index
from contactkit.util.atomic import remove_stale_temporaries
from contactkit.util.parallel import map_ordered

OPERATORS = tuple(f"sim-op-{i}" for i in range(1, 6))
MAX_BATCH = 32


def preset_specs(preset: Preset, n: int, seed: int, robot: RobotSetup | None = None,
                 variability: float | None = None) -> list[SessionSpec]:
    """Return the first ``n`` session specs of a preset for ``seed`` (deterministic)."""
    specs = []
    for k in range(n):
        rng = np.random.default_rng([seed, k])
        pose = preset.poses[k % len(preset.poses)]
        action = preset.actions[(k // len(preset.poses)) % len(preset.actions)]
        session_seed = int(rng.integers(2**63))
        link = None if preset.links is None or action == "none" else \
            int(preset.links[int(rng.integers(len(preset.links)))])
        common: dict[str, Any] = dict(
            seed=session_seed, action=action, operator=OPERATORS[k % len(OPERATORS)],
            pose_jitter_rad=preset.pose_jitter_rad, robot=robot, duration_s=preset.duration_s,
            link=link,
            operator_variability=preset.variability if variability is None else variability)
        if preset.free_motion:
            specs.append(plan_free_session(pose=pose, **common))
        elif preset.condition == "dynamic":
            assert preset.speed_range is not None  # a dynamic preset has its speeds
            speed = float(rng.uniform(*preset.speed_range))
            specs.append(plan_session(condition="dynamic", pose=START_POSE, target_pose=pose,
                                      speed_rad_s=round(speed, 4), **common))
        else:
            specs.append(plan_session(condition="static", pose=pose, **common))
    return specs


def simulate_specs(specs: list[SessionSpec], config: SimConfig, out_dir: str | Path
                   ) -> list[str]:
    """Simulate ``specs`` and write each session into ``out_dir`` unless its file exists;
    return the session paths. Raises :class:`InputError` naming the first session that
    failed, after writing all the others (see :func:`simulate_batch`)."""
    paths, problems = simulate_batch(specs, config, out_dir)
    if problems:
        name, problem = problems[0]
        raise InputError(f"{len(problems)} of {len(specs)} sessions failed; first: {problem}",
                         Path(out_dir) / name)
    return paths


def simulate_batch(specs: list[SessionSpec], config: SimConfig, out_dir: str | Path
                   ) -> tuple[list[str], list[tuple[str, str]]]:
    """Simulate ``specs`` together (one batch) and write each session into ``out_dir``
    unless its file exists. Runs in worker processes.

    Returns the session paths and the ``(name, problem)`` pairs of the sessions that
    failed. One failing session never costs the others: a session that fails its
    validation is reported and the batch goes on; a batch whose simulation fails is
    re-run one session at a time, so only the failing one is lost.
    """
    paths: list[str] = []
    problems: list[tuple[str, str]] = []
    try:
        for index, data, reflex in _simulated(specs, config):
            name, path, problem = _write_simulated(specs[index], config, data, reflex,
                                                   Path(out_dir))
            if problem is None:
                paths.append(path)
            else:
                problems.append((name, problem))
    except (InputError, ArithmeticError, ValueError) as err:
        if len(specs) == 1:
            return paths, [(_spec_name(specs[0], config), f"simulation failed: {err}")]
        paths, problems = [], []
        for spec in specs:
            one_path, one_problem = simulate_batch([spec], config, out_dir)
            paths += one_path
            problems += one_problem
    return paths, problems


def _simulated(specs: list[SessionSpec], config: SimConfig
               ) -> Iterator[tuple[int, dict[str, np.ndarray], dict[str, Any] | None]]:
    """Yield ``(spec index, columns, reflex)`` of every session of a batch as it
    finishes; ``reflex`` says what stopped the arm (:attr:`ArmSimulator.reflexes`), or
    is None."""
    parts: dict[int, list[dict[str, np.ndarray]]] = {}
    simulator = ArmSimulator(config)
    for index, columns, finished in simulator.run(specs):
        parts.setdefault(index, []).append(columns)
        if finished:
            chunks = parts.pop(index)
            yield index, {name: np.concatenate([c[name] for c in chunks])
                          for name in SIM_COLUMNS}, simulator.reflexes.get(index)


def _spec_name(spec: SessionSpec, config: SimConfig) -> str:
    try:
        return session_filename(SimSource(spec, config).session_meta())
    except InputError:
        return f"session with seed {spec.seed}"


def simulated_violation(data: dict[str, np.ndarray], robot: str) -> str | None:
    """Return why simulated columns are beyond the robot's limits (a blow-up), or None."""
    def joints(prefix: str) -> np.ndarray:
        return np.column_stack([data[f"{prefix}_{j}"] for j in range(1, 8)])

    return limit_violation(data["t"], joints("q"), joints("dq"), joints("tau"),
                           get_robot(robot).limits, data.get("robot_mode"))


def _write_simulated(spec: SessionSpec, config: SimConfig, data: dict[str, np.ndarray],
                     reflex: dict[str, Any] | None, out_dir: Path
                     ) -> tuple[str, str, str | None]:
    """Write one simulated session unless its file exists; return (name, path, problem).

    A session the arm's reflex stopped says so in its metadata (``simulator.reflex``:
    what triggered it, :attr:`ArmSimulator.reflexes`) as well as in its ``robot_mode``
    column.
    """
    try:
        meta = SimSource(spec, config).session_meta()
        name = session_filename(meta)
        if reflex is not None:
            meta = replace(meta, simulator={**(meta.simulator or {}), "reflex": reflex})
        path = out_dir / name
        unstable = simulated_violation(data, config.robot)
        if unstable is not None:
            raise InputError(f"simulation unstable, session not written: {unstable}")
        if not path.exists():
            write_session(path, data, meta)
    except InputError as err:
        return _spec_name(spec, config), "", err.problem
    return name, str(path), None


@dataclass
class SimulateResult:
    """What ``simulate`` did: sessions written and skipped, the ``(name, problem)`` pairs
    of the sessions that failed, and the rebuilt index."""

    written: int
    skipped: int
    index: IndexResult
    failed: list[tuple[str, str]] = field(default_factory=list)


def simulate_dataset(out_dir: str | Path, preset_name: str, sessions: int | None, seed: int,
                     workers: int, config: SimConfig | None = None,
                     progress: Callable[[int, int], None] | None = None,
                     variability: float | None = None, robot: str = DEFAULT_ROBOT,
                     scheduler: str | None = None) -> SimulateResult:
    """Write a preset's sessions into ``out_dir`` with ``workers`` processes (or on the
    Dask ``scheduler``, whose workers must see ``out_dir`` under the same path).

    Sessions whose file exists are skipped, and temporary files left by a killed run
    are removed. ``progress(done, total)`` is called as
    sessions finish. The index is rebuilt at the end. ``config`` defaults to the
    preset's rate with default physics on ``robot`` (a registry name,
    :mod:`contactkit.robots`).
    """
    if preset_name not in PRESETS:
        raise InputError(f"unknown preset {preset_name!r} (available: {', '.join(PRESETS)})")
    preset = PRESETS[preset_name]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if not os.access(out_dir, os.W_OK):
        raise InputError("cannot write here (permission denied)", out_dir)
    remove_stale_temporaries(out_dir)
    config = config or SimConfig(rate_hz=preset.rate_hz, robot_seed=preset.robot_seed,
                                 robot=robot)
    count = preset.sessions if sessions is None else sessions
    if count < 1:
        raise InputError(f"a dataset needs at least 1 session, got {count}")
    specs = preset_specs(preset, count, seed, config.setup, variability)
    todo = []
    for spec in specs:
        meta = SimSource(spec, config).session_meta()
        if not (out_dir / session_filename(meta)).exists():
            todo.append(spec)
    done = len(specs) - len(todo)
    if progress:
        progress(done, len(specs))
    failed: list[tuple[str, str]] = []
    for paths, problems in _run_batches(todo, config, out_dir, workers, scheduler):
        done += len(paths) + len(problems)
        failed += problems
        if progress:
            progress(done, len(specs))
    return SimulateResult(written=len(todo) - len(failed), skipped=len(specs) - len(todo),
                          index=rebuild_index(out_dir), failed=failed)


def _run_batches(todo: list[SessionSpec], config: SimConfig, out_dir: Path,
                 workers: int, scheduler: str | None
                 ) -> Iterator[tuple[list[str], list[tuple[str, str]]]]:
    size = max(1, min(MAX_BATCH, -(-len(todo) // max(workers, 1))))
    batches = [todo[i:i + size] for i in range(0, len(todo), size)]
    return map_ordered(partial(simulate_batch, config=config, out_dir=str(out_dir)), batches,
                       workers=workers, scheduler=scheduler)
