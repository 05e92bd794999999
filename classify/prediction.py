"""Predicting the contact class of sessions with a model file: the library behind
``classify predict``. The model's own Pipeline turns each session into its input
(scalar features or a grid), whatever its kind."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.classify.data import load_features
from contactkit.classify.modelfile.model_file import ModelFile
from contactkit.errors import DATA_ERRORS, problem_text
from contactkit.robots.dynamics import RobotChoice, override_dynamics, override_robot
from contactkit.schemas import InputError, read_session
from contactkit.schemas.dataset import session_files
from contactkit.schemas.features import FEATURES_KEY


@dataclass
class Prediction:
    """One session's predicted class, class probabilities and recorded action."""

    source: str
    predicted: str
    probabilities: dict[str, float]
    recorded: str | None


def session_paths(source: Path) -> list[Path]:
    """Return the session files of a directory, or ``[source]`` for a file; raise
    InputError for a missing path or an empty directory."""
    source = Path(source)
    if source.is_dir():
        files = session_files(source)
        if not files:
            raise InputError("no session files (*.parquet) in this directory", source)
        return files
    if not source.exists():
        raise InputError("no such file or directory", source)
    return [source]


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
        for path in session_paths(source):
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
