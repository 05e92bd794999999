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
``wrench/force_magnitude``            estimated |f| [N]
``wrench/moment_magnitude``           estimated |m| [Nm]
``observer/threshold``                contact-detector thresholds [Nm] (hook)
``classifier/probability``            class probabilities over time
``classifier/predicted``              predicted class, a state timeline
``events/planned``                    planned interaction time (text event)
``events/window``                     the offline window, a state lane
``events/contact``                    contact events, one bar each with its label
``events/offline_label``              the offline label at the window end
``ground_truth/force``                applied force [N] (simulated sessions; zero
                                      runs logged at their ends only)
``ground_truth/contact``              contact on/off, a state lane
``ground_truth/action``               the recorded action (text event)
``capture/cue``                       operator cue countdown (capture only)
``robot/...``                         the Panda from its URDF, joints animated
``ee_force``                          arrow: estimated end-effector force (1 cm/N),
                                      in the base frame ``panda_link0``
``contact/point``, ``contact/force``  isolated contact during each event (50 Hz):
                                      point and force arrow (1 cm/N) on the touched
                                      link, base frame
``contact/link<k>``                   the touched link highlighted (its surface
                                      samples, link frame) while the event lasts
``ground_truth/contact_point``,       the applied contact's true point and force
``ground_truth/contact_force``        (simulated sessions), base frame
====================================  ==========================================

Session metadata goes into the recording properties (``session``).

Frames: the URDF logger names each link's frame after the link (``panda_link0`` is
the root) and defines every joint's transform once, statically, on ``/tf_static``;
the arm joints are animated on ``robot/joint_transforms/<joint>`` (a temporal
definition of the same child frame, which Rerun allows beside one static one).
Nothing else defines a link frame. Data in the base frame say so with
``CoordinateFrame``.

The class colours here are the project's palette: the stats report uses them too.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb
import rerun.urdf

from contactkit.viewer.palette import CLASS_COLORS, JOINT_COLORS

TIME = "time"
SAMPLE = "sample"
JOINT_NAMES = [f"joint {i}" for i in range(1, 8)]
Q, DQ, TAU = "joints/q", "joints/dq", "joints/tau"
RESIDUAL = "observer/residual"
ROBOT_ESTIMATE = "observer/robot_estimate"
"""The robot's own external-torque estimate with the residual's sign (-tau_ext_hat)."""
FORCE, MOMENT = "wrench/force", "wrench/moment"
FORCE_NORM, MOMENT_NORM = "wrench/force_magnitude", "wrench/moment_magnitude"
THRESHOLD = "observer/threshold"
PROBABILITY, PREDICTED = "classifier/probability", "classifier/predicted"
PLANNED, WINDOW, OFFLINE_LABEL = "events/planned", "events/window", "events/offline_label"
CONTACT_EVENTS = "events/contact"
TRUE_FORCE, TRUE_CONTACT, TRUE_ACTION = ("ground_truth/force", "ground_truth/contact",
                                         "ground_truth/action")
CUE = "capture/cue"
ROBOT = "robot"
EE_FORCE = "ee_force"
CONTACT_POINT, CONTACT_FORCE, CONTACT_LINK = "contact/point", "contact/force", "contact/link"
TRUE_POINT, TRUE_ARROW = "ground_truth/contact_point", "ground_truth/contact_force"
BASE_FRAME = "panda_link0"
JOINT_TRANSFORMS = "robot/joint_transforms"
FORCE_ARROW_M_PER_N = 0.01
FORCE_ARROW_RADIUS_M = 0.006
AXIS_COLORS = [(200, 70, 50), (60, 150, 60), (50, 100, 200)]  # x, y, z
ESTIMATE_COLOR = (20, 20, 20)
CONTACT_COLOR = (150, 80, 200)
TRUTH_COLOR = (40, 170, 90)
CONTACT_POINT_RADIUS_M = 0.012
THRESHOLD_COLOR = (120, 120, 120)
CONTACT_COLORS = {"contact": (230, 140, 40), "free": (205, 205, 205)}
WINDOW_COLOR = (90, 170, 200)
LEGEND_ROOM = 0.2  # time axes run this fraction of the session past its end: the legends' room
CAMERA: dict[str, Any] = {"position": (1.1, -0.9, 0.8), "look_target": (0.3, 0.0, 0.45),
                          "eye_up": (0.0, 0.0, 1.0)}  # [m] in the base frame: the whole arm


