"""One safe writer for every file contactkit writes.

:func:`atomic_write` fills a temporary file beside the target and renames it into place
at the end, so a reader sees the old file or the whole new one, never a part, and a
failure (full disk, read-only directory, kill) leaves no partial target.

- The temporary file is named ``.<target name>.contactkit-<pid>-<random>.tmp[<suffix>]``
  (a target name of over 200 bytes cut and given a digest, :func:`temporary_stem`, so
  that the temporary's name fits the 255 bytes of any legal target name):
  unpredictable, created exclusively (``O_CREAT | O_EXCL | O_NOFOLLOW`` through
  :func:`tempfile.mkstemp`), so a symbolic link or file planted under any name is
  never followed or reused.
- The file gets the permissions a plain ``open()`` would give it (``0o666`` less the
  umask, :func:`new_file_mode`), not the owner-only mode of a temporary file, so that
  colleagues read a shared lab directory's sessions as they read any other file.
- The target is replaced with one ``rename`` (``overwrite``), or linked into place only
  when it does not exist (no overwrite), so two writers never both win.
- Whether an existing target may be replaced is the caller's policy: a file the user
  named (``--out``, ``--save``, ``--log``, ``--name``) only with ``--overwrite``; a
  default output the tool owns only when it is recognisably the tool's (``owned``, the
  tests and marks of :mod:`contactkit.util.owned`): never a symbolic link, never a
  foreign file.
- Errors of cleaning up never hide the error that made the write fail; an ``OSError``
  becomes one :class:`InputError` line naming the file (a :class:`ResourceError` when
  the device is full).
- Leftovers of killed writers are recognised by their name and removed by
  :func:`remove_stale_temporaries` only when their writer's process is gone or they are
  older than :data:`STALE_AGE_S`: the next write of the same target removes its own.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from contactkit.errors import InputError, write_error

STALE_AGE_S = 24 * 3600.0
"""Age [s] after which a temporary file is removed even when its pid is alive (pids are
reused; no writer runs for a day)."""

MARK = "contactkit"
_TEMPORARY = re.compile(
    rf"\.(?P<name>.+)\.(?:{MARK}-(?P<pid>\d+)-[A-Za-z0-9_]+\.tmp(?:\.[A-Za-z0-9]+)?"
    r"|(?P<oldpid>\d+)\.tmp)")

Owned = Callable[[Path], bool]
"""A test that an existing file is one the tool wrote itself (it may then be replaced)."""


@dataclass
class Temporary:
    """The temporary file of one :func:`atomic_write`: ``path`` [the name] and ``file``
    (open for binary writing; writers that take a name use ``path`` instead). Set
    ``keep`` to False to drop it at the end instead of moving it into place."""

    path: Path
    file: IO[bytes]
    keep: bool = True


MAX_TEMPORARY_STEM_BYTES = 200
"""Longest part of a temporary's name taken from its target's [bytes]: with the mark,
the pid, the random part and a suffix the name stays within the 255 bytes a file name
may have, whatever the target's legal name."""


def temporary_stem(name: str) -> str:
    """Return the part of a temporary's name that stands for the target ``name``: the
    name itself, or, when it is longer than :data:`MAX_TEMPORARY_STEM_BYTES` bytes, its
    start cut at a character boundary followed by ``~`` and 8 hex digits of its SHA-1,
    so that each target still has its own recognisable temporaries."""
    raw = name.encode(errors="surrogateescape")
    if len(raw) <= MAX_TEMPORARY_STEM_BYTES:
        return name
    digest = hashlib.sha1(raw).hexdigest()[:8]
    start = raw[:MAX_TEMPORARY_STEM_BYTES - 10].decode(errors="ignore")
    return f"{start}~{digest}"


def temporary_prefix(target: Path) -> str:
    """Return the recognisable start of ``target``'s temporary names (this process)."""
    return f".{temporary_stem(target.name)}.{MARK}-{os.getpid()}-"


def _describe(err: OSError) -> str:
    """Return one line on an ``OSError`` of writing (full disk, permissions, ...)."""
    if err.errno == errno.ENOSPC or err.errno == errno.EDQUOT:
        return "no space left on the device (nothing was written)"
    if err.errno in (errno.EACCES, errno.EPERM):
        return "cannot write here: permission denied (nothing was written)"
    if err.errno == errno.EROFS:
        return "cannot write here: read-only file system (nothing was written)"
    return f"cannot write the file ({err.strerror or type(err).__name__}; nothing was written)"


