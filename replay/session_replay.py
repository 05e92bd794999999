"""Replaying sessions into Rerun recordings: the library behind the ``replay`` command.

:func:`replay_session` runs one session through :class:`ReplayStream` into its own
recording (saved to an .rrd file, sent to a viewer, or both), paced at a multiple of
wall-clock speed or as fast as possible, and returns a :class:`ReplaySummary`. A
session that is refused (unreadable, or not usable by the model) leaves no file
behind; a recording file exists only when it was written completely.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from contactkit.classify.events import ContactEvent
from contactkit.classify.modelfile import ModelFile, load_model
from contactkit.features.detector import DetectorConfig
from contactkit.replay.default_model import build_default_model, default_model_path
from contactkit.replay.engine import DEFAULT_HOP_S, Block, OfflineAnswer, ReplayStream
from contactkit.replay.recording import (
    log_block,
    log_contact_events,
    log_offline,
    log_static,
    new_recording,
    save_path_for,
)
from contactkit.schemas import InputError, read_session
from contactkit.schemas import rerun_layout as layout
from contactkit.schemas.dataset import session_files
from contactkit.util.pacing import paced
from contactkit.util.progress import LabelledProgress


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

    def line(self) -> str:
        """Return a one-line summary for a terminal."""
        contact = [(t, label) for t, label in zip(self.pred_t, self.pred_label, strict=True)
                   if label != "none"]
        online = (f"first online contact: {contact[0][1]} at {contact[0][0]:.2f} s"
                  if contact else "online: none throughout")
        if self.offline is None:
            offline = "no planned time (no offline answer)"
        else:
            window = self.offline.window
            found = "detected" if window.found else "planned"
            offline = (f"predicted {self.offline.label} (offline, {found} window "
                       f"{window.start_s:.2f}-{window.end_s:.2f} s)")
        events = "" if self.events is None else (
            f"; {len(self.events)} contact events"
            + "".join(f", {e.label} at {e.onset_s:.2f} s" for e in self.events[:5]))
        return (f"{self.path.name}: recorded {self.recorded}, {offline}; {online}; "
                f"{len(self.pred_t)} online predictions{events}")


def session_inputs(inputs: Sequence[Path]) -> list[Path]:
    """Return the session files of files and directories, in order; raise InputError if
    there are none."""
    paths: list[Path] = []
    for source in inputs:
        paths += session_files(source) if Path(source).is_dir() else [Path(source)]
    if not paths:
        raise InputError("no session files given")
    return paths


def model_or_default(path: Path | None, progress: LabelledProgress | None = None
                     ) -> ModelFile:
    """Load the model file at ``path``, or the default model (built and cached on first
    use, see :mod:`contactkit.replay.default_model`)."""
    if path is not None:
        return load_model(path)
    return load_model(build_default_model(progress=progress))


def default_model_missing() -> bool:
    """Return whether the default model still has to be built (minutes, once)."""
    return not default_model_path().exists()


def _whole(stream: ReplayStream) -> Block:
    return Block(0, stream.session.n_samples, range(len(stream.pred_t)))


def replay_session(path: Path, model: ModelFile, *, save: Path | None = None,
                   connect: str | None = None, spawn: bool = False, rate: float | None = None,
                   hop_s: float = DEFAULT_HOP_S, detector: DetectorConfig | None = None,
                   decide_after_s: float | None = None) -> ReplaySummary:
    """Replay one session into its own recording; return its summary.

    The recording goes to the .rrd file ``save``, to the viewer at gRPC URL ``connect``
    or a spawned native viewer (``spawn``). ``rate`` is the multiple of wall-clock
    speed (None: as fast as possible, logged in one block); ``hop_s`` [s] is the time
    between online predictions. ``detector`` overrides the model's contact detector
    settings and ``decide_after_s`` [s] its decision delay. The session and model are
    checked before any file is created, and a replay that fails leaves no file.
    """
    if rate is not None and rate <= 0:
        raise InputError(f"the replay rate must be positive, got {rate}")
    session = read_session(path)
    stream = ReplayStream(session, model, hop_s, detector, decide_after_s)
    rec = new_recording(Path(path).stem, session.meta.session_id)
    blueprint = layout.replay_blueprint(float(session.t[-1]))
    if save is not None:
        rec.save(save, default_blueprint=blueprint)
    try:
        if connect is not None:
            rec.connect_grpc(connect, default_blueprint=blueprint)
        elif spawn:
            rec.spawn(default_blueprint=blueprint)
        tree = log_static(rec, stream)
        times = stream.session.t
        for block in paced(stream.blocks(), lambda b: times[b.stop - 1], rate,
                           origin_s=float(times[0])):
            if rate is not None:
                log_block(rec, tree, stream, block)
        if rate is None:
            log_block(rec, tree, stream, _whole(stream))
        if stream.pipeline is not None:
            log_contact_events(rec, stream.t, stream.events, {
                f"joint {j} at rest": v for j, v in enumerate(stream.detector.noise, 1)})
        answer = stream.offline()
        if answer is not None:
            log_offline(rec, stream, answer)
        rec.flush()
    except BaseException:
        rec.disconnect()
        if save is not None:
            Path(save).unlink(missing_ok=True)
        raise
    rec.disconnect()
    return ReplaySummary(Path(path), session.meta.action, answer, list(stream.pred_t),
                         list(stream.pred_label), save,
                         None if stream.pipeline is None else stream.events)


def replay_sessions(paths: Sequence[Path], model: ModelFile, *, save: Path | None = None,
                    connect: str | None = None, spawn: bool = False,
                    rate: float | None = None, hop_s: float = DEFAULT_HOP_S,
                    detector: DetectorConfig | None = None,
                    decide_after_s: float | None = None,
                    on_done: Callable[[ReplaySummary | InputError], None] | None = None
                    ) -> tuple[list[ReplaySummary], list[InputError]]:
    """Replay each session into its own recording (with several sessions and ``save``,
    one file each, see :func:`contactkit.replay.recording.save_path_for`); return the
    summaries and the sessions refused, which do not stop the others. ``detector`` and
    ``decide_after_s`` are as for :func:`replay_session`. ``on_done`` is
    called after each session with its summary or its error."""
    many = len(paths) > 1
    summaries, problems = [], []
    for path in paths:
        target = None if save is None else save_path_for(save, Path(path), many)
        try:
            result = replay_session(path, model, save=target, connect=connect, spawn=spawn,
                                    rate=rate, hop_s=hop_s, detector=detector,
                                    decide_after_s=decide_after_s)
            summaries.append(result)
        except InputError as err:
            result = err
            problems.append(err)
        if on_done is not None:
            on_done(result)
    return summaries, problems