def time_columns(t: np.ndarray, sample: np.ndarray) -> list[rr.TimeColumn]:
    """Return the ``time`` [s] and ``sample`` index columns for send_columns."""
    return [rr.TimeColumn(TIME, duration=np.asarray(t, dtype=float)),
            rr.TimeColumn(SAMPLE, sequence=np.asarray(sample, dtype=np.int64))]


def _colors(classes: list[str]) -> list[tuple[int, int, int]]:
    return [CLASS_COLORS.get(c, (0, 0, 0)) for c in classes]


def log_series_styles(rec: rr.RecordingStream, classes: list[str] | None = None) -> None:
    """Log static names and colours of every series and state lane (once per recording)."""
    for path, style in _series_styles(tuple(classes or ())):
        rec.log(path, style, static=True)


@cache
def _series_styles(classes: tuple[str, ...]) -> tuple[tuple[str, rr.AsComponents], ...]:
    """Return (entity path, style) of every series and state lane for the ``classes``:
    built once per process and set of classes (Rerun converts each style's values to
    Arrow as it builds it), logged again into every recording."""
    styles: list[tuple[str, rr.AsComponents]] = [
        (path, rr.SeriesLines(names=JOINT_NAMES, colors=JOINT_COLORS))
        for path in (Q, DQ, TAU, RESIDUAL)]
    styles.append((ROBOT_ESTIMATE, rr.SeriesLines(
        names=[f"robot -tau_ext_hat {n}" for n in JOINT_NAMES], colors=JOINT_COLORS,
        widths=[0.75] * 7)))
    styles += [(path, rr.SeriesLines(names=names, colors=AXIS_COLORS))
               for path, names in ((FORCE, ["f_x", "f_y", "f_z"]),
                                   (MOMENT, ["m_x", "m_y", "m_z"]),
                                   (TRUE_FORCE, ["applied f_x", "applied f_y",
                                                 "applied f_z"]))]
    styles.append((FORCE_NORM, rr.SeriesLines(names=["estimated |f|"], colors=[ESTIMATE_COLOR],
                                              widths=[2.0])))
    styles.append((MOMENT_NORM, rr.SeriesLines(names=["estimated |m|"],
                                               colors=[ESTIMATE_COLOR])))
    if classes:
        names = list(classes)
        styles.append((PROBABILITY, rr.SeriesLines(names=names, colors=_colors(names))))
        styles += [(path, rr.StateConfiguration(values=names, labels=names,
                                                colors=_colors(names)))
                   for path in (PREDICTED, CONTACT_EVENTS)]
    styles.append((TRUE_CONTACT, rr.StateConfiguration(values=list(CONTACT_COLORS),
                                                       colors=list(CONTACT_COLORS.values()))))
    styles.append((WINDOW, rr.StateConfiguration(values=["window"], colors=[WINDOW_COLOR])))
    return tuple(styles)


def log_state_spans(rec: rr.RecordingStream, path: str, starts: np.ndarray,
                    stops: np.ndarray, labels: list[str], starts_sample: np.ndarray,
                    stops_sample: np.ndarray) -> None:
    """Send one bar per span: state ``labels[i]`` from ``starts[i]`` to ``stops[i]`` [s],
    then no state (a gap) until the next span.

    The gap is an empty state (zero values: the component cleared), not a null value:
    the Rerun SDK rejects null values in a state column (``rerun rrd verify``)."""
    t = np.column_stack([starts, stops]).ravel()
    sample = np.column_stack([starts_sample, stops_sample]).ravel()
    rows = [[label] if k == 0 else [] for label in labels for k in (0, 1)]
    order = np.argsort(t, kind="stable")
    ordered = [rows[i] for i in order]
    values = pa.array([v for row in ordered for v in row], type=pa.string())
    rec.send_columns(path, indexes=time_columns(t[order], sample[order]),
                     columns=rr.StateChange.columns(state=values).partition(
                         [len(row) for row in ordered]))


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


