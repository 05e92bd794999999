"""The error hierarchy: every error a user can act on is a ContactkitError, one line,
exit code 2; a missing extra and a full disk are not InputErrors, so a command over many
sessions stops at them instead of listing every session as bad."""

from __future__ import annotations

import errno
import pickle
import tempfile
from pathlib import Path

import pytest

from contactkit.cli.common import new_app, run_app
from contactkit.errors import (
    DATA_ERRORS,
    ContactkitError,
    DependencyMissing,
    InputError,
    ResourceError,
    check_choice,
    problem_text,
    write_error,
)
from contactkit.util import atomic


@pytest.mark.parametrize("kind", [InputError, DependencyMissing, ResourceError])
def test_one_line_with_the_path_and_picklable(kind) -> None:
    err = kind("two\nlines", Path("a/b.parquet"))
    assert isinstance(err, ContactkitError)
    assert str(err) == "a/b.parquet: two lines" and err.problem == "two lines"
    assert err.path == "a/b.parquet"
    copy = pickle.loads(pickle.dumps(err))  # as it comes back from a worker process
    assert type(copy) is kind and (copy.problem, copy.path) == (err.problem, err.path)
    assert problem_text(err) == "two lines"


def test_siblings_not_input_errors() -> None:
    assert issubclass(InputError, ValueError)
    assert issubclass(DependencyMissing, ImportError)
    for kind in (DependencyMissing, ResourceError):
        assert not issubclass(kind, InputError)
        with pytest.raises(kind):  # a directory command does not take it for a bad session
            try:
                raise kind("x")
            except DATA_ERRORS:
                pytest.fail("caught as one session's problem")


def test_write_error_by_errno() -> None:
    assert type(write_error("full", OSError(errno.ENOSPC, "no space"))) is ResourceError
    assert type(write_error("quota", OSError(errno.EDQUOT, "quota"))) is ResourceError
    assert type(write_error("denied", OSError(errno.EACCES, "denied"))) is InputError


@pytest.mark.parametrize("kind", [InputError, DependencyMissing, ResourceError])
def test_run_app_gives_one_line_and_exit_code_2(kind, capsys) -> None:
    app = new_app("t")

    @app.command()
    def go() -> None:
        """Fail."""
        raise kind("it failed", "f.txt")

    @app.command()
    def other() -> None:
        """A second command, so that the app has subcommands."""

    assert run_app(app, "tool", ["go"]) == 2
    assert capsys.readouterr().err == "tool: error: f.txt: it failed\n"


def test_a_full_disk_is_a_resource_error(tmp_path, monkeypatch) -> None:
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(tempfile, "mkstemp", full)
    with pytest.raises(ResourceError, match="no space left on the device"):
        atomic.write_text(tmp_path / "x.txt", "hello")
    assert not (tmp_path / "x.txt").exists()


def test_check_choice_names_the_choices() -> None:
    assert check_choice("protocol", "group", ("group", "thesis")) is None
    with pytest.raises(InputError) as caught:
        check_choice("protocol", "x", ("group", "thesis"))
    assert str(caught.value) == "unknown protocol 'x' (expected one of group, thesis)"
