"""The Rerun entity layout that capture and replay share, and the blueprint pieces.

Entity tree (timelines: ``time``, seconds since session start, and ``sample``,
the sample index):

====================================  ==========================================
entity                                content
====================================  ==========================================
``joints/q``, ``joints/dq``,           7 named series each: rad, rad/s, Nm
``joints/tau``
``observer/residual``                 momentum-observer residual r, 7 series [Nm]
``wrench/force``, ``wrench/moment``   estimated end-effector wrench [N], [Nm]
``wrench/magnitude``                  |f| [N] and |m| [Nm]
``classifier/probability``            class probabilities over time
``classifier/predicted``              predicted class, a state timeline
``events/planned``                    planned interaction time (text event)
``events/window``                     the offline window, a state lane
``events/offline_label``              the offline label at the window end
``ground_truth/force``                applied force [N] (simulated sessions)
``ground_truth/contact``              contact on/off, a state lane
``ground_truth/action``               the recorded action (text event)
``capture/cue``                       operator cue countdown (capture only)
``robot/...``                         the Panda from its URDF, joints animated
``ee_force``                          arrow: estimated end-effector force (1 cm/N)
====================================  ==========================================

Session metadata goes into the recording properties (``session``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
import rerun.urdf

TIME = "time"
SAMPLE = "sample"
JOINT_NAMES = [f"joint {i}" for i in range(1, 8)]
Q, DQ, TAU = "joints/q", "joints/dq", "joints/tau"
RESIDUAL = "observer/residual"
FORCE, MOMENT, WRENCH_NORM = "wrench/force", "wrench/moment", "wrench/magnitude"
PROBABILITY, PREDICTED = "classifier/probability", "classifier/predicted"
PLANNED, WINDOW, OFFLINE_LABEL = "events/planned", "events/window", "events/offline_label"
TRUE_FORCE, TRUE_CONTACT, TRUE_ACTION = ("ground_truth/force", "ground_truth/contact",
                                         "ground_truth/action")
CUE = "capture/cue"
ROBOT = "robot"
EE_FORCE = "ee_force"
JOINT_TRANSFORMS = "robot/joint_transforms"
ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
FORCE_ARROW_M_PER_N = 0.01
CLASS_COLORS = {"none": (160, 160, 160), "bump": (66, 135, 245), "adjust": (60, 180, 75),
                "shove": (230, 60, 60), "contact": (230, 140, 40),
                "intentional": (150, 80, 200)}
JOINT_COLORS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40),
                (148, 103, 189), (140, 86, 75), (227, 119, 194)]


def time_columns(t: np.ndarray, sample: np.ndarray) -> list[rr.TimeColumn]:
    """Return the ``time`` [s] and ``sample`` index columns for send_columns."""
    return [rr.TimeColumn(TIME, duration=np.asarray(t, dtype=float)),
            rr.TimeColumn(SAMPLE, sequence=np.asarray(sample, dtype=np.int64))]


def log_series_styles(rec: rr.RecordingStream, classes: list[str] | None = None) -> None:
    """Log static names and colours of every series (call once per recording)."""
    for path in (Q, DQ, TAU, RESIDUAL):
        rec.log(path, rr.SeriesLines(names=JOINT_NAMES, colors=JOINT_COLORS), static=True)
    for path, names in ((FORCE, ["f_x", "f_y", "f_z"]), (MOMENT, ["m_x", "m_y", "m_z"]),
                        (WRENCH_NORM, ["|f| [N]", "|m| [Nm]"]),
                        (TRUE_FORCE, ["f_x", "f_y", "f_z"])):
        rec.log(path, rr.SeriesLines(names=names, colors=JOINT_COLORS[:len(names)]),
                static=True)
    if classes:
        rec.log(PROBABILITY, rr.SeriesLines(names=classes,
                                            colors=[CLASS_COLORS.get(c, (0, 0, 0))
                                                    for c in classes]), static=True)
        state_config = rr.StateConfiguration(values=classes, labels=classes,
                                             colors=[CLASS_COLORS.get(c, (0, 0, 0))
                                                     for c in classes])
        rec.log(PREDICTED, state_config, static=True)
    rec.log(TRUE_CONTACT, rr.StateConfiguration(values=["contact", "free"],
                                                colors=[(230, 60, 60), (200, 200, 200)]),
            static=True)


def log_joint_columns(rec: rr.RecordingStream, t: np.ndarray, sample: np.ndarray,
                      q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> None:
    """Send q [rad], dq [rad/s] and tau [Nm] (each (N, 7)) as columns."""
    index = time_columns(t, sample)
    for path, values in ((Q, q), (DQ, dq), (TAU, tau)):
        rec.send_columns(path, indexes=index, columns=rr.Scalars.columns(scalars=values))


def log_scalar_columns(rec: rr.RecordingStream, path: str, t: np.ndarray, sample: np.ndarray,
                       values: np.ndarray) -> None:
    """Send an (N, k) array of scalars as k series under ``path``."""
    rec.send_columns(path, indexes=time_columns(t, sample),
                     columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)))


def log_ground_truth(rec: rr.RecordingStream, t: np.ndarray, sample: np.ndarray,
                     force: np.ndarray, contact: np.ndarray) -> None:
    """Send the applied force [N] (N, 3) and the contact lane (state changes only)."""
    log_scalar_columns(rec, TRUE_FORCE, t, sample, force)
    contact = np.asarray(contact, dtype=bool)
    changes = np.flatnonzero(np.diff(contact.astype(int), prepend=-1))
    states = np.where(contact[changes], "contact", "free")
    rec.send_columns(TRUE_CONTACT, indexes=time_columns(t[changes], sample[changes]),
                     columns=rr.StateChange.columns(state=states))


def log_robot_model(rec: rr.RecordingStream, urdf_file: str | Path) -> rr.urdf.UrdfTree:
    """Log the robot's geometry and static transforms from a URDF; return its tree."""
    tree = rr.urdf.UrdfTree.from_file_path(urdf_file, entity_path_prefix=ROBOT)
    tree.log_urdf_to_recording(rec)
    for name in ("panda_finger_joint1", "panda_finger_joint2"):
        joint = tree.get_joint_by_name(name)
        if joint is not None:
            rec.log(f"{JOINT_TRANSFORMS}/{name}", joint.compute_transform(0.02), static=True)
    return tree