def log_contact_lane(rec: rr.RecordingStream, t: np.ndarray, sample: np.ndarray,
                     contact: np.ndarray, before: bool | None = None) -> None:
    """Send the true contact lane at times ``t`` [s]: its state changes only (``before``
    is the contact state logged last, None at the start of a session)."""
    contact = np.asarray(contact, dtype=bool)
    changes = np.flatnonzero(np.diff(contact.astype(int),
                                     prepend=-1 if before is None else int(before)))
    if not len(changes):
        return
    states = np.where(contact[changes], "contact", "free")
    rec.send_columns(TRUE_CONTACT, indexes=time_columns(t[changes], sample[changes]),
                     columns=rr.StateChange.columns(state=states))


def log_robot_model(rec: rr.RecordingStream, urdf_file: str | Path) -> rr.urdf.UrdfTree:
    """Log the robot's geometry and the static transforms of all its joints (movable
    joints at zero: the fingers stay there) from a URDF; return its tree."""
    stat = Path(urdf_file).stat()
    tree = _urdf_tree(str(urdf_file), stat.st_mtime_ns, stat.st_size)
    tree.log_urdf_to_recording(rec)
    return tree


@cache
def _urdf_tree(urdf_file: str, mtime_ns: int, size: int) -> rr.urdf.UrdfTree:
    """Return the tree of a URDF file, parsed once per process while the file's
    modification time [ns] and size [bytes] stay the same."""
    return rr.urdf.UrdfTree.from_file_path(urdf_file, entity_path_prefix=ROBOT)


def log_force_arrow_style(rec: rr.RecordingStream) -> None:
    """Log that the force arrow lives in the base frame, and its colour and radius."""
    rec.log(EE_FORCE, *_force_arrow_style(), static=True)


@cache
def _force_arrow_style() -> tuple[rr.AsComponents, ...]:
    """Return the force arrow's frame and style (built once per process)."""
    return (rr.CoordinateFrame(BASE_FRAME),
            rr.Arrows3D.from_fields(colors=[ESTIMATE_COLOR], radii=[FORCE_ARROW_RADIUS_M]))


def log_contact_styles(rec: rr.RecordingStream) -> None:
    """Log that the isolated and the true contact live in the base frame, with their
    colours and sizes (estimate purple, truth green)."""
    for path, *style in _contact_styles():
        rec.log(path, *style, static=True)


@cache
def _contact_styles() -> tuple[tuple[str, rr.CoordinateFrame, rr.Points3D | rr.Arrows3D], ...]:
    """Return (entity path, frame, style) of the isolated and the true contact's points
    and arrows (built once per process)."""
    styles: list[tuple[str, rr.CoordinateFrame, rr.Points3D | rr.Arrows3D]] = []
    for point, arrow, color in ((CONTACT_POINT, CONTACT_FORCE, CONTACT_COLOR),
                                (TRUE_POINT, TRUE_ARROW, TRUTH_COLOR)):
        styles.append((point, rr.CoordinateFrame(BASE_FRAME),
                       rr.Points3D.from_fields(colors=[color], radii=[CONTACT_POINT_RADIUS_M])))
        styles.append((arrow, rr.CoordinateFrame(BASE_FRAME),
                       rr.Arrows3D.from_fields(colors=[color], radii=[FORCE_ARROW_RADIUS_M])))
    return tuple(styles)


