"""One way to read a file named by input or by metadata: a URDF or mesh a session names,
a calibration, noise or map file, a model file, a dynamics file, a trajectory CSV.

A path inside a file is untrusted input: it may name a FIFO (whose reader waits for
ever), ``/dev/zero`` (endless), a device or a directory. :func:`open_input` refuses
anything but a regular file before opening it (``os.stat``), opens it without
blocking (``O_NONBLOCK``, so a FIFO swapped in after the check cannot hang the reader)
and checks the opened file again (``fstat``: still a regular file, the same one), and
bounds what is read: a file larger than its kind's limit (:data:`LIMITS`) is refused
before a byte is read. Every refusal is one :class:`~contactkit.errors.InputError`
naming the file.

:func:`read_json` parses JSON from such a file with bounded depth, size and number
length (Python's own ``json`` raises RecursionError on deep input and ValueError on
integers of over 4300 digits).
"""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from contactkit.errors import InputError

MiB = 1 << 20
LIMITS: dict[str, int] = {
    "urdf": 32 * MiB,
    "mesh": 32 * MiB,
    "json": 16 * MiB,
    "map": 1 * MiB,
    "model": 2048 * MiB,
    "csv": 64 * 1024 * MiB,
    "data": 64 * 1024 * MiB,
}
"""Largest size [bytes] read of each kind of input file: a URDF (32 MiB; real ones are
below 1 MiB), a collision mesh (32 MiB; an ASCII STL is split into words), a JSON file
(calibration, noise, dynamics, model metadata: 16 MiB), a CSV or CAN map (1 MiB), a
model file (2 GiB), a data file streamed in pieces (CSV, logs, arrays: 64 GiB)."""

MAX_JSON_DEPTH = 64
"""Deepest nesting of arrays and objects accepted in a JSON document."""
MAX_NUMBER_CHARS = 100
"""Longest number (characters) accepted in a JSON document."""


def _kind_name(mode: int) -> str:
    """Return what a non-regular file is, for the refusal."""
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_regular(path: str | Path, what: str = "file", kind: str = "data") -> os.stat_result:
    """Return ``os.stat(path)`` of a regular file (a link to one included) no larger than
    ``LIMITS[kind]``; raise one InputError naming ``path`` and ``what`` it should be
    otherwise (missing, a FIFO, a device, a directory, too large). Opens nothing."""
    try:
        info = os.stat(path)
    except (OSError, ValueError) as err:
        detail = getattr(err, "strerror", None) or type(err).__name__
        raise InputError(f"cannot read the {what}: {detail}", path) from err
    if not stat.S_ISREG(info.st_mode):
        raise InputError(f"cannot read the {what}: it is {_kind_name(info.st_mode)}, not a "
                         "regular file", path)
    limit = LIMITS[kind]
    if info.st_size > limit:
        raise InputError(f"the {what} is larger than {limit} bytes ({info.st_size})", path)
    return info


@contextmanager
def open_input(path: str | Path, what: str = "file", kind: str = "data") -> Iterator[IO[bytes]]:
    """Open the regular file ``path`` for binary reading (see the module docstring);
    ``what`` names it in refusals, ``kind`` picks its size limit in :data:`LIMITS`.
    Raises one InputError naming the file for a missing, special, changed or too large
    file."""
    before = check_regular(path, what, kind)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as err:
        raise InputError(f"cannot read the {what}: {err.strerror or err}", path) from err
    try:
        after = os.fstat(fd)
        if not stat.S_ISREG(after.st_mode) or (after.st_dev, after.st_ino) != (
                before.st_dev, before.st_ino):
            raise InputError(f"the {what} changed while it was opened "
                             f"(now {_kind_name(after.st_mode)})", path)
        os.set_blocking(fd, True)
        handle = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with handle:
        yield handle


def read_input_bytes(path: str | Path, what: str = "file", kind: str = "data") -> bytes:
    """Return the bytes of the regular file ``path`` (:func:`open_input`), refusing one
    that grows past its kind's limit while it is read."""
    limit = LIMITS[kind]
    with open_input(path, what, kind) as fh:
        try:
            data = fh.read(limit + 1)
        except OSError as err:
            raise InputError(f"cannot read the {what}: {err.strerror or err}", path) from err
    if len(data) > limit:
        raise InputError(f"the {what} is larger than {limit} bytes", path)
    return data


def read_input_text(path: str | Path, what: str = "file", kind: str = "data") -> str:
    """Return the UTF-8 text of the regular file ``path`` (:func:`read_input_bytes`);
    InputError naming the file when it is not UTF-8."""
    data = read_input_bytes(path, what, kind)
    try:
        return data.decode()
    except UnicodeDecodeError as err:
        raise InputError(f"the {what} is not UTF-8 text (byte {err.start})", path) from err


def _number(text: str) -> str:
    if len(text) > MAX_NUMBER_CHARS:
        raise ValueError(f"a number of {len(text)} characters (at most {MAX_NUMBER_CHARS})")
    return text


def _depth(value: Any) -> int:
    """Return the nesting depth of a parsed JSON value (iteratively)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict | list):
            deepest = max(deepest, depth)
            stack += [(v, depth + 1) for v in (item.values() if isinstance(item, dict)
                                                else item)]
    return deepest


def parse_json(text: str | bytes, what: str = "JSON", path: str | Path | None = None,
               limit: int = LIMITS["json"], max_depth: int = MAX_JSON_DEPTH) -> Any:
    """Return the JSON value of ``text`` with bounded size (``limit`` bytes), depth
    (``max_depth``, :data:`MAX_JSON_DEPTH` unless a format nests deeper, such as a skops
    schema) and number length (:data:`MAX_NUMBER_CHARS`); raise one InputError naming
    ``path`` and ``what`` otherwise (not JSON, too deep, too long a number, too
    large)."""
    if len(text) > limit:
        raise InputError(f"the {what} is larger than {limit} bytes", path)
    try:
        value = json.loads(text, parse_int=lambda s: int(_number(s)),
                           parse_float=lambda s: float(_number(s)))
    except RecursionError as err:
        raise InputError(f"the {what} is nested too deeply (at most {max_depth} "
                         "levels)", path) from err
    except (ValueError, UnicodeDecodeError) as err:
        detail = " ".join(str(err).split())[:200]
        raise InputError(f"the {what} is not JSON ({detail})", path) from err
    if _depth(value) > max_depth:
        raise InputError(f"the {what} is nested too deeply (at most {max_depth} levels)",
                         path)
    return value


def read_json(path: str | Path, what: str = "JSON file") -> Any:
    """Return the JSON value in the regular file ``path``: :func:`read_input_text` then
    :func:`parse_json`; one InputError naming the file for any problem."""
    return parse_json(read_input_text(path, what, "json"), what, path)