def log_joint_transforms(rec: rr.RecordingStream, tree: rr.urdf.UrdfTree, t: np.ndarray,
                         sample: np.ndarray, q: np.ndarray) -> None:
    """Animate the 7 arm joints from q [rad] (N, 7) as transform columns."""
    index = time_columns(t, sample)
    for j, name in enumerate(ARM_JOINTS):
        joint = tree.get_joint_by_name(name)
        columns = joint.compute_transform_columns(q[:, j].tolist(), clamp=False)
        rec.send_columns(f"{JOINT_TRANSFORMS}/{name}", indexes=index, columns=columns)


def log_force_arrows(rec: rr.RecordingStream, t: np.ndarray, sample: np.ndarray,
                     origins: np.ndarray, forces: np.ndarray) -> None:
    """Send arrows for forces [N] (N, 3) at points [m] (N, 3), 1 cm per N."""
    rec.send_columns(EE_FORCE, indexes=time_columns(t, sample),
                     columns=rr.Arrows3D.columns(origins=origins,
                                                 vectors=forces * FORCE_ARROW_M_PER_N))


def text_event(rec: rr.RecordingStream, path: str, t: float, sample: int, text: str,
               level: str = "INFO") -> None:
    """Log one text event at time ``t`` [s]."""
    rec.set_time(TIME, duration=t)
    rec.set_time(SAMPLE, sequence=sample)
    rec.log(path, rr.TextLog(text, level=level))


def signal_views() -> list[rrb.View]:
    """Return the stacked time-series views shared by capture and replay."""
    return [
        rrb.TimeSeriesView(origin=TAU, name="joint torque tau [Nm]",
                           plot_legend=rrb.Corner2D.RightTop),
        rrb.TimeSeriesView(origin=DQ, name="joint velocity dq [rad/s]",
                           plot_legend=rrb.Corner2D.RightTop),
    ]


def replay_blueprint() -> rrb.Blueprint:
    """The replay layout: the robot in 3-D beside stacked time series and state lanes."""
    right = rrb.Vertical(
        *signal_views()[:1],
        rrb.TimeSeriesView(origin=RESIDUAL, name="observer residual r [Nm]",
                           plot_legend=rrb.Corner2D.RightTop),
        rrb.TimeSeriesView(origin="wrench", contents=[f"+ {WRENCH_NORM}", f"+ {TRUE_FORCE}"],
                           name="estimated |f|, |m| and applied force [N]"),
        rrb.TimeSeriesView(origin=PROBABILITY, name="class probability",
                           axis_y=rrb.ScalarAxis(range=(0.0, 1.0)),
                           plot_legend=rrb.Corner2D.RightTop),
        rrb.StateTimelineView(origin="/", contents=[f"+ {PREDICTED}", f"+ {TRUE_CONTACT}",
                                                    f"+ {WINDOW}"],
                              name="predicted class, contact, window"),
        row_shares=[3, 3, 2, 2, 1.5],
    )
    left = rrb.Vertical(
        rrb.Spatial3DView(origin="/", contents=[f"+ {ROBOT}/**", f"+ {EE_FORCE}",
                                                f"- {ROBOT}/**/collision_geometries/**"],
                          name="Panda and estimated end-effector force"),
        rrb.TextLogView(origin="events", name="events"),
        row_shares=[4, 1],
    )
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[2, 3]),
                         rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(state="collapsed"))


def capture_blueprint() -> rrb.Blueprint:
    """The capture layout: the same signal views, the robot and the cue."""
    right = rrb.Vertical(*signal_views(),
                         rrb.TimeSeriesView(origin=Q, name="joint position q [rad]"),
                         rrb.TimeSeriesView(origin=TRUE_FORCE, name="applied force [N]"))
    left = rrb.Vertical(rrb.Spatial3DView(origin="/", contents=[
                            f"+ {ROBOT}/**", f"- {ROBOT}/**/collision_geometries/**"],
                                          name="Panda"),
                        rrb.TextLogView(origin="capture", name="operator cue"),
                        row_shares=[4, 1])
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[2, 3]))
