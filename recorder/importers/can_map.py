"""CAN frame maps: how a bus carries one sample of the arm (a small TOML file).

A map names the SYNC id that closes a sample, whether frames are CAN FD, a list of
PDOs (``base_id`` + node id, payload length, signals) and the joints (node id and
scale factors). A signal is ``quantity`` (q, dq or tau), ``start`` byte, ``type``
(int8/16/32, uint8/16/32, float32), optional ``byte_order`` (little, default, or
big) and its scaling: value = raw x factor x joint[multiply_by] / joint[divide_by]
in rad, rad/s or Nm. The default map (``recorder/data/can_default_map.toml``)
documents CANopen CiA 402 and its quantisation; another arm needs only another map.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from contactkit.recorder.importers.map_file import (
    boolean,
    integer,
    known_keys,
    load_map_file,
    number,
    one_of,
)
from contactkit.robots import canonical_robot_name
from contactkit.schemas import N_JOINTS

TYPES = {"int8": "b", "uint8": "B", "int16": "h", "uint16": "H", "int32": "i", "uint32": "I",
         "float32": "f"}
QUANTITIES = ("q", "dq", "tau")
BYTE_ORDERS = {"little": "<", "big": ">"}


@dataclass(frozen=True)
class Signal:
    """One value in a frame: which quantity and joint, where, and its scale
    (engineering value = raw * scale)."""

    quantity: str
    joint: int
    codec: struct.Struct
    start: int
    scale: float
    integer: bool


@dataclass(frozen=True)
class FrameLayout:
    """One frame id: its payload length and signals."""

    can_id: int
    length: int
    signals: tuple[Signal, ...]


@dataclass(frozen=True)
class FrameMap:
    """A parsed frame map: SYNC id, CAN FD flag, frame layouts by id, and the arm the
    bus carries (``robot``, a registry name of :mod:`contactkit.robots`; None: not said)."""

    name: str
    sync_id: int
    fd: bool
    frames: dict[int, FrameLayout]
    source: str
    robot: str | None = None

    def describe(self) -> dict:
        """Return a JSON-ready description for session metadata."""
        return {"name": self.name, "sync_id": self.sync_id, "fd": self.fd,
                "frame_ids": sorted(self.frames), "source": self.source}


def default_map_path() -> Path:
    """Return the path of the default CiA 402 map."""
    return Path(str(resources.files("contactkit.recorder").joinpath("data/can_default_map.toml")))


def load_map(path: str | Path | None = None) -> FrameMap:
    """Parse and check a frame map (the default map when ``path`` is None); raise
    InputError naming the file and the problem."""
    return load_map_file(default_map_path() if path is None else Path(path), "frame map",
                         _parse)


MAX_CAN_ID = 0x1FFFFFFF
"""The largest CAN identifier (29 bits, extended frames)."""
SIGNAL_KEYS = ("quantity", "type", "start", "byte_order", "factor", "multiply_by", "divide_by")


def _parse(doc: dict, source: str) -> FrameMap:
    known_keys(doc, ("name", "fd", "sync_id", "joint", "pdo"), "the map")
    joints = {integer(j["node"], "joint node", 0, 127): (i + 1, j)
              for i, j in enumerate(doc["joint"])}
    if len(joints) != N_JOINTS:
        raise ValueError(f"needs {N_JOINTS} joints, found {len(joints)}")
    fd = boolean(doc.get("fd", False), "fd")
    sync_id = integer(doc["sync_id"], "sync_id", 0, MAX_CAN_ID)
    max_length = 64 if fd else 8
    frames: dict[int, FrameLayout] = {}
    covered = set()
    used = {"node"}
    for pdo in doc["pdo"]:
        known_keys(pdo, ("name", "base_id", "length", "signals"), "[[pdo]]")
        length = integer(pdo["length"], "PDO length")
        if not 0 < length <= max_length:
            raise ValueError(f"PDO {pdo.get('name')} length {length} exceeds {max_length}")
        for node, (joint, params) in joints.items():
            signals = []
            for sig in pdo["signals"]:
                known_keys(sig, SIGNAL_KEYS, "a signal")
                used.update(sig[k] for k in ("multiply_by", "divide_by") if k in sig)
                quantity = one_of(sig["quantity"], QUANTITIES, "quantity")
                order = one_of(sig.get("byte_order", "little"), BYTE_ORDERS, "byte_order")
                codec = struct.Struct(BYTE_ORDERS[order] + TYPES[one_of(sig["type"], TYPES,
                                                                        "type")])
                start = integer(sig["start"], "signal start")
                if start < 0 or start + codec.size > length:
                    raise ValueError(f"signal {quantity} does not fit in {length} bytes")
                scale = number(sig.get("factor", 1.0), "signal factor")
                if "multiply_by" in sig:
                    scale *= number(params[sig["multiply_by"]], sig["multiply_by"])
                if "divide_by" in sig:
                    scale /= number(params[sig["divide_by"]], sig["divide_by"])
                if not (math.isfinite(scale) and scale != 0):
                    raise ValueError(f"signal {quantity} of joint {joint} has scale {scale}")
                signals.append(Signal(quantity, joint, codec, start, scale,
                                      sig["type"] != "float32"))
                covered.add((quantity, joint))
            can_id = integer(pdo["base_id"], "PDO base_id", 0, MAX_CAN_ID) + node
            if can_id > MAX_CAN_ID:
                raise ValueError(f"frame id {can_id:#x} is beyond {MAX_CAN_ID:#x}")
            if can_id in frames or can_id == sync_id:
                raise ValueError(f"frame id {can_id:#x} used twice")
            frames[can_id] = FrameLayout(can_id, length, tuple(signals))
    for _, params in joints.values():
        known_keys(params, used, "[[joint]] (a parameter no signal uses)")
    missing = {(q, j) for q in QUANTITIES for j in range(1, N_JOINTS + 1)} - covered
    if missing:
        raise ValueError(f"no signal carries {sorted(missing)[0]}")
    robot = doc.get("robot")
    return FrameMap(doc.get("name", Path(source).stem), sync_id, fd, frames, source,
                    None if robot is None else canonical_robot_name(str(robot)))