@contextmanager
def _write_errors(path: Path) -> Iterator[None]:
    """Raise an ``OSError`` of the block as one line naming ``path``
    (:func:`~contactkit.errors.write_error`: a ResourceError when the device is full)."""
    try:
        yield
    except OSError as err:
        raise write_error(_describe(err), err, path) from err


def _already_exists(path: Path, flag: str, what: str = "output file") -> InputError:
    """Return the one-line error for an existing ``path`` that ``flag`` would replace."""
    return InputError(f"{what} already exists (pass {flag} to replace it)", path)


def check_target(path: str | Path, *, overwrite: bool = False, flag: str = "--overwrite",
                 owned: Owned | None = None) -> Path:
    """Check that ``path`` may be written under the overwrite policy; return it.

    A missing target is always fine. An existing one (a symbolic link included) is
    replaced with ``overwrite``; without it, only when ``owned`` is given, the target is
    a regular file (not a link) and ``owned(path)`` says the tool wrote it. Raises one
    :class:`InputError` line naming the file and ``flag`` otherwise, and when the
    directory does not exist.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise InputError("output directory does not exist", path.parent)
    if overwrite or not os.path.lexists(path):
        return path
    if owned is not None:
        if path.is_symlink():
            raise InputError("is a symbolic link, not a file contactkit wrote: remove it or "
                             "choose another output", path)
        if not path.is_file() or not _safe_owned(owned, path):
            raise InputError("exists and is not a file contactkit wrote: remove it or choose "
                             "another output", path)
        return path
    raise _already_exists(path, flag)


def _safe_owned(owned: Owned, path: Path) -> bool:
    try:
        return bool(owned(path))
    except (OSError, ValueError):
        return False


def new_file_mode() -> int:
    """Return the permission bits a new file gets from ``open()``: ``0o666`` less the
    process umask (read from ``/proc/self/status`` where it is, so no other thread sees
    the umask changed)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            umask = next(int(line.split()[1], 8) for line in status
                         if line.startswith("Umask:"))
    except (OSError, StopIteration, ValueError, IndexError):
        umask = os.umask(0o022)
        os.umask(umask)
    return 0o666 & ~umask


@contextmanager
def atomic_write(path: str | Path, *, overwrite: bool = False, flag: str = "--overwrite",
                 owned: Owned | None = None, suffix: str = "") -> Iterator[Temporary]:
    """Write ``path`` atomically: yield a :class:`Temporary` to fill, then move it into
    place (see the module docstring).

    ``overwrite``, ``flag`` and ``owned`` are the overwrite policy of
    :func:`check_target`, checked before the temporary is created and again when it is
    moved into place. ``suffix`` ends the temporary's name (for writers that choose a
    format by suffix, e.g. ``.asc``). On any error the temporary is removed and the
    target left as it was; an ``OSError`` is raised as one :class:`InputError` line (a
    :class:`~contactkit.errors.ResourceError` when the device is full).
    """
    path = Path(path)
    replace = overwrite or owned is not None
    check_target(path, overwrite=overwrite, flag=flag, owned=owned)
    remove_stale_temporaries(path.parent, target=path.name)
    with _write_errors(path):
        fd, name = tempfile.mkstemp(prefix=temporary_prefix(path), suffix=".tmp" + suffix,
                                    dir=path.parent)
        os.fchmod(fd, new_file_mode())
    tmp = Path(name)
    handle = os.fdopen(fd, "wb")
    try:
        with _write_errors(path):
            temporary = Temporary(tmp, handle)
            yield temporary
            if not temporary.keep:
                return
            if not handle.closed:
                handle.flush()
            _fsync(tmp)
            handle.close()
            check_target(path, overwrite=overwrite, flag=flag, owned=owned)
            if replace:
                os.replace(tmp, path)
            else:
                try:
                    os.link(tmp, path)
                except FileExistsError as err:
                    raise _already_exists(path, flag) from err
                except OSError as err:  # file systems without hard links
                    if err.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP):
                        raise
                    if os.path.lexists(path):
                        raise _already_exists(path, flag) from err
                    os.replace(tmp, path)
            _fsync_dir(path.parent)
    finally:
        with suppress(OSError):
            handle.close()
        with suppress(OSError):
            tmp.unlink(missing_ok=True)


