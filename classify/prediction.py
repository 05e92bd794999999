"""Predicting the contact class of sessions with a model file: the library behind
``classify predict``. The model's own Pipeline turns each session into its input
(scalar features or a grid), whatever its kind."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.classify.data import load_features
from contactkit.classify.modelfile.model_file import ModelFile
from contactkit.errors import DATA_ERRORS, problem_text
from contactkit.robots.dynamics import (
    ArmDynamics,
    RobotChoice,
    arm_override,
    override_dynamics,
    override_robot,
)
from contactkit.schemas import InputError, read_session
from contactkit.schemas.dataset import source_sessions
from contactkit.schemas.features import FEATURES_KEY
from contactkit.util.parallel import map_ordered

if TYPE_CHECKING:
    from contactkit.classify.events.contact_events import ContactEvent, EventModel
    from contactkit.features.detector import DetectorConfig


@dataclass
class Prediction:
    """One session's predicted class, class probabilities and recorded action."""

    source: str
    predicted: str
    probabilities: dict[str, float]
    recorded: str | None


def is_feature_table(path: Path) -> bool:
    """Return whether ``path`` is a feature table written by ``classify features``."""
    try:
        metadata = pq.read_schema(path).metadata or {}
    except (pa.ArrowInvalid, OSError):
        return False
    return FEATURES_KEY in metadata


def _rows(model: ModelFile, probabilities: np.ndarray, sources: Sequence[str] | np.ndarray,
          recorded: Sequence[str | None] | np.ndarray) -> list[Prediction]:
    classes = model.classes
    return [Prediction(str(source), classes[int(np.argmax(p))],
                       dict(zip(classes, (float(v) for v in p), strict=True)), truth)
            for source, p, truth in zip(sources, probabilities, recorded, strict=True)]


def predict_table(model: ModelFile, table: Path) -> list[Prediction]:
    """Predict every row of a feature table (models on scalar features only); the table
    must hold exactly the model's features."""
    if model.kind.input.name != "features":
        raise InputError(f"a {model.kind.name} model takes sessions, not a feature table",
                         table)
    data = load_features([table], model.transformer())
    model.check_features(data.names, table)
    proba = model.estimator.predict_proba(data.X)
    return _rows(model, proba, data.info["file"], data.info["action"])


def predict_sources(model: ModelFile, sources: Sequence[Path], robot: RobotChoice = None
                    ) -> tuple[list[Prediction], list[InputError]]:
    """Predict every session of the sources (session files, dataset directories or
    feature tables), with the arm's model ``robot`` instead of each session's own when
    given (a name, or an :class:`~contactkit.robots.dynamics.ArmOverride` with the arm's
    identified dynamics). Return the predictions in order and the sessions that could not be used
    (unreadable, window too short), which do not stop the others."""
    pipeline = model.pipeline()
    pipeline.named_steps["input"].dynamics = override_dynamics(robot)
    chain = pipeline.named_steps["input"].chain_config()  # the arm whose model gives the features
    predictions: list[Prediction] = []
    problems: list[InputError] = []
    for source in sources:
        if Path(source).is_file() and is_feature_table(Path(source)):
            predictions += predict_table(model, Path(source))
            continue
        for path in source_sessions([source]):
            try:
                session = read_session(path)
                session.meta = session.meta.with_robot(override_robot(robot))
                proba = pipeline.predict_proba([session])
                model.check_robot(chain.robot_setup(session.meta, path).robot, path)
            except DATA_ERRORS as err:
                problems.append(err if isinstance(err, InputError)
                                else InputError(problem_text(err), path))
                continue
            predictions += _rows(model, proba, [str(path)], [session.meta.action])
    return predictions, problems


@dataclass(frozen=True)
class EventsJob:
    """One session's contact events to find (:func:`session_contact_events`): the
    session at ``path``, found by ``detector`` (None: the thresholds the arm's identified
    dynamics carry, else ``fallback``, the model's), decided by ``events_model`` at
    ``decide_after_s`` [s] after onset (None: the model's delays), on the arm ``robot``
    (a name, an :class:`~contactkit.robots.dynamics.ArmOverride`, or None: the
    session's own)."""

    path: Path
    detector: DetectorConfig | None
    fallback: DetectorConfig | None
    events_model: EventModel | None
    decide_after_s: float | None
    robot: RobotChoice


def session_contact_events(job: EventsJob) -> tuple[list[ContactEvent] | None, str | None]:
    """Return one session's contact events and None, or None and the problem (one
    line) when the session cannot be used."""
    from contactkit.classify.events.contact_events import session_events
    from contactkit.features.detector import dynamics_detector
    from contactkit.features.timeseries import ChainConfig

    try:
        session = read_session(job.path)
        setup = ChainConfig(robot=job.robot).robot_setup(session.meta, job.path)
        detector = job.detector or dynamics_detector(setup.dynamics) or job.fallback
        if detector is None:
            raise InputError("no contact detector: the model carries none and the arm's "
                             "dynamics hold no thresholds", job.path)
        return session_events(session, detector, job.events_model, job.decide_after_s,
                              job.robot), None
    except DATA_ERRORS as err:
        return None, problem_text(err)


def predict_events(model: ModelFile, paths: Sequence[Path], detector: DetectorConfig | None,
                   decide_after_s: float | None = None, robot: RobotChoice = None,
                   own: Mapping[Path, ArmDynamics] | None = None, *, workers: int = 1
                   ) -> Iterator[tuple[Path, list[ContactEvent] | None, str | None]]:
    """Yield ``(path, events, problem)`` for each session of ``paths``, in order: the
    contact events ``model`` decides, found by ``detector`` (None: the thresholds of the
    identified dynamics a session's arm carries, else the model's), with the arm's
    model ``robot`` instead of each session's own when given, and the arm identified
    from the dataset itself (and its detector) for the sessions in ``own``
    (:mod:`contactkit.features.self_identification`). ``events`` None: the session
    could not be used, ``problem`` says why. ``workers`` processes score the sessions."""
    from contactkit.features.detector import dynamics_detector

    own = own or {}
    events_model, fallback = model.event_model(), model.detector_config()
    jobs = []
    for path in paths:
        arm, chosen = robot, detector
        if path in own:
            arm = arm_override(override_robot(robot), own[path])
            chosen = dynamics_detector(own[path]) or detector
        jobs.append(EventsJob(path, chosen, fallback, events_model, decide_after_s, arm))
    for path, (events, problem) in zip(paths, map_ordered(
            session_contact_events, jobs, workers=workers), strict=True):
        yield path, events, problem
