"""Errors that the command-line tools turn into one-line messages with exit code 2.

Every error a user can act on is a :class:`ContactkitError`; its ``str()`` is one line
naming the offending file (when there is one) and the problem. Three kinds:

- :class:`InputError`: a file, argument or stream that cannot be used as given (also a
  ``ValueError``). Commands over many sessions list such a session as a problem and go
  on with the rest.
- :class:`DependencyMissing`: an optional dependency (an extra) is not installed; the
  message names the ``pip install`` that fixes it (also an ``ImportError``).
- :class:`ResourceError`: the machine, not the input, is the problem: a full disk, an
  unreachable or empty Dask cluster. A command over many sessions stops at the first,
  since the rest would fail alike.

The three are siblings: ``except InputError`` does not catch the other two, so a
missing extra or a full disk is never taken for one bad session. Code that must catch
every one of them (cleaning up, trying the next backend) catches :class:`ContactkitError`.
"""

from __future__ import annotations

import errno
from collections.abc import Collection
from pathlib import Path

MAX_PROBLEM_CHARS = 1000
"""The longest problem [characters] an error line holds; a longer one (a value quoted from
a file) is cut, with its length said."""

NO_SPACE_ERRNOS = (errno.ENOSPC, errno.EDQUOT)
"""``OSError`` numbers of a full device or an exhausted quota."""


class ContactkitError(Exception):
    """An error a user can act on, shown as one line (exit code 2 in the commands).

    ``problem`` is the one-line description, ``path`` the file it concerns (or None);
    ``str(err)`` is ``"<path>: <problem>"``, for example
    ``sessions/x.parquet: NaN in column tau_3 at row 12``. A problem is cut at
    :data:`MAX_PROBLEM_CHARS` characters.
    """

    def __init__(self, problem: str, path: str | Path | None = None) -> None:
        one_line = problem.replace("\n", " ")
        if len(one_line) > MAX_PROBLEM_CHARS:  # a 50 MB CSV cell quoted whole
            one_line = f"{one_line[:MAX_PROBLEM_CHARS]}... ({len(one_line)} characters)"
        where = None if path is None else str(path)
        super().__init__(one_line if where is None else f"{where}: {one_line}")
        self.problem = one_line
        self.path = where  # after the base class's __init__: ImportError sets its own

    def __reduce__(self):
        """Pickle as ``(problem, path)``, so an error raised in a worker process keeps
        both when it reaches the parent."""
        return type(self), (self.problem, self.path)


class InputError(ContactkitError, ValueError):
    """Bad input: a file, argument or stream that cannot be used as given.

    A ``ValueError``, so code that catches those catches it too.
    """


class DependencyMissing(ContactkitError, ImportError):
    """An optional dependency is not installed; the message says which extra to install
    (``pip install 'contactkit[nn]'``). An ``ImportError``, so code that falls back when
    an optional import fails catches it too."""


class ResourceError(ContactkitError):
    """The machine cannot do the job: no space left on the device, a Dask scheduler that
    does not answer or has no worker."""


def check_choice(what: str, value: object, allowed: Collection[str]) -> None:
    """Return None when ``value`` is one of ``allowed``; raise the one-line InputError
    ``unknown <what> <value!r> (expected one of <allowed>)`` otherwise."""
    if value not in allowed:
        raise InputError(f"unknown {what} {value!r} (expected one of {', '.join(allowed)})")


def write_error(problem: str, err: OSError, path: str | Path | None = None
                ) -> InputError | ResourceError:
    """Return the error to raise for ``err``, an ``OSError`` of writing described by
    ``problem``: a :class:`ResourceError` when the device is full (or the quota
    exhausted), an :class:`InputError` otherwise (permissions, read-only file system)."""
    kind = ResourceError if err.errno in NO_SPACE_ERRNOS else InputError
    return kind(problem, path)


DATA_ERRORS: tuple[type[BaseException], ...] = (InputError, ValueError, IndexError,
                                                ArithmeticError)
"""What one bad session may raise while a directory command processes it (besides
InputError: numeric faults of odd data, such as an empty array after dropping
incomplete samples). Commands over many sessions list such a session as a problem and
go on with the rest; other exceptions stop them: a :class:`DependencyMissing` or
:class:`ResourceError` (every other session would fail alike) and bugs."""


def problem_text(err: BaseException) -> str:
    """Return one line (at most about 200 characters of detail) on a session's problem."""
    if isinstance(err, ContactkitError):
        return err.problem
    detail = " ".join(str(err).split())[:200]
    return f"cannot process this session ({type(err).__name__}: {detail})"


def input_error_about(err: InputError, path: str | Path | None) -> InputError:
    """Return ``err`` as an InputError about ``path`` (a session); a file ``err`` named
    that is not ``path`` (the robot's URDF) stays in the problem, so the line names both."""
    if path is None or err.path is None or Path(err.path) == Path(path):
        return InputError(err.problem, path or err.path)
    return InputError(f"{err.path}: {err.problem}", path)