@contextmanager
def atomic_directory(path: str | Path, *, overwrite: bool = False,
                     flag: str = "--overwrite", kind: Owned | None = None,
                     what: str = "output") -> Iterator[Path]:
    """Write the directory ``path`` atomically: yield a path to create it at (inside a
    private temporary directory beside ``path``), then rename it into place.

    An existing ``path`` is refused (one line naming ``flag``) unless ``overwrite``,
    which moves it (a link itself, never what it points to) into the temporary
    directory and removes it there; with ``kind`` (a test of an existing directory)
    only a directory it accepts is replaced (a file or a link, itself), never another
    directory the user named by mistake (``what`` names the kind in the refusal). On
    any error nothing new is left at ``path`` and the temporary directory is removed.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise InputError("output directory does not exist", path.parent)
    if os.path.lexists(path) and not overwrite:
        raise _already_exists(path, flag, "output")
    if kind is not None and path.is_dir() and not path.is_symlink() and not kind(path):
        raise InputError(f"exists and is not a {what}: not replaced, even with {flag}", path)
    remove_stale_temporaries(path.parent, target=path.name)
    with _write_errors(path):
        holder = Path(tempfile.mkdtemp(prefix=temporary_prefix(path), suffix=".tmp",
                                       dir=path.parent))
    try:
        with _write_errors(path):
            inner = holder / path.name
            yield inner
            if os.path.lexists(path):
                if not overwrite:
                    raise _already_exists(path, flag, "output")
                old = holder / ".old"
                os.rename(path, old)
            os.rename(inner, path)
            _fsync_dir(path.parent)
    finally:
        with suppress(OSError):
            shutil.rmtree(holder)


@contextmanager
def scratch_directory(target: str | Path) -> Iterator[Path]:
    """Yield an empty private directory beside ``target`` for a writer that must build
    its output in several files first (a rosbags writer makes a bag directory); it is
    removed at the end, and its name is recognisable like every temporary here, so the
    leftover of a killed run is cleaned up by :func:`remove_stale_temporaries`."""
    target = Path(target)
    remove_stale_temporaries(target.parent, target=target.name)
    with _write_errors(target):
        holder = Path(tempfile.mkdtemp(prefix=temporary_prefix(target), suffix=".tmp",
                                       dir=target.parent))
    try:
        with _write_errors(target):
            yield holder
    finally:
        with suppress(OSError):
            shutil.rmtree(holder)


def write_bytes(path: str | Path, data: bytes, *, overwrite: bool = False,
                flag: str = "--overwrite", owned: Owned | None = None) -> Path:
    """Write ``data`` to ``path`` with :func:`atomic_write`; return the path."""
    with atomic_write(path, overwrite=overwrite, flag=flag, owned=owned) as tmp:
        tmp.file.write(data)
    return Path(path)


def write_text(path: str | Path, text: str, *, overwrite: bool = False,
               flag: str = "--overwrite", owned: Owned | None = None) -> Path:
    """Write ``text`` (UTF-8) to ``path`` with :func:`atomic_write`; return the path."""
    return write_bytes(path, text.encode(), overwrite=overwrite, flag=flag, owned=owned)


def output_directory(path: Path) -> Path:
    """Return ``path`` after creating it if needed and proving it writable (a read-only
    mount, missing permission, a full disk), before any source, robot or bus is started;
    raise InputError when it cannot be created or written to. Temporary files that
    killed writers left there are removed (only those whose writer is gone, see
    :func:`remove_stale_temporaries`)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot create output directory ({err.strerror})", path) from err
    try:
        with tempfile.TemporaryFile(dir=path) as probe:
            probe.write(b"\0")
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as err:
        raise InputError(f"cannot write here ({err.strerror or err})", path) from err
    remove_stale_temporaries(path)
    return path


def any_regular_file(path: Path) -> bool:
    """:data:`Owned` for files in contactkit's own cache: any regular file there."""
    return path.is_file() and not path.is_symlink()


def remove_stale_temporaries(directory: str | Path, max_age_s: float = STALE_AGE_S,
                             target: str | None = None) -> list[Path]:
    """Remove the temporary files and directories that killed writers left in
    ``directory`` (named as :func:`atomic_write` names them, or the older
    ``.<name>.<pid>.tmp``), only those of the file named ``target`` when given; return
    them. One is removed only when its writer's process is gone or it is older than
    ``max_age_s`` [s]; others stay."""
    removed: list[Path] = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    now = time.time()
    for entry in entries:
        match = _TEMPORARY.fullmatch(entry.name)
        if match is None or (target is not None and match.group("name") != temporary_stem(target)):
            continue
        pid = int(match.group("pid") or match.group("oldpid"))
        try:
            age = now - entry.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        if pid != os.getpid() and (_alive(pid) and age < max_age_s):
            continue
        if pid == os.getpid() and age < max_age_s:
            continue
        with suppress(OSError):
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
            removed.append(Path(entry.path))
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
