"""Samples to CAN frames and back, per a :class:`contactkit.recorder.importers.can_map.FrameMap`.

Encoding: for each sample the PDO frames of every joint, then a SYNC frame carrying
a CiA 301 counter (1..240) at the sample's time stamp; the PDOs go out 10 us apart
just before it.

Decoding (:class:`SampleAssembler`) treats faults as data, never as exceptions:

* a SYNC closes the sample being filled; its time stamp is the sample's time (from
  the first SYNC, in s). A value no frame delivered stays NaN and the sample counts
  as incomplete; a jump in the SYNC counter counts the samples whose SYNC was lost;
* a frame whose id is in no PDO counts as an unknown id, one shorter than its layout
  as a bad length, an error frame as a bus error; all are otherwise ignored;
* a second frame for values already filled is a duplicate (the newer frame wins);
  a PDO frame time-stamped before the last SYNC (out of order) fills the previous
  sample if that value is still missing there, else counts as a duplicate;
* a SYNC with the counter of the previous one is a duplicate and ignored.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from contactkit.recorder.importers.can_map import QUANTITIES, FrameMap
from contactkit.schemas import N_JOINTS, joint_columns

if TYPE_CHECKING:  # python-can is imported where frames are made: not for --help
    import can

FRAME_SPACING_S = 10e-6
SYNC_COUNTER_MAX = 240
COLUMNS = ["t", *[c for q in QUANTITIES for c in joint_columns(q)]]
SLOT = {(q, j): 1 + QUANTITIES.index(q) * N_JOINTS + (j - 1)
        for q in QUANTITIES for j in range(1, N_JOINTS + 1)}


def _raw_limits(signal) -> tuple[float, float]:
    if not signal.integer:
        return -np.inf, np.inf
    bits = signal.codec.size * 8
    signed = signal.codec.format[-1].islower()
    return (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1) if signed else (0, 2**bits - 1)


def sample_frames(fmap: FrameMap, t: float, values: np.ndarray, counter: int | None
                  ) -> list[can.Message]:
    """Return the frames of one sample: ``values`` holds q, dq, tau (21 values, joint
    order) in rad, rad/s, Nm; NaN values leave their frame out."""
    import can

    frames = []
    layouts = sorted(fmap.frames.values(), key=lambda f: f.can_id)
    for i, layout in enumerate(layouts):
        payload = bytearray(layout.length)
        complete = True
        for signal in layout.signals:
            value = values[SLOT[(signal.quantity, signal.joint)] - 1]
            if not np.isfinite(value):
                complete = False
                break
            raw = value / signal.scale
            if signal.integer:
                lo, hi = _raw_limits(signal)
                raw = int(np.clip(np.rint(raw), lo, hi))
            signal.codec.pack_into(payload, signal.start, raw)
        if complete:
            frames.append(can.Message(
                timestamp=t - (len(layouts) - i) * FRAME_SPACING_S, arbitration_id=layout.can_id,
                is_extended_id=False, data=bytes(payload), is_fd=fmap.fd))
    sync = b"" if counter is None else bytes([counter])
    frames.append(can.Message(timestamp=t, arbitration_id=fmap.sync_id, is_extended_id=False,
                              data=sync, is_fd=fmap.fd))
    return frames


def session_frames(fmap: FrameMap, t: np.ndarray, values: np.ndarray, t_start: float = 0.0
                   ) -> Iterator[can.Message]:
    """Yield every frame of a session, time-stamped ``t_start + t`` [s]; ``values`` is
    (N, 21): q, dq, tau per joint."""
    for k in range(len(t)):
        yield from sample_frames(fmap, t_start + float(t[k]), values[k],
                                 (k % SYNC_COUNTER_MAX) + 1)


@dataclass
class BusStatistics:
    """Counts of what the bus delivered (stored in the session metadata)."""

    frames: int = 0
    samples: int = 0
    unknown_ids: int = 0
    bad_lengths: int = 0
    bus_errors: int = 0
    duplicates: int = 0
    out_of_order: int = 0
    incomplete_samples: int = 0
    lost_syncs: int = 0

    def as_dict(self) -> dict:
        """Return the counts as a plain dict."""
        return asdict(self)


class SampleAssembler:
    """Turns frames (in arrival order) into samples; see the module docstring."""

    def __init__(self, fmap: FrameMap) -> None:
        self.fmap = fmap
        self.stats = BusStatistics()
        self._current = np.full(1 + 3 * N_JOINTS, np.nan)
        self._pending: np.ndarray | None = None
        self._t0: float | None = None
        self._last_sync_time: float | None = None
        self._last_counter: int | None = None

    def feed(self, msg: can.Message) -> list[np.ndarray]:
        """Take one frame; return the samples it completes (rows: t, q, dq, tau)."""
        self.stats.frames += 1
        if msg.is_error_frame:
            self.stats.bus_errors += 1
            return []
        if msg.is_remote_frame:
            return []
        if msg.arbitration_id == self.fmap.sync_id:
            return self._sync(msg)
        layout = self.fmap.frames.get(msg.arbitration_id)
        if layout is None:
            self.stats.unknown_ids += 1
            return []
        if len(msg.data) < layout.length:
            self.stats.bad_lengths += 1
            return []
        late = self._last_sync_time is not None and msg.timestamp < self._last_sync_time
        target = self._pending if late else self._current
        if late:
            self.stats.out_of_order += 1
        slots = [SLOT[(signal.quantity, signal.joint)] for signal in layout.signals]
        if target is None:
            self.stats.duplicates += 1
            return []
        filled = any(not np.isnan(target[slot]) for slot in slots)
        if filled:
            self.stats.duplicates += 1
            if late:
                return []
        for signal, slot in zip(layout.signals, slots, strict=True):
            (raw,) = signal.codec.unpack_from(msg.data, signal.start)
            target[slot] = raw * signal.scale
        return []

    def _sync(self, msg: can.Message) -> list[np.ndarray]:
        counter = msg.data[0] if len(msg.data) else None
        if counter is not None and counter == self._last_counter:
            self.stats.duplicates += 1
            return []
        if self._last_sync_time is not None and msg.timestamp <= self._last_sync_time:
            self.stats.out_of_order += 1
            return []
        if counter is not None and self._last_counter is not None:
            self.stats.lost_syncs += (counter - self._last_counter - 1) % SYNC_COUNTER_MAX
        self._last_counter = counter
        if self._t0 is None:
            self._t0 = msg.timestamp
        self._last_sync_time = msg.timestamp
        self._current[0] = msg.timestamp - self._t0
        done = [] if self._pending is None else [self._emit(self._pending)]
        self._pending = self._current
        self._current = np.full(1 + 3 * N_JOINTS, np.nan)
        return done

    def _emit(self, row: np.ndarray) -> np.ndarray:
        self.stats.samples += 1
        if np.isnan(row[1:]).any():
            self.stats.incomplete_samples += 1
        return row

    def finish(self) -> list[np.ndarray]:
        """Return the last closed sample (values after the last SYNC are dropped)."""
        done = [] if self._pending is None else [self._emit(self._pending)]
        self._pending = None
        return done


def rows_to_columns(rows: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Stack sample rows into session columns."""
    block = np.array(rows).reshape(-1, len(COLUMNS))
    return {name: np.ascontiguousarray(block[:, i]) for i, name in enumerate(COLUMNS)}


def session_values(q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Return the (N, 21) value rows of a session: q, dq, tau for joints 1..7."""
    return np.hstack([q, dq, tau])
