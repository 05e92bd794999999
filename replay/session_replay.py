"""Replaying sessions into Rerun recordings: the library behind the ``replay`` command.

:func:`replay_session` streams one session through :class:`ReplayStream` into its
own recording (saved to an .rrd file, sent to a viewer, or both) batch by batch, in
memory bounded by one batch, paced at a multiple of wall-clock speed or as fast as
possible, optionally thinning what goes to Rerun, and returns a
:class:`ReplaySummary`. A session that is refused (unreadable, or not usable by the
model) leaves no file behind; a recording file exists only when it was written
completely.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rerun as rr

from contactkit.classify.events.contact_events import ContactEvent
from contactkit.classify.modelfile.model_file import ModelFile
from contactkit.errors import DATA_ERRORS, problem_text
from contactkit.features.detector import DetectorConfig
from contactkit.replay.engine import DEFAULT_HOP_S, OfflineAnswer, ReplayStream
from contactkit.replay.recording import (
    BlockLogger,
    log_results,
    log_static,
    new_recording,
    save_paths_for,
)
from contactkit.robots.dynamics import RobotChoice
from contactkit.schemas import InputError
from contactkit.schemas.dataset import session_files
from contactkit.util.atomic import Owned, atomic_write
from contactkit.util.pacing import paced
from contactkit.util.rrd_file import check_space, finish_recording, start_recording
from contactkit.viewer import layout


@dataclass
class ReplaySummary:
    """What one replay found: the recorded action, the offline answer (None without a
    planned interaction time), the online predictions (time [s] and label of each), the
    contact events (with a detector) and the .rrd file written (if any)."""

    path: Path
    recorded: str
    offline: OfflineAnswer | None
    pred_t: list[float]
    pred_label: list[str]
    saved: Path | None
    events: list[ContactEvent] | None = None
    agreement: dict | None = None
    """The residual's agreement with the robot's own estimate
    (:class:`~contactkit.features.agreement.ResidualAgreement`), where recorded."""
    contact_span: tuple[float, float] | None = None
    """The first and last time [s] of the recorded (labelled or simulated) contact, None
    where the session records none."""

    def line(self) -> str:
        """Return a one-line summary for a terminal: the contact events first (the answer),
        then the offline window answer, then the per-hop online labels as a diagnostic."""
        contact = [(t, label) for t, label in zip(self.pred_t, self.pred_label, strict=True)
                   if label != "none"]
        online = (f"first contact hop {contact[0][1]} at {contact[0][0]:.2f} s"
                  if contact else "none throughout")
        if self.offline is None:
            offline = "no planned time (no offline answer)"
        else:
            window = self.offline.window
            found = "detected" if window.found else "planned"
            offline = (f"predicted {self.offline.label} (offline, {found} window "
                       f"{window.start_s:.2f}-{window.end_s:.2f} s)")
        agreement = "" if self.agreement is None else (
            "; residual vs robot estimate: correlation "
            + " ".join("-" if c is None else f"{c:.2f}" for c in self.agreement["correlation"])
            + ", RMS difference max "
            + f"{max(v for v in self.agreement['rms_difference_nm'] if v is not None):.2f} Nm")
        return (f"{self.path.name}: recorded {self.recorded}, {self.events_text()}; {offline}"
                f" (per-hop diagnostic: {online}, {len(self.pred_t)} online predictions)"
                f"{agreement}")

    def events_text(self) -> str:
        """Return the contact events as words: ``1 contact event: adjust at 5.32 s``
        (the first five listed), ``no contact event``, or ``no event pipeline``."""
        if self.events is None:
            return "no event pipeline"
        if not self.events:
            return "no contact event"
        count = len(self.events)
        listed = ", ".join(f"{e.label} at {e.onset_s:.2f} s" for e in self.events[:5])
        more = f", {count - 5} more" if count > 5 else ""
        return f"{count} contact event{'s' if count != 1 else ''}: {listed}{more}"


ExtraProperties = Callable[[ReplayStream, ReplaySummary], Mapping[str, Mapping[str, Any]]]
"""Returns more recording properties of a replayed session, group: {name: value}; a value
may be a pyarrow array (a typed list, which may hold nulls)."""


def session_inputs(inputs: Sequence[Path]) -> list[Path]:
    """Return the session files of files and directories, in order; raise InputError if
    there are none."""
    paths: list[Path] = []
    for source in inputs:
        paths += session_files(source) if Path(source).is_dir() else [Path(source)]
    if not paths:
        raise InputError("no session files given")
    return paths


def replay_session(path: Path, model: ModelFile, *, save: Path | None = None,
                   connect: str | None = None, spawn: bool = False, rate: float | None = None,
                   hop_s: float = DEFAULT_HOP_S, detector: DetectorConfig | None = None,
                   decide_after_s: float | None = None,
                   log_rate_hz: float | None = None, robot: RobotChoice = None,
                   overwrite: bool = False, owned: Owned | None = None,
                   session_file: str | None = None,
                   properties: ExtraProperties | None = None) -> ReplaySummary:
    """Replay one session into its own recording; return its summary.

    The session is read, computed and logged batch by batch, so memory stays bounded
    however long it is. The recording goes to the .rrd file ``save``, to the viewer at
    gRPC URL ``connect`` or a spawned native viewer (``spawn``). ``rate`` is the
    multiple of wall-clock speed (None: as fast as possible, logged a batch at a time);
    ``hop_s`` [s] is the time between online predictions. ``log_rate_hz`` [Hz] thins
    the series sent to Rerun (None: every sample; the chain, the events and the
    predictions still see every sample). ``detector`` overrides the model's contact
    detector settings and ``decide_after_s`` [s] its decision delay; ``robot`` names the
    arm's model instead of the session's own, or carries its identified dynamics
    (:class:`~contactkit.robots.dynamics.ArmOverride`). The session's
    metadata and the model are checked before any file is created, and a replay that
    fails (also on a bad row found late in the file) leaves no file: the recording is
    written to a temporary file and renamed at the end. An existing ``save`` is replaced
    only with ``overwrite``, or when ``owned`` recognises it as contactkit's own.
    ``session_file`` is the file as the recording's ``session`` properties name it
    (default: ``path`` as given). ``properties`` is called once the session has streamed,
    with its summary, and returns more recording properties (group: values), logged
    before the recording is closed (see :mod:`contactkit.replay.catalog`).
    """
    if rate is not None and rate <= 0:
        raise InputError(f"the replay rate must be positive, got {rate}")
    if log_rate_hz is not None and not log_rate_hz > 0:
        raise InputError(f"the log rate must be positive, got {log_rate_hz} Hz")
    stream = ReplayStream(Path(path), model, hop_s, detector, decide_after_s, robot=robot)
    t0, t_end = stream.time_span()
    rec = new_recording(Path(path).stem, stream.meta.session_id)
    blueprint = layout.replay_blueprint(t_end)
    with ExitStack() as stack:
        if save is not None:
            tmp = stack.enter_context(atomic_write(save, overwrite=overwrite, owned=owned,
                                                   suffix=".rrd"))
            start_recording(rec, tmp.path, save, blueprint)
        try:
            if connect is not None:
                rec.connect_grpc(connect, default_blueprint=blueprint)
            elif spawn:
                rec.spawn(default_blueprint=blueprint)
            logger = BlockLogger(rec, log_static(rec, stream, session_file), stream,
                                 log_rate_hz)
            for block in paced(stream.blocks(every_hop=rate is not None), lambda b: b.t[-1],
                               rate, origin_s=t0):
                if save is not None:
                    check_space(save)
                logger.log(block)
            logger.finish()
            answer = stream.offline()
            log_results(rec, stream, answer)
            summary = ReplaySummary(Path(path), stream.meta.action, answer,
                                    stream.pred_t.tolist(), stream.pred_label, save,
                                    None if stream.pipeline is None else stream.events,
                                    stream.agreement.result(), logger.contact_span)
            if properties is not None:
                for group, values in properties(stream, summary).items():
                    rec.send_property(group, rr.AnyValues(**values))
            if save is not None:
                finish_recording(rec, tmp.path, save)
            else:
                rec.flush()
        finally:
            rec.disconnect()
    return summary


def replay_sessions(paths: Sequence[Path], model: ModelFile, *, save: Path | None = None,
                    connect: str | None = None, spawn: bool = False,
                    rate: float | None = None, hop_s: float = DEFAULT_HOP_S,
                    detector: DetectorConfig | None = None,
                    decide_after_s: float | None = None, log_rate_hz: float | None = None,
                    robot: RobotChoice = None, overwrite: bool = False,
                    owned: Owned | None = None,
                    on_done: Callable[[ReplaySummary | InputError], None] | None = None
                    ) -> tuple[list[ReplaySummary], list[InputError]]:
    """Replay each session into its own recording (with several sessions and ``save``,
    one file each, see :func:`contactkit.replay.recording.save_paths_for`); return the
    summaries and the sessions refused, which do not stop the others. ``detector``,
    ``decide_after_s``, ``log_rate_hz``, ``robot``, ``overwrite`` and ``owned`` are as
    for :func:`replay_session`. ``on_done`` is called after each session with its
    summary or its error. Two sessions that would be saved under one name (equal file
    names in different directories) raise InputError before any is replayed."""
    targets = [None] * len(paths) if save is None else save_paths_for(save, paths)
    summaries: list[ReplaySummary] = []
    problems: list[InputError] = []
    result: ReplaySummary | InputError
    for path, target in zip(paths, targets, strict=True):
        try:
            result = replay_session(path, model, save=target, connect=connect, spawn=spawn,
                                    rate=rate, hop_s=hop_s, detector=detector,
                                    decide_after_s=decide_after_s,
                                    log_rate_hz=log_rate_hz, robot=robot,
                                    overwrite=overwrite, owned=owned)
            summaries.append(result)
        except DATA_ERRORS as err:  # one bad session never stops the others
            result = err if isinstance(err, InputError) else InputError(problem_text(err),
                                                                        path)
            problems.append(result)
        if on_done is not None:
            on_done(result)
    return summaries, problems
