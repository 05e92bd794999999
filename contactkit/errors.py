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
