"""Rerun recordings saved to a file (``replay --save``, ``capture --save-rrd``, the
catalog's ``.rrd`` files): checks that a streamed recording was written whole.

Rerun's file sink writes from a thread of its own into the temporary file of an
:func:`~contactkit.util.atomic.atomic_write`; a full disk only shows as a
``RuntimeError`` of a later flush, as warnings, or as a file without its footer. So the
writer checks the free space before (:func:`start_recording`) and while it logs
(:func:`check_space`), flushes with a time
limit and checks the footer before the file is moved into place
(:func:`finish_recording`): a failed recording is one line (a
:class:`~contactkit.errors.ResourceError` when the device is full), its temporary file
is removed by the ``atomic_write`` and nothing is left at the target.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from contactkit.errors import InputError, ResourceError

if TYPE_CHECKING:
    import rerun as rr
    import rerun.blueprint as rrb

RRD_FOOTER = b"RRF2FOOT"
"""The mark near the end of every whole .rrd file (followed by 4 bytes of version)."""
MIN_FREE_BYTES = 1 << 20
"""Free space [bytes] below which a recording being written is stopped as a full disk:
Rerun's writer thread retries a write that failed for space, and a disconnect waits for
it, for ever when the device stays full (Rerun 0.41), so the writers stop while there is
still room."""
FLUSH_TIMEOUT_S = 60.0
"""Longest wait [s] for Rerun to write what was logged at the end of a recording."""

_FULL = "no space left on the device (nothing was written)"


def free_bytes(directory: str | Path) -> int | None:
    """Return the bytes free to this user in ``directory``'s file system (None when not
    known)."""
    try:
        info = os.statvfs(directory)
    except OSError:
        return None
    return info.f_bavail * info.f_frsize


def check_space(target: str | Path) -> None:
    """Raise ResourceError naming ``target`` when its directory has less than
    :data:`MIN_FREE_BYTES` free: called while a recording is logged, so a full disk
    stops it at once rather than stalling Rerun's writer."""
    free = free_bytes(Path(target).parent)
    if free is not None and free < MIN_FREE_BYTES:
        raise ResourceError(_FULL, target)


def start_recording(rec: rr.RecordingStream, written: Path, target: str | Path,
                    blueprint: rrb.Blueprint | None = None) -> None:
    """Save ``rec`` into the file ``written`` (the temporary behind ``target``) with the
    default ``blueprint``, after :func:`check_space` (Rerun's ``save`` waits for ever
    when the device is already full)."""
    check_space(target)
    rec.save(written, default_blueprint=blueprint)


def finish_recording(rec: rr.RecordingStream, written: Path, target: str | Path) -> None:
    """Flush ``rec`` (at most :data:`FLUSH_TIMEOUT_S`), disconnect it, and check that the
    file ``written`` (the temporary behind ``target``) ends with Rerun's footer. Raises
    one line naming ``target`` otherwise: a ResourceError when the disk is full, an
    InputError for another failure of Rerun's writer."""
    try:
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        rec.disconnect()
    except RuntimeError as err:  # Rerun's: "File-writer thread shut down prematurely"
        _raise_failed(target, err)
    try:
        with open(written, "rb") as fh:
            fh.seek(max(0, os.fstat(fh.fileno()).st_size - 64))
            whole = RRD_FOOTER in fh.read()
    except OSError as err:
        _raise_failed(target, err)
    if not whole:
        _raise_failed(target, None)


def _raise_failed(target: str | Path, err: Exception | None) -> None:
    free = free_bytes(Path(target).parent)
    if free is not None and free < MIN_FREE_BYTES:
        raise ResourceError(_FULL, target) from err
    detail = "" if err is None else f": {' '.join(str(err).split())[:200]}"
    raise InputError(f"the recording could not be written whole{detail} (nothing was "
                     "written)", target) from err
