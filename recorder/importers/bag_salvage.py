"""Reading what is left of a bag whose end is missing (a recorder that crashed or ran
out of disk): ROS 1 ``.bag`` and MCAP files, scanned record by record from the start.

rosbags opens a bag through the index at its end; a truncated bag has none. This
reader walks the records in file order instead (the formats are documented at
wiki.ros.org/Bags/Format/2.0 and mcap.dev/spec), keeps every complete message, and
says at which byte the file stopped making sense. It offers the few parts of the
rosbags reader interface that :mod:`contactkit.recorder.importers.bags` uses.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROS1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass
class SalvagedConnection:
    """A topic found while scanning: its id in the file, name, type and definition."""

    id: int
    topic: str
    msgtype: str
    msgdef: str
    msgcount: int = 0


def _ros1_fields(block: bytes) -> dict[str, bytes]:
    fields, pos = {}, 0
    while pos + 4 <= len(block):
        (size,) = struct.unpack_from("<I", block, pos)
        name, _, value = block[pos + 4:pos + 4 + size].partition(b"=")
        fields[name.decode()] = value
        pos += 4 + size
    return fields


def _ros2_name(msgtype: str) -> str:
    package, _, name = msgtype.rpartition("/")
    return msgtype if "/msg/" in msgtype else f"{package}/msg/{name}"


class SalvageReader:
    """Messages of a truncated ROS 1 or MCAP bag, in file order (rosbags-like interface:
    ``connections``, ``messages()``, ``deserialize()``, ``close()``)."""

    def __init__(self, path: Path, typestore: Any) -> None:
        self.path = path
        self.data = path.read_bytes()
        self.ros1 = self.data.startswith(ROS1_MAGIC)
        if not self.ros1 and not self.data.startswith(MCAP_MAGIC):
            raise ValueError("neither a ROS 1 bag nor an MCAP file")
        self.typestore = typestore
        self.stopped_at: int | None = None
        self.by_id: dict[int, SalvagedConnection] = {}
        self.messages_found: list[tuple[int, int, bytes]] = []
        self._scan()
        self.connections = list(self.by_id.values())
        self._register_definitions()

    def _scan(self) -> None:
        try:
            if self.ros1:
                self._scan_ros1(self.data, len(ROS1_MAGIC))
            else:
                self._scan_mcap(self.data, len(MCAP_MAGIC))
        except (struct.error, ValueError, KeyError, OSError, EOFError) as err:
            if self.stopped_at is None:
                self.stopped_at = len(self.data)
            self.error = str(err)

    def _stop(self, pos: int) -> None:
        if self.stopped_at is None:
            self.stopped_at = pos

    def _scan_ros1(self, data: bytes, pos: int, offset: int = 0) -> None:
        """Scan records from ``pos``; ``offset`` is where ``data`` starts in the file."""
        while pos < len(data):
            if pos + 4 > len(data):
                return self._stop(offset + pos)
            (header_len,) = struct.unpack_from("<I", data, pos)
            header_end = pos + 4 + header_len
            if header_end + 4 > len(data):
                return self._stop(offset + pos)
            header = _ros1_fields(data[pos + 4:header_end])
            (data_len,) = struct.unpack_from("<I", data, header_end)
            body = data[header_end + 4:header_end + 4 + data_len]
            op = header.get("op", b"\0")[0]
            if op == 0x05:  # chunk: scan the records inside, even a cut one if uncompressed
                compression = header["compression"].decode()
                if compression == "none":
                    self._scan_ros1(body, 0, offset + header_end + 4)
                elif len(body) == data_len:
                    raw = bz2.decompress(body) if compression == "bz2" else _lz4(body)
                    self._scan_ros1(raw, 0, offset + pos)
            elif len(body) < data_len:
                return self._stop(offset + pos)
            elif op == 0x07:  # connection
                conn = struct.unpack("<I", header["conn"])[0]
                fields = _ros1_fields(body)
                self.by_id.setdefault(conn, SalvagedConnection(
                    conn, header["topic"].decode(), _ros2_name(fields["type"].decode()),
                    fields.get("message_definition", b"").decode()))
            elif op == 0x02:  # message data
                conn = struct.unpack("<I", header["conn"])[0]
                sec, nsec = struct.unpack("<II", header["time"])
                self.messages_found.append((conn, sec * 1_000_000_000 + nsec, body))
            if len(body) < data_len:
                return self._stop(offset + pos)
            pos = header_end + 4 + data_len
        return None

    def _scan_mcap(self, data: bytes, pos: int) -> None:
        schemas: dict[int, tuple[str, str]] = {}
        while pos < len(data):
            if pos + 9 > len(data):
                return self._stop(pos)
            op, length = struct.unpack_from("<BQ", data, pos)
            body = data[pos + 9:pos + 9 + length]
            if len(body) < length or op == 0x0F:  # cut short, or DataEnd
                return self._stop(pos) if len(body) < length else None
            self._mcap_record(op, body, schemas)
            pos += 9 + length
        return None

    def _mcap_record(self, op: int, body: bytes, schemas: dict[int, tuple[str, str]]) -> None:
        if op == 0x03:  # schema
            (schema_id,) = struct.unpack_from("<H", body, 0)
            name, at = _mcap_string(body, 2)
            _, at = _mcap_string(body, at)
            text, _ = _mcap_string(body, at)
            schemas[schema_id] = (name, text)
        elif op == 0x04:  # channel
            channel_id, schema_id = struct.unpack_from("<HH", body, 0)
            topic, _ = _mcap_string(body, 4)
            name, text = schemas.get(schema_id, ("", ""))
            self.by_id.setdefault(channel_id, SalvagedConnection(channel_id, topic, name, text))
        elif op == 0x05:  # message
            channel_id, _, log_time, _ = struct.unpack_from("<HIQQ", body, 0)
            self.messages_found.append((channel_id, log_time, body[22:]))
        elif op == 0x06:  # chunk
            from rosbags.rosbag2.storage_mcap import DECOMPRESSORS

            _, _, size, _ = struct.unpack_from("<QQQI", body, 0)
            compression, at = _mcap_string(body, 28)
            (records_len,) = struct.unpack_from("<Q", body, at)
            records = DECOMPRESSORS[compression](body[at + 8:at + 8 + records_len], size)
            pos = 0
            while pos + 9 <= len(records):
                inner_op, length = struct.unpack_from("<BQ", records, pos)
                self._mcap_record(inner_op, records[pos + 9:pos + 9 + length], schemas)
                pos += 9 + length

    def _register_definitions(self) -> None:
        from rosbags.typesys import get_types_from_msg

        for conn in self.connections:
            if conn.msgtype not in self.typestore.types and conn.msgdef:
                try:
                    self.typestore.register(get_types_from_msg(conn.msgdef, conn.msgtype))
                except Exception:  # an unparsable definition: that type stays unknown
                    continue

    def messages(self, connections: list[SalvagedConnection]
                 ) -> Iterator[tuple[SalvagedConnection, int, bytes]]:
        """Yield ``(connection, recording time [ns], raw message)`` in file order."""
        wanted = {c.id: c for c in connections}
        for conn_id, stamp, raw in self.messages_found:
            if conn_id in wanted:
                yield wanted[conn_id], stamp, raw

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        """Return the message decoded with the bag's or the bundled definition."""
        if self.ros1:
            return self.typestore.deserialize_ros1(raw, msgtype)
        return self.typestore.deserialize_cdr(raw, msgtype)

    def lost(self) -> str | None:
        """Return where the readable part ends, or None when the whole file was read."""
        if self.stopped_at is None:
            return None
        return (f"the file ends inside a record at byte {self.stopped_at} of "
                f"{len(self.data)}; the {len(self.data) - self.stopped_at} bytes after "
                "it are lost")

    def close(self) -> None:
        """Release the file's bytes."""
        self.data = b""


def _mcap_string(body: bytes, at: int) -> tuple[str, int]:
    (size,) = struct.unpack_from("<I", body, at)
    return body[at + 4:at + 4 + size].decode(), at + 4 + size


def _lz4(body: bytes) -> bytes:
    import lz4.frame

    return lz4.frame.decompress(body)
