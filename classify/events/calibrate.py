"""Calibrate the contact detector on a robot's no-contact sessions.

What a lab does with a new robot: record a minute of free motion and holds with
nobody touching it, then ``classify calibrate SESSIONS... --out robot.json``. The
no-contact samples of a session are all of it when its action is ``none``; a
session with a ``contact`` column contributes its stretches at least
``CLEAR_S`` away from any labelled contact (so simulated contact sessions and
labelled real recordings can be used too). A session with contact but without a
``contact`` column is refused: its no-contact samples are unknown.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from contactkit.errors import DATA_ERRORS, problem_text
from contactkit.features.detector import (
    DYNAMIC_FEATURE,
    MIN_NOISE,
    CalibrationData,
    DetectorConfig,
    calibrate,
    calibration_samples,
)
from contactkit.features.limits import session_limit_violation
from contactkit.features.timeseries import ChainConfig, TimeseriesChain
from contactkit.robots import canonical_robot_name
from contactkit.robots.dynamics import RobotChoice, override_robot
from contactkit.schemas import InputError, Session, read_session
from contactkit.schemas.session import read_session_meta
from contactkit.util.parallel import map_ordered
from contactkit.util.progress import ProgressCallback

CLEAR_S = 0.4  # s kept clear of a labelled contact on either side
MIN_STRETCH_S = 0.5  # s, shorter no-contact stretches are not used


def no_contact_stretches(session: Session) -> list[np.ndarray]:
    """Return the sample indices of a session's no-contact stretches (see module doc)."""
    t = session.t
    if session.has("contact"):
        touched = session.column("contact").astype(bool)
        near = np.zeros(len(t), bool)
        for k in np.flatnonzero(touched):
            near[np.searchsorted(t, t[k] - CLEAR_S):np.searchsorted(t, t[k] + CLEAR_S,
                                                                     side="right")] = True
        idx = np.flatnonzero(~near)
    elif session.meta.action == "none":
        idx = np.arange(len(t))
    else:
        raise InputError(f"session has a {session.meta.action!r} contact but no contact "
                         "column, so its no-contact samples are unknown", session.path)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if idx.size else []
    return [run for run in runs if t[run[-1]] - t[run[0]] >= MIN_STRETCH_S]


def session_calibration_data(path: str | Path, template: DetectorConfig | None = None,
                             robot: RobotChoice = None, dynamic: bool = False
                             ) -> list[CalibrationData]:
    """Read one session and return the detector's calibration samples of each of its
    no-contact stretches (the observer restarts on each stretch), with the dynamic
    torque scale (``tau_dyn``) when ``dynamic``; ``robot`` names the
    arm's model instead of the session's own. A session with a sample beyond the robot's
    limits raises InputError: its thresholds would be meaningless."""
    session = read_session(path).complete()
    beyond = session_limit_violation(session, robot)
    if beyond is not None:  # a blown-up simulation or a mis-scaled log sets no threshold
        raise InputError(beyond, path)
    template = template or DetectorConfig()
    chain = TimeseriesChain.for_session(session.meta, ChainConfig(robot=robot), path)
    names = ["r", DYNAMIC_FEATURE] if dynamic else ["r"]
    features = chain.compute(session.t, session.q, session.dq, session.tau, names)
    r, dyn = features["r"], features.get(DYNAMIC_FEATURE)
    t, dq = session.t, session.dq
    return [calibration_samples(t[run], r[run], dq[run], template,
                                None if dyn is None else dyn[run])
            for run in no_contact_stretches(session)]


def calibrate_sessions(paths: Sequence[str | Path], template: DetectorConfig | None = None,
                       margin: float = 1.5, workers: int = 1,
                       progress: ProgressCallback | None = None,
                       motion_margin: float | None = None,
                       robot: RobotChoice = None,
                       problems: list[tuple[str, str]] | None = None,
                       scheduler: str | None = None,
                       floor: float | tuple[float, ...] = MIN_NOISE,
                       dynamic: bool = False, bound_dynamic: bool = True) -> DetectorConfig:
    """Calibrate the detector on the no-contact samples of ``paths`` (``margin``,
    ``motion_margin``, the at-rest ``floor`` [Nm] and ``bound_dynamic`` as in
    :func:`~contactkit.features.detector.calibrate`; with ``dynamic`` the thresholds
    also grow with each joint's dynamic torque scale, else its coefficients are 0;
    ``robot``
    the arm's model instead of each session's own); return its settings, with the
    session count in ``source`` and, when every session is of one arm, its name in
    ``robot`` (the settings then apply to that arm as they are). A session that cannot
    be read is left out and, when ``problems`` is given, appended to it as ``(file,
    problem)`` (without it, the first such session raises its InputError). Sessions are
    read in ``workers`` processes or on the Dask ``scheduler``."""
    template = template or DetectorConfig()
    results = list(map_ordered(_job, [(str(p), template, robot, dynamic) for p in paths],
                               workers=workers, progress=progress, scheduler=scheduler))
    bad = [(name, problem) for name, _, problem in results if problem is not None]
    if bad and problems is None:
        raise InputError(bad[0][1], bad[0][0])
    if problems is not None:
        problems += bad
    parts = [part for _, parts, problem in results if problem is None for part in parts]
    if not parts:
        raise InputError("no no-contact stretch of at least "
                         f"{MIN_STRETCH_S} s in the given sessions")
    failed = {name for name, _ in bad}
    robots = {canonical_robot_name(override_robot(robot) or read_session_meta(p)[0].robot)
              for p in paths
              if str(p) not in failed}
    config = calibrate(parts, template, margin,
                       source={"sessions": len(paths) - len(bad)}, motion_margin=motion_margin,
                       floor=floor, bound_dynamic=bound_dynamic)
    return replace(config, robot=robots.pop() if len(robots) == 1 else None)


def _job(item: tuple[str, DetectorConfig, RobotChoice, bool]
         ) -> tuple[str, list[CalibrationData], str | None]:
    try:
        return item[0], session_calibration_data(*item), None
    except DATA_ERRORS as err:
        return item[0], [], problem_text(err)
