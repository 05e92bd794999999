"""Errors that the command-line tools turn into one-line messages with exit code 2."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad input: a file, argument or stream that cannot be used as given.

    A ``ValueError``, so code that catches those catches it too.

    ``str(err)`` is one line naming the offending file (when there is one) and the
    problem, for example ``sessions/x.parquet: NaN in column tau_3 at row 12``.
    """

    def __init__(self, problem: str, path: str | Path | None = None) -> None:
        self.problem = problem.replace("\n", " ")
        self.path = None if path is None else str(path)
        super().__init__(self.problem if self.path is None else f"{self.path}: {self.problem}")


DATA_ERRORS: tuple[type[BaseException], ...] = (InputError, ValueError, IndexError,
                                                ArithmeticError)
"""What one bad session may raise while a directory command processes it (besides
InputError: numeric faults of odd data, such as an empty array after dropping
incomplete samples). Commands over many sessions list such a session as a problem and
go on with the rest; other exceptions are bugs and still stop them."""


def problem_text(err: BaseException) -> str:
    """Return one line (at most about 200 characters of detail) on a session's problem."""
    if isinstance(err, InputError):
        return err.problem
    detail = " ".join(str(err).split())[:200]
    return f"cannot process this session ({type(err).__name__}: {detail})"
