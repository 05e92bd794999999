"""Identify a dataset's arm from the dataset itself, cross-fitted, to find its contacts.

A moving arm's nominal model is wrong by several Nm, so the contact detector's
thresholds must grow with motion, and light touches (and pushes close to a joint's
axis) stay under them. A dataset recorded on one arm, with nobody's labels, shows that
arm's own dynamics in the motion around its contacts (:func:`~contactkit.features.
identification.motion_around_contacts`). :func:`cross_fitted_dynamics` deals the
sessions into two halves, whole poses to each (:func:`halves`), identifies the arm from
each half (``recorder identify --around-contacts`` does the same for a whole dataset)
and gives each session the dynamics identified from the *other* half, with the detector
calibrated alongside. So no contact is judged with a model fitted to the motion around
it, and what was measured is what is used: on 16 simulated ``thesis-dynamic`` datasets
of seeds and robot instances the default model never saw, 14 met every event-level bar
of issue 38 this way and 9 with the nominal model (docs/howto/identify.md).

:func:`moving_dataset` says whether the sessions :func:`survey` read are such a
dataset: each half must hold :data:`MIN_MOTION_S` of motion, and no session may carry
identified dynamics already (``recorder set-robot --dynamics``). ``classify predict
--events`` identifies by itself when they are (``--identify/--no-identify`` decide
instead).

Units: times [s], joint speeds [rad/s].
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from contactkit.errors import DATA_ERRORS, InputError, problem_text
from contactkit.features.detector import REST_SPEED, DetectorConfig
from contactkit.features.identification import Identified, identify_sessions, progress_steps
from contactkit.robots.dynamics import ArmDynamics
from contactkit.schemas import read_session
from contactkit.util.parallel import map_ordered, pool_context

MIN_MOTION_S = 60.0
"""Motion each half must hold for a dataset to identify its own arm [s]: samples with
joint speed |dq| (2-norm) at least :data:`~contactkit.features.detector.REST_SPEED`.
A half of a 96-session ``thesis-dynamic`` dataset holds about 350 s; a static dataset
next to none; the real Panda log 21 s in one session, the two real FR3 recordings 10 s
each."""


@dataclass(frozen=True)
class SessionSurvey:
    """What deciding on self-identification needs of one session: its ``path``, its
    pose ``group`` (the target pose of a move, else the pose; "" for none), how long
    its arm moves (``motion_s`` [s]) and whether it carries identified dynamics."""

    path: Path
    group: str
    motion_s: float
    carries_dynamics: bool


@dataclass(frozen=True)
class Fold:
    """One half of a cross-fitted identification: the sessions ``scored`` with the arm
    ``identified`` from the sessions ``fitted`` (the other half)."""

    fitted: tuple[Path, ...]
    scored: tuple[Path, ...]
    identified: Identified


def survey(paths: Sequence[str | Path], problems: list[tuple[str, str]] | None = None
           ) -> list[SessionSurvey]:
    """Read each session of ``paths``; return what :func:`halves` and
    :func:`moving_dataset` need of each. A file that is not a readable session is left
    out, and appended to ``problems`` as ``(file, why)`` when given (else the command
    that scores it reports it)."""
    out = []
    for name in paths:
        path = Path(name)
        try:
            session = read_session(path)
        except DATA_ERRORS as err:
            if problems is not None:
                problems.append((str(path), problem_text(err)))
            continue
        meta = session.meta
        t, speed = session.t, np.linalg.norm(np.nan_to_num(session.dq), axis=1)
        motion = float(np.diff(t)[speed[1:] >= REST_SPEED].sum())  # steps ending moving
        out.append(SessionSurvey(path, meta.target_pose or meta.pose or "", motion,
                                 meta.dynamics is not None))
    return out


def halves(sessions: Sequence[SessionSurvey]) -> tuple[list[Path], list[Path]]:
    """Return the two halves of ``sessions`` for cross-fitting: their pose groups dealt
    alternately in sorted order (whole poses in each), or with a single group, the
    sessions dealt alternately."""
    groups = sorted({s.group for s in sessions})
    if len(groups) > 1:
        first = [s.path for s in sessions if groups.index(s.group) % 2 == 0]
        second = [s.path for s in sessions if groups.index(s.group) % 2 == 1]
    else:
        first = [s.path for s in sessions[::2]]
        second = [s.path for s in sessions[1::2]]
    return first, second


def moving_dataset(sessions: Sequence[SessionSurvey]) -> str | None:
    """Return why ``sessions`` should not identify their own arm (None: they should):
    a session already carries identified dynamics, or a half holds less than
    :data:`MIN_MOTION_S` of motion."""
    if any(s.carries_dynamics for s in sessions):
        return "a session carries identified dynamics"
    motion = {s.path: s.motion_s for s in sessions}
    least = min((sum(motion[p] for p in half) for half in halves(sessions)), default=0.0)
    if least < MIN_MOTION_S:
        return (f"too little motion to identify the arm from: {least:.0f} s in a half, "
                f"{MIN_MOTION_S:.0f} s needed")
    return None


def cross_fitted_dynamics(sessions: Sequence[SessionSurvey], detector: DetectorConfig,
                          robot: str | None = None,
                          progress: Callable[[str, int, int], None] | None = None, *,
                          workers: int = 1) -> list[Fold]:
    """Identify the arm of ``sessions`` from each of their :func:`halves`, around the
    contacts ``detector`` finds with the nominal model (the arm ``robot`` names in place
    of the sessions' own when given); return the two folds, each half scored with the
    arm identified from the other. ``progress(label, done, total)`` follows each
    identification's steps (:func:`~contactkit.features.identification.
    identify_sessions`), or with ``workers`` > 1 (both halves at once, in two
    processes) both identifications' steps together. InputError (one line) when a half
    is empty, its sessions are of different arms, or its motion determines nothing."""
    first, second = halves(sessions)
    if not first or not second:
        raise InputError("cross-fitting needs sessions in both halves: at least two")
    pairs = ((second, first), (first, second))
    if workers > 1:
        results = _identify_halves_at_once([fitted for fitted, _ in pairs], detector, robot,
                                           progress)
    else:
        results = []
        for k, (fitted, _) in enumerate(pairs, 1):
            label = f"identifying the arm from half {3 - k} of 2"
            counted = None if progress is None else (
                lambda done, total, label=label: progress(label, done, total))
            results.append(_identify_half((fitted, detector, robot, None), counted))
    folds = []
    for (fitted, scored), (identified, problem) in zip(pairs, results, strict=True):
        if identified is None:
            raise InputError(problem or "not identified")
        folds.append(Fold(tuple(fitted), tuple(scored), identified))
    return folds


def _identify_halves_at_once(fitted: Sequence[list[Path]], detector: DetectorConfig,
                             robot: str | None,
                             progress: Callable[[str, int, int], None] | None
                             ) -> list[tuple[Identified | None, str | None]]:
    """Return :func:`_identify_half` of each of ``fitted``, all at once in as many
    processes. The workers' steps reach ``progress`` through a queue, summed over the
    halves (a half that has not reported yet counts
    :func:`~contactkit.features.identification.progress_steps`)."""
    jobs = [(half, detector, robot) for half in fitted]
    if progress is None:
        return list(map_ordered(_identify_half, [(*job, None) for job in jobs],
                                workers=len(jobs)))
    label = "identifying the arm from both halves at once"
    steps = [(0, progress_steps(len(half))) for half in fitted]
    progress(label, 0, sum(total for _, total in steps))
    context, _, _ = pool_context()
    with context.Manager() as manager:
        reports = manager.Queue()

        def relay() -> None:
            while (report := reports.get()) is not None:
                half, done, total = report
                steps[half] = (done, total)
                progress(label, sum(d for d, _ in steps), sum(t for _, t in steps))

        relaying = threading.Thread(target=relay, name="identify-progress", daemon=True)
        relaying.start()
        try:
            return list(map_ordered(_identify_half, [(*job, (reports, k))
                                                     for k, job in enumerate(jobs)],
                                    workers=len(jobs)))
        finally:
            reports.put(None)
            relaying.join()


def _identify_half(job: tuple[list[Path], DetectorConfig, str | None, tuple[Any, int] | None],
                   progress: Callable[[int, int], None] | None = None
                   ) -> tuple[Identified | None, str | None]:
    """Identify the arm of one half's sessions around the contacts the detector finds;
    return it and None, or None and why not (one line: a worker's result is data).
    The job's last item, a queue and the half's number (or None), sends the
    identification's steps as ``(half, done, total)`` to the process that mapped it;
    else they go to ``progress``."""
    fitted, detector, robot, reports = job
    try:
        return identify_sessions(fitted, robot, around_contacts=detector, problems=[],
                                 progress=progress if reports is None else _sender(*reports)
                                 ), None
    except InputError as err:
        return None, err.problem


def _sender(queue: Any, half: int) -> Callable[[int, int], None]:
    """Return a ``(done, total)`` callback that puts ``(half, done, total)`` on
    ``queue`` (a manager's queue, which a worker process can reach)."""
    def send(done: int, total: int) -> None:
        queue.put((half, done, total))

    return send


def dynamics_by_session(folds: Sequence[Fold]) -> dict[Path, ArmDynamics]:
    """Return the identified dynamics each scored session of ``folds`` is scored with."""
    return {path: fold.identified.dynamics for fold in folds for path in fold.scored}
