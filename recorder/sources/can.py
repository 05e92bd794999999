"""A python-can bus as a capture source.

A ``can.Notifier`` thread fills a ``can.BufferedReader``; the stream assembles
samples (:class:`contactkit.recorder.importers.can_codec.SampleAssembler`) with time stamps from the
frames and hands them to the capture every 10 ms. The capture ends after
``duration_s`` of session time, or when the bus has been silent for ``timeout_s``
(a clear message is printed and what was recorded is kept). An optional cue frame
goes out when the session reaches the planned interaction time; its own echo on
the bus gives the cue's time on the bus clock.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from contactkit.recorder.importers.can_codec import COLUMNS, SampleAssembler, rows_to_columns
from contactkit.recorder.importers.can_map import FrameMap, load_map
from contactkit.recorder.sources.base import ProtocolChoices, Source
from contactkit.schemas import InputError

if TYPE_CHECKING:  # python-can is imported when a bus opens: not for capture --help
    import can

log = logging.getLogger(__name__)
CHUNK_S = 0.01


@dataclass(frozen=True)
class BusConfig:
    """Which bus to open: python-can interface name and channel."""

    interface: str
    channel: str

    def open(self, fd: bool, receive_own_messages: bool = False) -> can.BusABC:
        """Open the bus; raise InputError when python-can cannot."""
        import can

        try:
            return can.Bus(interface=self.interface, channel=self.channel, fd=fd,
                           receive_own_messages=receive_own_messages)
        except (can.CanError, ImportError, OSError, ValueError, NotImplementedError) as err:
            raise InputError(f"cannot open CAN interface {self.interface!r} channel "
                             f"{self.channel!r}: {err}") from err


@dataclass(frozen=True)
class Cue:
    """A frame to send at the planned interaction time (for a lamp or buzzer)."""

    can_id: int
    data: bytes
    planned_at_s: float


class CanSource(Source):
    """Samples from a live CAN bus, decoded with a frame map."""

    name = "can"
    columns = COLUMNS
    live = True

    @dataclass(frozen=True)
    class Config:
        """Options of a CAN bus source."""

        channel: str = field(metadata={"help": "Bus channel, e.g. can0."})
        interface: str = field(default="socketcan", metadata={
            "help": "python-can interface (virtual, socketcan, pcan, kvaser, ...)."})
        map_file: Path | None = field(default=None, metadata={
            "name": "map", "help": "Frame map TOML (default: CANopen CiA 402, "
                                   "recorder/data/can_default_map.toml)."})
        timeout: float = field(default=1.0, metadata={
            "help": "End the capture when the bus is silent this long.", "unit": "s"})
        cue_id: str | None = field(default=None, metadata={
            "help": "Send a cue frame with this id (e.g. 0x700) at the planned time, for a "
                    "lamp or buzzer; its bus time goes into the metadata."})
        cue_data: str = field(default="01", metadata={"help": "Cue frame payload, hex."})

    def __init__(self, bus: BusConfig, fmap: FrameMap, duration_s: float,
                 timeout_s: float = 1.0, cue: Cue | None = None,
                 first_frame_timeout_s: float = 30.0,
                 choices: ProtocolChoices | None = None) -> None:
        self.choices = choices or ProtocolChoices(action="none")
        self.planned_at_s = cue.planned_at_s if cue is not None else \
            self.choices.timing()[0]
        self.bus_config = bus
        self.fmap = fmap
        self.duration_s = duration_s
        self.timeout_s = timeout_s
        self.first_frame_timeout_s = first_frame_timeout_s
        self.cue = cue
        self.assembler = SampleAssembler(fmap)
        self.end_reason = ""
        self.cue_time_s: float | None = None

    @classmethod
    def from_config(cls, config: CanSource.Config, choices: ProtocolChoices) -> CanSource:
        """Return the bus source for options ``config``, ending at the session duration."""
        planned, duration = choices.timing()
        cue = None
        if config.cue_id is not None:
            try:
                cue = Cue(int(config.cue_id, 0), bytes.fromhex(config.cue_data), planned)
            except ValueError as err:
                raise InputError(f"bad cue frame id {config.cue_id!r} or payload "
                                 f"{config.cue_data!r} ({err})") from err
        return cls(BusConfig(config.interface, config.channel), load_map(config.map_file),
                   duration, config.timeout, cue, choices=choices)

    def stream(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield chunks of samples until the duration is reached or the bus goes silent."""
        import can

        bus = self.bus_config.open(self.fmap.fd, receive_own_messages=self.cue is not None)
        reader = can.BufferedReader()
        notifier = can.Notifier(bus, [reader], timeout=0.05)
        try:
            yield from self._read(bus, reader)
        finally:
            notifier.stop()
            bus.shutdown()

    def _read(self, bus: can.BusABC, reader: can.BufferedReader
              ) -> Iterator[dict[str, np.ndarray]]:
        import can

        rows: list[np.ndarray] = []
        last_frame = time.monotonic()
        last_yield = last_frame
        started = False
        t_first: float | None = None
        while True:
            msg = reader.get_message(timeout=0.01)
            now = time.monotonic()
            if msg is not None:
                last_frame = now
                started = True
                if self.cue is not None and msg.arbitration_id == self.cue.can_id and \
                        t_first is not None:
                    self.cue_time_s = msg.timestamp - t_first
                    continue
                if t_first is None and msg.arbitration_id == self.fmap.sync_id:
                    t_first = msg.timestamp
                rows += self.assembler.feed(msg)
            else:
                limit = self.timeout_s if started else self.first_frame_timeout_s
                if now - last_frame > limit:
                    self.end_reason = (f"bus silent for {limit:.1f} s: capture ended, "
                                       "everything received so far is kept")
                    log.warning(self.end_reason)
                    break
            if self.cue is not None and t_first is not None and self.cue_time_s is None and \
                    rows and rows[-1][0] >= self.cue.planned_at_s:
                bus.send(can.Message(arbitration_id=self.cue.can_id, data=self.cue.data,
                                     is_extended_id=False))
                self.cue_time_s = float("nan")
            if rows and rows[-1][0] >= self.duration_s:
                self.end_reason = f"reached the session duration ({self.duration_s} s)"
                break
            if rows and now - last_yield >= CHUNK_S:
                yield rows_to_columns(rows)
                rows = []
                last_yield = now
        rows += self.assembler.finish()
        if rows:
            yield rows_to_columns(rows)

    def metadata(self) -> dict[str, Any]:
        """Return source, bus statistics and map for the session metadata."""
        info = {"interface": self.bus_config.interface, "channel": self.bus_config.channel,
                "map": self.fmap.describe(), "end": self.end_reason,
                **self.assembler.stats.as_dict()}
        if self.cue is not None:
            info["cue_id"] = self.cue.can_id
            info["cue_bus_time_s"] = None if self.cue_time_s is None or \
                np.isnan(self.cue_time_s) else self.cue_time_s
        robot = {} if self.fmap.robot is None else {"robot": self.fmap.robot}
        return {"source": self.name, "source_info": info, **robot}
