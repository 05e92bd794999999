"""Capturing one session: a source's stream, the operator cue, the crash-safe writer."""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Protocol

import numpy as np

from contactkit.recorder.capture.journal import SessionWriter
from contactkit.recorder.metadata import session_filename
from contactkit.recorder.sources.base import Source
from contactkit.robots import get_robot
from contactkit.schemas import SessionMeta, joint_columns
from contactkit.util.atomic import output_directory
from contactkit.util.pacing import paced

if TYPE_CHECKING:
    from contactkit.features.agreement import StreamAgreement

ChunkCallback = Callable[[dict[str, np.ndarray]], None]


class CaptureListener(Protocol):
    """Something that follows a capture as it is recorded (a live event pipeline, for
    example) and leaves results in the session's metadata."""

    def on_chunk(self, chunk: dict[str, np.ndarray]) -> None:
        """Take one chunk of rows (column name -> array, ``t`` in s) as it is recorded."""

    def session_fields(self) -> dict[str, Any]:
        """Return the metadata fields to store with the session when the capture closes."""


class OperatorCue:
    """Counts down to the planned interaction time on the terminal, then rings the bell.
    ``stream`` is where it prints (None: whatever ``sys.stderr`` is when it prints)."""

    def __init__(self, planned_at_s: float, action: str, link: int | None,
                 stream: IO[str] | None = None, countdown_s: int = 3,
                 echo: Callable[[float, str], None] | None = None) -> None:
        self.planned_at_s = planned_at_s
        self.what = action + (f" link {link}" if link else "")
        self.stream = stream
        self.marks = [planned_at_s - k for k in range(countdown_s, 0, -1)]
        self.started = False
        self.done = False
        self.echo = echo

    def _say(self, t: float, text: str, bell: bool = False) -> None:
        print(("\a" if bell else "") + "  " + text, file=self.stream or sys.stderr, flush=True)
        if self.echo is not None:
            self.echo(t, text)

    def update(self, t: float) -> None:
        """Print the countdown marks and the cue that session time ``t`` [s] has passed."""
        if not self.started:
            self.started = True
            self._say(t, "recording started")
        while self.marks and t >= self.marks[0]:
            left = round(self.planned_at_s - self.marks.pop(0))
            self._say(t, f"{self.what} in {left} ...")
        if not self.done and t >= self.planned_at_s:
            self.done = True
            self._say(t, f"NOW: {self.what.upper()}", bell=True)


class AgreementListener:
    """Measures the observer residual's agreement with the robot's own estimate while a
    capture records (:class:`contactkit.features.agreement.StreamAgreement`) and leaves
    it in the metadata's ``residual_agreement``. The arm's model is built before the
    stream starts (building it takes longer than a live robot waits), from the arm the
    source names then; if the source names another once its first chunk has arrived (a
    Franka robot's backend tells which arm), or the session's identified dynamics have
    changed then (the robot's load as their payload,
    :class:`~contactkit.recorder.capture.live_dynamics.LiveDynamics`), the model is built
    again. Chunks are
    gathered to ``BATCH_ROWS`` samples before the chain runs on them, so a live source
    loses at most a few states to it per second."""

    BATCH_ROWS = 1000

    def __init__(self, meta: SessionMeta, source: Source) -> None:
        self.meta, self.source = meta, source
        self.robot, self.dynamics = self._robot(), meta.dynamics
        self.stream = self._stream()
        self.first = True
        self.pending: list[dict[str, np.ndarray]] = []

    def _robot(self) -> str:
        return self.source.metadata().get("robot", self.meta.robot)

    def _stream(self) -> StreamAgreement:
        """Return a new agreement measure for the current arm. The chain (pinocchio) is
        imported here, not when the command line imports this module."""
        from contactkit.features.agreement import StreamAgreement

        return StreamAgreement(self.meta.with_robot(self.robot).robot_setup())

    def on_chunk(self, chunk: dict[str, np.ndarray]) -> None:
        """Take the next chunk of session columns."""
        if self.first and (self._robot(), self.meta.dynamics) != (self.robot, self.dynamics):
            self.robot, self.dynamics = self._robot(), self.meta.dynamics
            self.stream = self._stream()
        self.first = False
        self.pending.append(chunk)
        if sum(len(c["t"]) for c in self.pending) >= self.BATCH_ROWS:
            self._flush()

    def _flush(self) -> None:
        if self.pending:
            self.stream.add({name: np.concatenate([c[name] for c in self.pending])
                             for name in self.pending[0]})
            self.pending = []

    def session_fields(self) -> dict:
        """Return the ``residual_agreement`` metadata field."""
        self._flush()
        return {"residual_agreement": self.stream.result()}


@dataclass
class CaptureResult:
    """The written session path and how many samples it holds."""

    path: Path
    samples: int


def capture(source: Source, meta: SessionMeta, out_path: Path, *, realtime: bool = False,
            cue: OperatorCue | None = None, on_chunk: list[ChunkCallback] | None = None,
            listeners: list[CaptureListener] | None = None, overwrite: bool = False,
            flush_interval_s: float = 0.1) -> CaptureResult:
    """Record ``source`` into ``out_path`` through the journal; return the result.

    With ``realtime`` (or a live source) each chunk is handed on when the wall clock
    reaches its last time stamp, as with a live robot; otherwise as fast as possible.
    ``on_chunk`` callbacks (for example a Rerun logger) see every chunk, and so do
    ``listeners``, whose :meth:`CaptureListener.session_fields` go into the session
    metadata, written with the session (atomically). A source that records the robot's
    own estimate (``tau_ext_hat``) gets the residual's agreement with it measured as it
    goes (:class:`AgreementListener`). If the capture is interrupted,
    the journal stays for ``recorder recover`` (without the listeners' fields). An
    existing file at ``out_path`` is replaced only with ``overwrite`` (and only when the
    new session is complete).
    """
    rate = 1.0 if realtime and not source.live else None
    listeners = list(listeners or ())
    if all(c in source.columns for c in joint_columns("tau_ext_hat")):
        listeners.append(AgreementListener(meta, source))
    callbacks = list(on_chunk or ()) + [listener.on_chunk for listener in listeners]
    with SessionWriter(out_path, meta, source.columns, flush_interval_s,
                       overwrite=overwrite) as writer:
        for chunk in paced(source.stream(), lambda c: c["t"][-1], rate, origin_s=0.0):
            writer.append(chunk)
            for callback in callbacks:
                callback(chunk)
            if cue is not None:
                cue.update(float(chunk["t"][-1]))
        for key, value in source.metadata().items():
            setattr(writer.meta, key, value)
        # a source may name its arm only once connected (a Franka robot's backend)
        writer.meta.urdf_sha256 = get_robot(writer.meta.robot).urdf_sha256(
            writer.meta.with_hand)
        for listener in listeners:
            for key, value in listener.session_fields().items():
                setattr(writer.meta, key, value)
        path = writer.close()
    return CaptureResult(path=path, samples=writer.samples_written)


def record_session(source: Source, out_dir: Path, *, meta: SessionMeta | None = None,
                   **options) -> CaptureResult:
    """Record one session from ``source`` into ``out_dir`` (created if needed) under its
    standard file name; return the result. ``meta`` defaults to the source's
    :meth:`~contactkit.recorder.sources.Source.session_meta`; ``options`` are those of
    :func:`capture` (``realtime``, ``cue``, ``on_chunk``, ``listeners``, ``overwrite``)."""
    meta = meta or source.session_meta()
    return capture(source, meta, output_directory(Path(out_dir)) / session_filename(meta),
                   **options)
