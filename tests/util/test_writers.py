"""One safe writer for every output (issue 25): no write through a planted link, no
overwrite without being asked, no partial file on a full disk or a read-only directory,
one line and exit code 2 for each refusal, leftovers of killed writers cleaned up."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from contactkit.cli.classify import app as classify_app
from contactkit.cli.common import run_app
from contactkit.cli.recorder import app as recorder_app
from contactkit.errors import InputError
from contactkit.util import atomic, owned
from tests.conftest import make_session, run_command

VICTIM_TEXT = b"precious, outside the output directory\n"


def run(capsys, app, prog: str, *argv) -> tuple[int, str, str]:
    """Run a command line in this process; return exit code, stdout and stderr."""
    code = run_app(app, prog, [str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def recorder(capsys, *argv) -> tuple[int, str, str]:
    return run(capsys, recorder_app, "recorder", *argv)


def classify(capsys, *argv) -> tuple[int, str, str]:
    return run(capsys, classify_app, "classify", *argv)


def one_line(code: int, err: str, *texts: str) -> None:
    """Exit code 2 and one error line holding ``texts`` (a progress bar may precede it)."""
    assert code == 2, err
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert "Traceback" not in err and len(errors) == 1, err
    for text in texts:
        assert text in errors[0], err


# -- the writer itself -------------------------------------------------------------------

def test_temporary_names_are_unpredictable_and_recognisable(tmp_path: Path) -> None:
    seen = []
    for _ in range(2):
        with atomic.atomic_write(tmp_path / "x.bin", overwrite=True) as tmp:
            seen.append(tmp.path.name)
            tmp.file.write(b"1")
    assert seen[0] != seen[1]
    for name in seen:
        assert re.fullmatch(rf"\.x\.bin\.contactkit-{os.getpid()}-\w+\.tmp", name), name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.bin"]


def test_a_planted_link_is_never_followed(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_bytes(VICTIM_TEXT)
    out = tmp_path / "out"
    out.mkdir()
    (out / "m.bin").symlink_to(victim)
    with pytest.raises(InputError, match="--overwrite"):
        atomic.write_bytes(out / "m.bin", b"model")
    with pytest.raises(InputError, match="symbolic link"):
        atomic.write_bytes(out / "m.bin", b"model", owned=atomic.any_regular_file)
    atomic.write_bytes(out / "m.bin", b"model", overwrite=True)  # replaces the link itself
    assert victim.read_bytes() == VICTIM_TEXT
    assert not (out / "m.bin").is_symlink() and (out / "m.bin").read_bytes() == b"model"


def test_owned_outputs_are_replaced_and_foreign_ones_kept(tmp_path: Path) -> None:
    mine = owned.owned_by_marker(b"MINE")
    target = tmp_path / "report.html"
    atomic.write_text(target, "MINE 1", owned=mine)
    atomic.write_text(target, "MINE 2", owned=mine)
    assert target.read_text() == "MINE 2"
    target.write_text("someone else's notes")
    with pytest.raises(InputError, match="not a file contactkit wrote"):
        atomic.write_text(target, "MINE 3", owned=mine)
    assert target.read_text() == "someone else's notes"


def test_fixed_name_results_replace_only_their_own_files(tmp_path: Path) -> None:
    """gridsearch.md, window.json, augmentation.png ...: a user's Markdown notes, JSON
    object or picture of that name is not the tool's (it was replaced: the test was a
    leading '# ', '{' or a PNG signature); a result the tool wrote is."""
    import json

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure()
    mine = {"notes.md": "# My notes\n\nprecious\n", "notes.json": '{"precious": 1}'}
    for name, text in mine.items():
        (tmp_path / name).write_text(text)
    fig.savefig(tmp_path / "notes.png")
    picture = (tmp_path / "notes.png").read_bytes()
    for name in ("notes.md", "notes.json", "notes.png"):
        assert not owned.owned_result(tmp_path / name), name
    with pytest.raises(InputError, match="not a file contactkit wrote"):
        atomic.write_text(tmp_path / "notes.md", owned.result_markdown("# Results\n"),
                          owned=owned.owned_result)
    with pytest.raises(InputError, match="not a file contactkit wrote"):
        owned.write_figure(tmp_path / "notes.png", fig, owned=owned.owned_result)
    assert (tmp_path / "notes.md").read_text() == mine["notes.md"]
    assert (tmp_path / "notes.png").read_bytes() == picture
    results = {"r.md": owned.result_markdown("# Results\n"),
               "r.json": json.dumps(owned.result_json({"rows": []}), indent=1)}
    for _ in range(2):  # a re-run replaces its own results
        for name, text in results.items():
            atomic.write_text(tmp_path / name, text, owned=owned.owned_result)
        owned.write_figure(tmp_path / "r.png", fig, owned=owned.owned_result)
    plt.close(fig)
    assert all(owned.owned_result(tmp_path / n) for n in ("r.md", "r.json", "r.png"))


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_written_files_get_the_umask_s_permissions(umask: int, tmp_path: Path) -> None:
    """A file written through a temporary has the permissions ``open()`` would give it
    (a session in a shared lab directory is as readable as any file), not the
    owner-only mode of a temporary file."""
    old = os.umask(umask)
    try:
        atomic.write_text(tmp_path / "a.txt", "x")
        plain = tmp_path / "plain.txt"
        plain.write_text("x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o666 & ~umask
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == plain.stat().st_mode & 0o777


def test_an_error_while_writing_leaves_nothing(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError), atomic.atomic_write(tmp_path / "x") as tmp:
        tmp.file.write(b"half")
        raise RuntimeError("writer failed")
    assert list(tmp_path.iterdir()) == []


def test_the_next_write_of_a_target_removes_its_killed_writers_leftovers(tmp_path) -> None:
    """`replay --save x.rrd` killed, then run again: the dead writer's temporary of
    x.rrd goes; a live writer's, and other targets' leftovers, stay."""
    proc = subprocess.Popen(["true"])
    proc.wait()
    dead = tmp_path / f".x.rrd.contactkit-{proc.pid}-abc123.tmp"
    live = tmp_path / f".x.rrd.contactkit-{os.getppid()}-abc123.tmp"
    other = tmp_path / f".y.rrd.contactkit-{proc.pid}-abc123.tmp"
    for path in (dead, live, other):
        path.write_bytes(b"half")
    atomic.write_bytes(tmp_path / "x.rrd", b"whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["x.rrd", live.name, other.name])


def test_stale_temporaries_go_only_when_their_writer_is_gone_or_old(tmp_path: Path) -> None:
    dead = subprocess.run(["true"], check=True)  # noqa: F841 (a pid that has exited)
    proc = subprocess.Popen(["true"])
    proc.wait()
    gone = tmp_path / f".a.parquet.contactkit-{proc.pid}-abc123.tmp"
    live = tmp_path / f".b.parquet.contactkit-{os.getppid()}-abc123.tmp"
    old = tmp_path / f".c.parquet.contactkit-{os.getppid()}-zz9.tmp"
    legacy = tmp_path / f".d.parquet.{proc.pid}.tmp"
    other = tmp_path / ".notes.tmp"
    for path in (gone, live, old, legacy, other):
        path.write_bytes(b"x")
    os.utime(old, (1, 1))
    removed = atomic.remove_stale_temporaries(tmp_path)
    assert sorted(removed) == sorted([gone, old, legacy])
    assert live.exists() and other.exists()


# -- every writer, with links planted at its temporary and target names ------------------

def _plant(directory: Path, name: str, victim: Path) -> None:
    """Plant links to ``victim`` under ``name`` and under every temporary name a writer
    could predict (older contactkit versions used ``.NAME.tmp`` and ``.NAME.PID.tmp``)."""
    for link in (name, f".{name}.tmp", f".{name}.{os.getpid()}.tmp",
                 f".{name}.contactkit-{os.getpid()}-0.tmp"):
        (directory / link).symlink_to(victim)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("sessions")
    for seed, action in ((3, "none"), (4, "shove"), (5, "none")):
        make_session(directory, seed=seed, action=action, duration_s=4.0)
    return directory


def _writers(sessions: Path) -> dict[str, tuple[str, Callable[[Path, Path], tuple]]]:
    """name -> (target file name, argv(out_dir, target) for recorder or classify)."""
    first = sessions / "none_3.parquet"
    return {
        "features": ("f.parquet", lambda d, o: ("classify", "features", first, "--out", o)),
        "features --per-sample": ("p.parquet", lambda d, o: (
            "classify", "features", first, "--per-sample", "--out", o)),
        "calibrate": ("robot.json", lambda d, o: ("classify", "calibrate", first, "--out", o)),
        "stats --out": ("r.html", lambda d, o: ("recorder", "stats", sessions, "--out", o)),
        "export-mcap": ("bag", lambda d, o: ("recorder", "export-mcap", first, "--out", o)),
        "can-bridge --log": ("f.asc", lambda d, o: ("recorder", "can-bridge", first, "--log",
                                                    o)),
    }


WRITERS = ["features", "features --per-sample", "calibrate", "stats --out", "export-mcap",
           "can-bridge --log"]


def _call(capsys, argv: tuple) -> tuple[int, str, str]:
    prog, *rest = argv
    return (recorder if prog == "recorder" else classify)(capsys, *rest)


@pytest.mark.parametrize("writer", WRITERS)
def test_links_planted_at_a_writers_names_change_nothing_outside(writer, sessions, tmp_path,
                                                                capsys) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_bytes(VICTIM_TEXT)
    out = tmp_path / "out"
    out.mkdir()
    name, argv = _writers(sessions)[writer]
    _plant(out, name, victim)
    code, _, err = _call(capsys, argv(out, out / name))
    one_line(code, err, name)
    assert victim.read_bytes() == VICTIM_TEXT
    assert (out / name).is_symlink()
    # with --overwrite the link itself is replaced, its target still untouched
    code, _, err = _call(capsys, (*argv(out, out / name), "--overwrite"))
    assert code == 0, err
    assert victim.read_bytes() == VICTIM_TEXT
    assert not (out / name).is_symlink()
    left = {p.name for p in out.iterdir() if not p.is_symlink()}
    assert not any(".contactkit-" in n for n in left), left


@pytest.mark.parametrize("writer", WRITERS)
def test_a_user_named_output_is_never_replaced_without_overwrite(writer, sessions, tmp_path,
                                                                 capsys) -> None:
    name, argv = _writers(sessions)[writer]
    target = tmp_path / name
    if writer == "export-mcap":
        target.mkdir()
        (target / "keep.txt").write_text("mine")
    else:
        target.write_text("mine")
    code, _, err = _call(capsys, argv(tmp_path, target))
    one_line(code, err, name, "--overwrite")
    assert (target / "keep.txt" if target.is_dir() else target).read_text() == "mine"


def test_default_outputs_are_replaced_only_when_the_tool_wrote_them(sessions, tmp_path,
                                                                   capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert recorder(capsys, "stats", sessions)[0] == 0
    assert recorder(capsys, "stats", sessions)[0] == 0  # its own report: replaced
    (tmp_path / "report.html").write_text("<p>my notes</p>")
    code, _, err = recorder(capsys, "stats", sessions)
    one_line(code, err, "report.html", "not a file contactkit wrote")
    assert (tmp_path / "report.html").read_text() == "<p>my notes</p>"
    # the index: rebuilt over its own file, never over a session or a link
    index = sessions / "index.parquet"
    assert recorder(capsys, "index", sessions)[0] == 0 and index.is_file()
    assert recorder(capsys, "index", sessions)[0] == 0
    code, _, err = recorder(capsys, "import-arrays", "--t", "x", "--q", "x", "--dq", "x",
                            "--tau", "x", "--out", tmp_path, "--name", "index.parquet")
    assert code == 2 and "index" in err


def test_import_name_needs_overwrite_to_replace(tmp_path, capsys) -> None:
    rows = 50
    t = 0.001 * np.arange(rows)
    args = []
    for key, values in {"t": t[:, None], "q": np.zeros((rows, 7)), "dq": np.zeros((rows, 7)),
                        "tau": np.ones((rows, 7))}.items():
        np.savetxt(tmp_path / f"{key}.txt", values)
        args += [f"--{key}", tmp_path / f"{key}.txt"]
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_bytes(VICTIM_TEXT)
    _plant(out, "s.parquet", victim)
    code, _, err = recorder(capsys, "import-arrays", *args, "--out", out, "--name", "s.parquet")
    one_line(code, err, "s.parquet")
    code, _, err = recorder(capsys, "import-arrays", *args, "--out", out, "--name",
                            "s.parquet", "--overwrite")
    assert victim.read_bytes() == VICTIM_TEXT
    assert code == 2 or not (out / "s.parquet").is_symlink()


def test_capture_save_rrd_is_renamed_into_place(tmp_path, capsys) -> None:
    rrd = tmp_path / "live.rrd"
    rrd.write_text("mine")
    code, _, err = recorder(capsys, "capture", "--pose", "A", "--action", "bump", "--seed",
                            "4", "--duration", "1.5", "--planned-at", "0.5", "--rate", "100",
                            "--out", tmp_path / "s", "--save-rrd", rrd)
    one_line(code, err, "live.rrd", "--overwrite")
    assert rrd.read_text() == "mine"
    code, _, err = recorder(capsys, "capture", "--pose", "A", "--action", "bump", "--seed",
                            "4", "--duration", "1.5", "--planned-at", "0.5", "--rate", "100",
                            "--out", tmp_path / "s", "--save-rrd", rrd, "--overwrite")
    assert code == 0, err
    assert rrd.read_bytes()[:3] == b"RRF"
    assert not [p for p in tmp_path.iterdir() if ".contactkit-" in p.name]


# -- hostile file systems: read-only and full ----------------------------------------------

def _mount(target: Path, options: str) -> None:
    target.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("needs root to mount a small tmpfs (read-only or full file system)")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(target)],
                          capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()[:100]}")


def _fill(directory: Path) -> None:
    """Fill the file system of ``directory`` to the last byte."""
    with open(directory / "filler", "wb", buffering=0) as fh:
        try:
            while True:
                fh.write(b"\0" * 4096)
                fh.flush()
        except OSError:
            pass
        try:
            while True:
                fh.write(b"\0")
                fh.flush()
        except OSError:
            pass


@pytest.mark.parametrize("condition", ["read-only", "full"])
def test_every_writer_on_a_hostile_file_system(condition, sessions, tmp_path, capsys) -> None:
    target_dir = tmp_path / condition
    _mount(target_dir, "ro,size=64k" if condition == "read-only" else "size=256k")
    try:
        if condition == "full":
            _fill(target_dir)
        before = {p.name for p in target_dir.iterdir()}
        for writer in WRITERS:
            name, argv = _writers(sessions)[writer]
            code, _, err = _call(capsys, argv(target_dir, target_dir / name))
            one_line(code, err, name)
            assert {p.name for p in target_dir.iterdir()} == before, writer
    finally:
        subprocess.run(["umount", str(target_dir)], check=False)


def test_a_killed_importer_leaves_nothing_a_rerun_does_not_clean(tmp_path, capsys) -> None:
    """A temporary of a writer that was killed (its pid gone) is removed by the next
    import into that directory; one of a live writer stays."""
    out = tmp_path / "out"
    out.mkdir()
    proc = subprocess.Popen(["true"])
    proc.wait()
    dead = out / f".s.parquet.contactkit-{proc.pid}-abc.tmp"
    live = out / f".t.parquet.contactkit-{os.getppid()}-abc.tmp"
    dead.write_bytes(b"x" * 1000)
    live.write_bytes(b"x")
    rows = 50
    args = []
    for key, values in {"t": 0.001 * np.arange(rows)[:, None], "q": np.zeros((rows, 7)),
                        "dq": np.zeros((rows, 7)), "tau": np.ones((rows, 7))}.items():
        np.savetxt(tmp_path / f"{key}.txt", values)
        args += [f"--{key}", tmp_path / f"{key}.txt"]
    code, _, err = recorder(capsys, "import-arrays", *args, "--out", out, "--name", "s.parquet")
    assert code == 0, err
    assert not dead.exists() and live.exists()
    code, _, err = recorder(capsys, "import-arrays", *args, "--out", out, "--name", "s.parquet")
    one_line(code, err, "s.parquet", "--overwrite")  # no duplicate, no second file
    assert sorted(p.name for p in out.iterdir()) == sorted([live.name, "s.parquet"])


def test_the_index_never_replaces_a_session_or_a_link(sessions, tmp_path, capsys) -> None:
    data = tmp_path / "data"
    data.mkdir()
    shutil.copy(sessions / "none_3.parquet", data / "none_3.parquet")
    shutil.copy(sessions / "none_3.parquet", data / "index.parquet")  # an old --name
    code, _, err = recorder(capsys, "index", data)
    one_line(code, err, "index.parquet", "not a file contactkit wrote")
    assert (data / "index.parquet").read_bytes() == (sessions / "none_3.parquet").read_bytes()
    (data / "index.parquet").unlink()
    victim = tmp_path / "victim.txt"
    victim.write_bytes(VICTIM_TEXT)
    (data / "index.parquet").symlink_to(victim)
    code, _, err = recorder(capsys, "index", data)
    one_line(code, err, "index.parquet", "symbolic link")
    assert victim.read_bytes() == VICTIM_TEXT


def test_fixed_name_results_are_checked_before_any_work(tmp_path: Path) -> None:
    """An experiment, the augmentation experiment and a grid search refuse a user's file
    at one of their result names before they start (they ran for hours and refused it
    at the end): here the refusal comes before the missing dataset is even looked at."""
    from contactkit.classify.experiments.augmentation import run_augmentation
    from contactkit.classify.experiments.thesis import Setting, run_experiment
    from contactkit.classify.kinds.kind import ModelOptions
    from contactkit.classify.kinds.registry import get_kind

    for name in ("window.png", "augmentation.json"):
        (tmp_path / name).write_text("mine\n")
    missing = tmp_path / "no-such-dataset"
    with pytest.raises(InputError, match="not a file contactkit wrote") as found:
        run_experiment("window", [missing], tmp_path, Setting())
    assert found.value.path == str(tmp_path / "window.png")
    lstm = get_kind("lstm")
    with pytest.raises(InputError, match="not a file contactkit wrote") as found:
        run_augmentation(missing, missing, tmp_path, kind=lstm, options=ModelOptions("lstm"))
    assert found.value.path == str(tmp_path / "augmentation.json")
    assert owned.check_results(tmp_path / "new", ["window.md"]) == [tmp_path / "new/window.md"]
    (tmp_path / "a file").write_text("")
    with pytest.raises(InputError, match="is not a directory"):
        run_experiment("window", [missing], tmp_path / "a file", Setting())
    (tmp_path / "gridsearch.md").write_text("# mine\n")
    result = run_command("classify", "gridsearch", str(missing), "--out", str(tmp_path))
    assert result.returncode == 2 and "gridsearch.md: exists and is not a file contactkit " \
        "wrote" in result.stderr, result.stderr
    for name, text in (("window.png", "mine\n"), ("gridsearch.md", "# mine\n")):
        assert (tmp_path / name).read_text() == text