def _partitioned(points: np.ndarray, present: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the rows of ``points`` (N, 3) that are ``present`` and the partition
    lengths (1 or 0 per row: an empty row clears the entity from that time on)."""
    present = np.asarray(present, dtype=bool)
    return np.asarray(points, dtype=float).reshape(-1, 3)[present], present.astype(np.int32)


def log_contact_columns(rec: rr.RecordingStream, t: np.ndarray, sample: np.ndarray,
                        points: np.ndarray, forces: np.ndarray, present: np.ndarray,
                        truth: bool = False) -> None:
    """Send contact points [m] and force arrows [N] (N, 3 each, base frame) at times
    ``t`` [s]: one per row where ``present``, none (cleared) elsewhere. ``truth``: the
    simulator's applied contact instead of the estimate."""
    index = time_columns(t, sample)
    positions, lengths = _partitioned(points, present)
    vectors, _ = _partitioned(forces, present)
    point, arrow = (TRUE_POINT, TRUE_ARROW) if truth else (CONTACT_POINT, CONTACT_FORCE)
    rec.send_columns(point, indexes=index,
                     columns=rr.Points3D.columns(positions=positions).partition(lengths))
    rec.send_columns(arrow, indexes=index, columns=rr.Arrows3D.columns(
        origins=positions, vectors=vectors * FORCE_ARROW_M_PER_N).partition(lengths))


def log_link_highlight(rec: rr.RecordingStream, link: int, surface_points: np.ndarray,
                       t: np.ndarray, sample: np.ndarray, shown: np.ndarray) -> None:
    """Highlight link ``link`` by its surface points [m] (n, 3, link frame) at the
    times [s] where ``shown``, and clear it at the others."""
    path = f"{CONTACT_LINK}{link}"
    rec.log(path, rr.CoordinateFrame(f"panda_link{link}"),
            rr.Points3D.from_fields(colors=[CONTACT_COLOR], radii=[0.006]), static=True)
    shown = np.asarray(shown, dtype=bool)
    lengths = np.where(shown, len(surface_points), 0).astype(np.int32)
    positions = np.tile(surface_points, (int(shown.sum()), 1))
    rec.send_columns(path, indexes=time_columns(t, sample),
                     columns=rr.Points3D.columns(positions=positions).partition(lengths))


def log_joint_transforms(rec: rr.RecordingStream, tree: rr.urdf.UrdfTree, t: np.ndarray,
                         sample: np.ndarray, q: np.ndarray) -> None:
    """Animate the 7 arm joints (the tree's first 7 revolute joints from its root, whatever
    the robot names them) from q [rad] (N, 7) as transform columns: the tree computes all
    joints' transforms in one call, joint by joint, and each joint's go out as slices of
    its Arrow arrays (already Rerun's component types: nothing is converted again).

    Every row carries the whole transform (translation [m], quaternion, parent and child
    frame), the constant parts too: Rerun resolves a ``Transform3D`` atomically, from the
    last row that sets any of its components, so a row with only the rotation would drop
    the joint's offset and its frames."""
    arm = [j.name for j in tree.joints() if j.joint_type in ("revolute", "continuous")][:7]
    n, k = len(q), len(arm)
    one_row = pa.array([0, k * n], type=pa.int32())  # all joints' values in one list, joint-major
    names = pa.ListArray.from_arrays(one_row, pa.array(arm).take(np.repeat(np.arange(k), n)))
    values = pa.ListArray.from_arrays(one_row, pa.array(
        np.asarray(q, dtype=float)[:, :k].T.ravel()))
    batches = tree.compute_joint_transform_batches(names, values, clamp=False).flatten()
    fields = dict(zip([f.name for f in batches.type], batches.flatten(), strict=True))
    index = time_columns(t, sample)
    for j, name in enumerate(arm):
        rec.send_columns(f"{JOINT_TRANSFORMS}/{name}", indexes=index, columns=[
            rr.ComponentColumn(descriptor, batch(fields[field].slice(j * n, n)))
            for field, batch, descriptor in _TRANSFORM_FIELDS])


_TRANSFORM_FIELDS = (
    ("translation", rr.components.Translation3DBatch, rr.Transform3D.descriptor_translation()),
    ("quaternion", rr.components.RotationQuatBatch, rr.Transform3D.descriptor_quaternion()),
    ("parent_frame", rr.components.TransformFrameIdBatch,
     rr.Transform3D.descriptor_parent_frame()),
    ("child_frame", rr.components.TransformFrameIdBatch, rr.Transform3D.descriptor_child_frame()),
)
"""The fields of the URDF tree's joint transforms (already in these component types), and
the ``Transform3D`` components they are sent as: one per row of a joint's column."""


def log_force_arrows(rec: rr.RecordingStream, t: np.ndarray, sample: np.ndarray,
                     origins: np.ndarray, forces: np.ndarray) -> None:
    """Send arrows for forces [N] (N, 3) at points [m] (N, 3), both in the base frame,
    1 cm per N."""
    rec.send_columns(EE_FORCE, indexes=time_columns(t, sample),
                     columns=rr.Arrows3D.columns(origins=origins,
                                                 vectors=forces * FORCE_ARROW_M_PER_N))


def text_event(rec: rr.RecordingStream, path: str, t: float, sample: int, text: str,
               level: str = "INFO") -> None:
    """Log one text event at time ``t`` [s], rounded to the millisecond: the viewer's
    events table prints the time as it is stored (``+10.950015s`` unrounded)."""
    rec.set_time(TIME, duration=round(t, 3))
    rec.set_time(SAMPLE, sequence=sample)
    rec.log(path, rr.TextLog(text, level=level))


def time_axis(duration_s: float | None) -> rrb.TimeAxis | None:
    """Return the time axis of the stacked views: 0 to ``duration_s`` [s] plus room on the
    right for the legends, the same in every view (None: fit to the data)."""
    if duration_s is None:
        return None
    end = duration_s * (1.0 + LEGEND_ROOM)
    return rrb.TimeAxis(link="Independent", view_range=rr.TimeRange(
        start=rr.TimeRangeBoundary.absolute(seconds=0.0),
        end=rr.TimeRangeBoundary.absolute(seconds=end)))


def series_view(origin: str, name: str, duration_s: float | None,
                contents: list[str] | None = None, axis_y: rrb.ScalarAxis | None = None,
                legend: bool = True) -> rrb.TimeSeriesView:
    """Return one stacked time-series view with the shared time axis and its legend in
    the room right of the data."""
    return rrb.TimeSeriesView(origin=origin, name=name, contents=contents or "$origin/**",
                              axis_x=time_axis(duration_s), axis_y=axis_y,
                              plot_legend=rrb.PlotLegend(rrb.Corner2D.RightTop,
                                                         visible=legend))


def robot_view(name: str, contents: list[str]) -> rrb.Spatial3DView:
    """Return the 3-D view of the robot, its camera framing the whole arm."""
    return rrb.Spatial3DView(origin="/", contents=contents, name=name,
                             eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital,
                                                            **CAMERA))


