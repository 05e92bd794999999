"""Capturing one session: a source's stream, the operator cue, the crash-safe writer."""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from contactkit.features.dynamics import urdf_sha256
from contactkit.recorder.journal import SessionWriter
from contactkit.recorder.protocol import check_action, check_condition, pose_q
from contactkit.recorder.sim import SessionSpec, SimConfig
from contactkit.recorder.sources.base import Source
from contactkit.schemas import InputError, SessionMeta, new_session_id
from contactkit.util.paths import safe_name

ChunkCallback = Callable[[dict[str, np.ndarray]], None]


def tool_version() -> str:
    """Return the installed contactkit version."""
    try:
        return importlib.metadata.version("contactkit")
    except importlib.metadata.PackageNotFoundError:
        return "0+unknown"


def utc_now() -> str:
    """Return the current UTC time in ISO 8601 with a Z suffix."""
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def sim_session_id(spec: SessionSpec, config: SimConfig) -> str:
    """Return a session id determined by the spec and configuration (same seed, same id)."""
    doc = json.dumps({"spec": spec.as_dict(), "config": config.to_dict()}, sort_keys=True)
    return hashlib.sha256(doc.encode()).hexdigest()[:16]


def sim_session_meta(spec: SessionSpec, config: SimConfig, source_fields: dict) -> SessionMeta:
    """Return the metadata of a simulated session."""
    return SessionMeta(
        session_id=sim_session_id(spec, config),
        action=spec.action,
        condition=spec.condition,
        pose=spec.pose,
        pose_q=list(spec.q_start),
        target_pose=spec.target_pose,
        target_q=None if spec.q_target is None else list(spec.q_target),
        speed_rad_s=spec.speed_rad_s,
        link=spec.link,
        planned_at_s=spec.planned_at_s,
        nominal_rate_hz=config.rate_hz,
        operator=spec.operator,
        created_utc=utc_now(),
        with_hand=config.with_hand,
        urdf_sha256=urdf_sha256(config.with_hand),
        tool_version=tool_version(),
        **source_fields,
    )


def protocol_meta(*, source: str, action: str, condition: str, pose: str | None,
                  target_pose: str | None, speed_rad_s: float | None, link: int | None,
                  planned_at_s: float | None, operator: str, with_hand: bool,
                  notes: str = "") -> SessionMeta:
    """Return the metadata of a session recorded from a robot, bus or log (not simulated):
    the protocol's choices, checked, with the pose's joint values from Table 3.1."""
    check_action(action)
    check_condition(condition)
    if link is not None and not 1 <= link <= 7:
        raise InputError(f"unknown link {link} (expected 1..7)")
    return SessionMeta(
        session_id=new_session_id(), source=source, action=action, condition=condition,
        pose=None if pose is None else pose.upper(),
        pose_q=None if pose is None else pose_q(pose).tolist(),
        target_pose=None if target_pose is None else target_pose.upper(),
        target_q=None if target_pose is None else pose_q(target_pose).tolist(),
        speed_rad_s=speed_rad_s, link=link, planned_at_s=planned_at_s, operator=operator,
        notes=notes, created_utc=utc_now(), with_hand=with_hand,
        urdf_sha256=urdf_sha256(with_hand), tool_version=tool_version())


def session_filename(meta: SessionMeta) -> str:
    """Return the file name of a session: condition, pose(s), action and short id.

    The metadata is checked first, so every part is within its domain; the name is a
    safe file-name component (raises :class:`InputError` otherwise).
    """
    meta.check()
    poses = meta.pose or "x"
    if meta.target_pose:
        poses += "to" + meta.target_pose
    return safe_name(f"{meta.condition}_{poses}_{meta.action}_{meta.session_id[:12]}.parquet",
                     "session file name")


class OperatorCue:
    """Counts down to the planned interaction time on the terminal, then rings the bell."""

    def __init__(self, planned_at_s: float, action: str, link: int | None,
                 stream=sys.stderr, countdown_s: int = 3,
                 echo: Callable[[float, str], None] | None = None) -> None:
        self.planned_at_s = planned_at_s
        self.what = action + (f" link {link}" if link else "")
        self.stream = stream
        self.marks = [planned_at_s - k for k in range(countdown_s, 0, -1)]
        self.started = False
        self.done = False
        self.echo = echo

    def _say(self, t: float, text: str, bell: bool = False) -> None:
        print(("\a" if bell else "") + "  " + text, file=self.stream, flush=True)
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


@dataclass
class CaptureResult:
    """The written session path and how many samples it holds."""

    path: Path
    samples: int


def capture(source: Source, meta: SessionMeta, out_path: Path, *, realtime: bool = False,
            cue: OperatorCue | None = None, on_chunk: list[ChunkCallback] | None = None,
            flush_interval_s: float = 0.1) -> CaptureResult:
    """Record ``source`` into ``out_path`` through the journal; return the result.

    With ``realtime`` (or a live source) each chunk is handed on when the wall clock
    reaches its last time stamp, as with a live robot; otherwise as fast as possible.
    ``on_chunk`` callbacks (for example a Rerun logger) see every chunk. If the
    capture is interrupted, the journal stays for ``recorder recover``.
    """
    pace = realtime and not source.live
    with SessionWriter(out_path, meta, source.columns, flush_interval_s) as writer:
        start = time.monotonic()
        for chunk in source.stream():
            if pace:
                delay = start + float(chunk["t"][-1]) - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            writer.append(chunk)
            for callback in on_chunk or ():
                callback(chunk)
            if cue is not None:
                cue.update(float(chunk["t"][-1]))
        for key, value in source.metadata().items():
            setattr(writer.meta, key, value)
        path = writer.close()
    return CaptureResult(path=path, samples=writer.samples_written)