def replay_blueprint(duration_s: float | None = None) -> rrb.Blueprint:
    """The replay layout: the robot in 3-D beside stacked time series and state lanes,
    on one time axis of ``duration_s`` [s] (None: each fits its data)."""
    right = rrb.Vertical(
        series_view(TAU, "joint torque tau [Nm]", duration_s),
        series_view("observer", "observer residual r [Nm] (joint colours as above; thin: "
                    "the robot's own estimate, -tau_ext_hat, where recorded)",
                    duration_s, contents=[f"+ {RESIDUAL}", f"+ {ROBOT_ESTIMATE}",
                                          f"+ {THRESHOLD}"], legend=False),
        series_view("/", "estimated |f| and applied force [N]", duration_s,
                    contents=[f"+ {FORCE_NORM}", f"+ {TRUE_FORCE}"]),
        series_view(PROBABILITY, "class probability", duration_s,
                    axis_y=rrb.ScalarAxis(range=(-0.05, 1.05), zoom_lock=True)),
        rrb.StateTimelineView(origin="/", contents=[f"+ {PREDICTED}", f"+ {CONTACT_EVENTS}",
                                                    f"+ {TRUE_CONTACT}", f"+ {WINDOW}"],
                              name="predicted class, contact events, true contact, window",
                              time_view=time_axis(duration_s)),
        row_shares=[4.8, 2.8, 3.3, 3.3, 3.8],  # room for 7 legend rows and 4 state lanes
    )
    left = rrb.Vertical(
        robot_view("Panda, end-effector force, isolated contact (purple) and true "
                   "contact (green), 1 cm per N",
                   [f"+ {ROBOT}/**", f"+ {EE_FORCE}", "+ contact/**", f"+ {TRUE_POINT}",
                    f"+ {TRUE_ARROW}"]),
        rrb.TextLogView(origin="events", name="events"),
        row_shares=[4, 1],
    )
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[2, 3]),
                         rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(state="collapsed"))


def capture_blueprint(duration_s: float | None = None) -> rrb.Blueprint:
    """The capture layout: the robot and the operator cue beside joint torque,
    velocity, position and the applied force, on one time axis of ``duration_s`` [s]."""
    right = rrb.Vertical(series_view(TAU, "joint torque tau [Nm]", duration_s),
                         series_view(DQ, "joint velocity dq [rad/s]", duration_s),
                         series_view(Q, "joint position q [rad]", duration_s),
                         series_view(TRUE_FORCE, "applied force [N]", duration_s))
    left = rrb.Vertical(robot_view("Panda", [f"+ {ROBOT}/**"]),
                        rrb.TextLogView(origin="capture", name="operator cue"),
                        row_shares=[4, 1])
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[2, 3]),
                         rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(state="collapsed"))
