"""Hostile input and hostile conditions: no escape from the output directory, no crash,
nothing lost (issue 16). Long-running variants are marked ``slow``."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from contactkit.cli.common import run_app
from contactkit.cli.recorder import app
from contactkit.recorder.capture import journal
from contactkit.recorder.capture.journal import SessionWriter, journal_path, recover_directory
from contactkit.recorder.sim import dataset
from contactkit.recorder.sim.simulator import SimConfig, plan_session
from contactkit.recorder.sources.sim import SimSource, sim_session_id
from contactkit.schemas import InputError, SessionMeta, validate_session
from contactkit.schemas.session import METADATA_KEY
from contactkit.util.paths import inside, safe_name
from tests.conftest import BIN, run_cli


def recorder(capsys, *argv: str) -> tuple[int, str, str]:
    """Run ``recorder`` in this process; return exit code, stdout and stderr."""
    code = run_app(app, "recorder", [str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code: int, err: str, text: str) -> None:
    assert code == 2, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert text in err, err


def _rows(t0: float, n: int, step: float = 0.001) -> dict[str, np.ndarray]:
    t = t0 + step * np.arange(n)
    cols = {"t": t}
    for prefix in ("q", "dq", "tau"):
        for i in range(1, 8):
            cols[f"{prefix}_{i}"] = np.sin(t * i)
    return cols


COLUMNS = list(_rows(0, 1))
META = SessionMeta(session_id="hostile", source="sim", action="bump")


@pytest.fixture
def arrays(tmp_path: Path) -> list[str]:
    """Plain-array files of a 50-sample recording, as ``import-arrays`` options."""
    rows = _rows(0, 50)
    files = {"t": rows["t"][:, None]}
    for prefix in ("q", "dq", "tau"):
        files[prefix] = np.column_stack([rows[f"{prefix}_{i}"] for i in range(1, 8)])
    args = []
    for key, values in files.items():
        path = tmp_path / f"{key}.txt"
        np.savetxt(path, values)
        args += [f"--{key}", str(path)]
    return args


# -- path escape -----------------------------------------------------------------------

def test_safe_name_and_inside_refuse_escapes(tmp_path: Path) -> None:
    for bad in ("../x", "a/b", "..", ".hidden", "-rf", "", "a\0b", "x" * 201, "a b"):
        with pytest.raises(InputError):
            safe_name(bad)
    assert safe_name("static_A_bump_0123.parquet") == "static_A_bump_0123.parquet"
    for bad in ("../evil.parquet", "/etc/passwd", "", ".", "sub/../../x"):
        with pytest.raises(InputError):
            inside(tmp_path / "out", bad)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "link").symlink_to(tmp_path)
    with pytest.raises(InputError, match="outside"):
        inside(tmp_path / "out", "link/evil.parquet")
    assert inside(tmp_path / "out", "s.parquet") == (tmp_path / "out" / "s.parquet").resolve()


def test_import_name_cannot_escape_the_output_directory(tmp_path, arrays, capsys) -> None:
    out = tmp_path / "imp" / "y"
    code, _, err = recorder(capsys, "import-arrays", *arrays, "--out", out,
                            "--name", "../../evil.parquet")
    one_line_error(code, err, "unsafe output name")
    assert not list(tmp_path.rglob("evil*")) and not any(out.iterdir())


@pytest.mark.parametrize("pair", ["pose=../../evil", "target_pose=a/b", "session_id=../x",
                                  "link=9", "planned_at_s=1e12", "planned_at_s=NaN",
                                  "pose_q=[1, 2]", "speed_rad_s=-1", "link=\"3\""])
def test_import_metadata_outside_its_domain_is_refused(tmp_path, arrays, capsys,
                                                       pair: str) -> None:
    out = tmp_path / "imp"
    code, _, err = recorder(capsys, "import-arrays", *arrays, "--out", out, "--meta", pair)
    one_line_error(code, err, "metadata")
    assert not list(tmp_path.rglob("*.parquet")) and not list(tmp_path.rglob("*evil*"))


def test_import_writes_inside_with_a_safe_pose_name(tmp_path, arrays, capsys) -> None:
    code, out, err = recorder(capsys, "import-arrays", *arrays, "--out", tmp_path / "imp",
                              "--meta", "pose=lab_pose-3", "--meta", "planned_at_s=0.02")
    assert code == 0, err
    path = Path(out.strip())
    assert path.parent == (tmp_path / "imp").resolve() and "lab_pose-3" in path.name
    assert validate_session(path).n_samples == 50


def _with_meta(source: Path, target: Path, **changes) -> Path:
    table = pq.read_table(source)
    doc = json.loads(table.schema.metadata[METADATA_KEY]) | changes
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: json.dumps(doc).encode()}),
                   target)
    return target


def test_info_rejects_what_replay_would_choke_on(session_path: Path, tmp_path, capsys) -> None:
    for changes, text in (({"planned_at_s": 1e12}, "planned_at_s"),
                          ({"pose": "../../evil"}, "not a pose name"),
                          ({"link": "seven"}, "link has the wrong type"),
                          ({"source_info": {"incomplete_samples": "many"}}, "not a count")):
        bad = _with_meta(session_path, tmp_path / "bad.parquet", **changes)
        code, _, err = recorder(capsys, "info", bad)
        one_line_error(code, err, text)


# -- simulate never loses a batch --------------------------------------------------------

def _specs(n: int) -> list:
    return [plan_session(seed=k, condition="static", action="bump", pose="A", duration_s=1.0,
                         planned_at_s=0.5) for k in range(n)]


def test_one_failing_session_is_reported_and_the_batch_is_written(tmp_path, monkeypatch
                                                                   ) -> None:
    real = dataset.write_session
    config = SimConfig(rate_hz=100.0)
    specs = _specs(4)
    doomed = sim_session_id(specs[1], config)

    def failing(path, data, meta, **kw):
        if meta.session_id == doomed:
            raise InputError("NaN in column 'tau_3' at row 7", path)
        return real(path, data, meta, **kw)

    monkeypatch.setattr(dataset, "write_session", failing)
    paths, problems = dataset.simulate_batch(specs, config, tmp_path)
    assert len(paths) == 3 and all(validate_session(p) for p in paths)
    ((name, problem),) = problems
    assert doomed[:12] in name and "NaN" in problem


def test_a_batch_whose_simulation_fails_is_rerun_one_by_one(tmp_path, monkeypatch) -> None:
    real = dataset._simulated
    config = SimConfig(rate_hz=100.0)
    specs = _specs(3)

    def diverging(batch, cfg):
        if any(spec.seed == 2 for spec in batch):
            raise FloatingPointError("simulation diverged")
        yield from real(batch, cfg)

    monkeypatch.setattr(dataset, "_simulated", diverging)
    paths, problems = dataset.simulate_batch(specs, config, tmp_path)
    assert len(paths) == 2 and len(problems) == 1 and "diverged" in problems[0][1]


def test_simulate_cli_reports_the_failure_and_writes_the_rest(tmp_path, monkeypatch,
                                                             capsys) -> None:
    real = dataset.write_session
    monkeypatch.setattr(dataset, "write_session", lambda path, data, meta, **kw: (
        (_ for _ in ()).throw(InputError("boom", path)) if (meta.pose, meta.action) == ("B", "bump")
        else real(path, data, meta, **kw)))
    code, _, err = recorder(capsys, "simulate", tmp_path, "--sessions", "4",
                              "--workers", "1", "--rate", "100")
    assert code == 2 and "Traceback" not in err
    assert "3 written" in err and "1 failed" in err and "boom" in err
    assert pq.read_table(tmp_path / "index.parquet").num_rows == 3


# -- disk full, read-only directory --------------------------------------------------------

class _FillingFile:
    """A journal file that runs out of space after ``room`` bytes (ENOSPC)."""

    def __init__(self, path, mode, room: int) -> None:
        self._file = open(path, mode)  # noqa: SIM115
        self.room = room

    def write(self, data) -> int:
        if len(data) > self.room:
            self._file.write(bytes(data)[:self.room])
            self.room = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.room -= len(data)
        return self._file.write(data)

    def __getattr__(self, name):
        return getattr(self._file, name)


def test_disk_full_stops_the_capture_and_flushed_samples_recover(tmp_path, monkeypatch,
                                                                  capsys) -> None:
    monkeypatch.setattr(journal, "open", lambda path, mode: _FillingFile(path, mode, 300_000),
                        raising=False)
    out = tmp_path / "d"
    code, _, err = recorder(capsys, "capture", "--pose", "A", "--action", "bump", "--seed",
                            "4", "--duration", "6", "--planned-at", "3", "--rate", "1000",
                            "--out", out)
    one_line_error(code, err, "No space left on device")
    assert "kept for `recorder recover`" in err
    safe = int(err.split("its ")[1].split(" samples")[0])
    assert safe > 0 and not list(out.glob("*.parquet"))
    monkeypatch.undo()
    (recovery,) = recover_directory(out)
    session = validate_session(recovery.session)
    assert session.n_samples == safe and session.meta.recovered


@pytest.mark.slow
def test_disk_full_on_a_real_small_filesystem(tmp_path: Path) -> None:
    target = tmp_path / "small"
    target.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(target)],
                             capture_output=True)
    if mounted.returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    try:
        result = run_cli("recorder", "capture", "--pose", "A", "--action", "bump", "--seed",
                         "4", "--duration", "30", "--planned-at", "3", "--rate", "1000",
                         "--out", str(target))
        one_line_error(result.returncode, result.stderr, "No space left on device")
        safe = int(result.stderr.split("its ")[1].split(" samples")[0])
        rescue = tmp_path / "rescue"
        rescue.mkdir()
        (journal_file,) = target.glob("*.journal")
        (rescue / journal_file.name).write_bytes(journal_file.read_bytes())
    finally:
        subprocess.run(["umount", str(target)], check=False)
    (recovery,) = recover_directory(rescue)
    assert validate_session(recovery.session).n_samples == safe > 0


def _read_only_dir(tmp_path: Path) -> Path:
    """A directory this process cannot write into (a read-only mount for root)."""
    target = tmp_path / "ro"
    target.mkdir()
    if os.geteuid() != 0:
        target.chmod(0o555)
        return target
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs",
                              str(target)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip("running as root without permission to mount a read-only tmpfs")
    return target


def test_read_only_directory_fails_before_the_source_starts(tmp_path, monkeypatch,
                                                             capsys) -> None:
    target = _read_only_dir(tmp_path)
    started = []
    monkeypatch.setattr(SimSource, "stream", lambda self: started.append(1) or iter(()))
    try:
        code, _, err = recorder(capsys, "capture", "--pose", "A", "--action", "bump",
                                "--out", target)
        one_line_error(code, err, "cannot write here")
        assert not started
    finally:
        if os.geteuid() == 0:
            subprocess.run(["umount", str(target)], check=False)


# -- recover: live journals, twice, torn records ---------------------------------------------

def test_recover_leaves_a_live_capture_alone_and_runs_twice_safely(tmp_path: Path) -> None:
    out = tmp_path / "s.parquet"
    writer = SessionWriter(out, META, COLUMNS, flush_interval_s=0.02)
    writer.append(_rows(0, 100))
    (live,) = recover_directory(tmp_path)
    assert live.session is None and "live capture" in live.note
    writer.append(_rows(0.1, 100))
    assert writer.close() == out and validate_session(out).n_samples == 200
    assert recover_directory(tmp_path) == []
    assert validate_session(out).n_samples == 200 and not validate_session(out).meta.recovered


def test_recover_twice_neither_duplicates_nor_changes(tmp_path: Path) -> None:
    out = tmp_path / "s.parquet"
    writer = SessionWriter(out, META, COLUMNS, flush_interval_s=0.02)
    writer.append(_rows(0, 100))
    writer.abort()
    (first,) = recover_directory(tmp_path)
    before = out.read_bytes()
    assert recover_directory(tmp_path) == []
    assert out.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == [
        "s.parquet"]
    assert first.samples == 100


def test_torn_journal_recovers_every_complete_batch_at_every_cut(tmp_path: Path) -> None:
    source = tmp_path / "src"
    source.mkdir()
    out = source / "s.parquet"
    writer = SessionWriter(out, META, COLUMNS, flush_interval_s=0.02)
    for k in range(4):
        writer.append(_rows(k * 0.02, 20))
    writer.abort()
    whole = journal_path(out).read_bytes()
    complete = {}
    for cut in [*range(0, len(whole), 97), len(whole)]:
        directory = tmp_path / f"cut{cut}"
        directory.mkdir()
        journal_path(directory / "s.parquet").write_bytes(whole[:cut])
        (recovery,) = recover_directory(directory)
        if recovery.session is not None:
            session = validate_session(recovery.session)
            assert np.allclose(session.t, 0.001 * np.arange(session.n_samples))
            assert session.n_samples % 20 == 0
            complete[cut] = session.n_samples
    assert complete[max(complete)] == 80 and sorted(complete.values()) == list(
        complete[c] for c in sorted(complete))


# -- concurrent writers ------------------------------------------------------------------------

def test_two_concurrent_captures_into_one_directory(tmp_path: Path) -> None:
    common = ["capture", "--pose", "B", "--action", "bump", "--duration", "3",
              "--planned-at", "1.5", "--rate", "500", "--out", str(tmp_path)]
    commands = [[str(BIN / "recorder"), *common, "--seed", seed] for seed in ("1", "2", "1")]
    procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for c in commands]
    results = [(p.wait(timeout=300), p.stdout.read(), p.stderr.read()) for p in procs]
    for proc in procs:
        proc.stdout.close()
        proc.stderr.close()
    codes = sorted(code for code, _, _ in results)
    assert codes == [0, 0, 2], results
    refused = next(err for code, _, err in results if code == 2)
    assert "already exists" in refused or "another capture" in refused, refused
    files = sorted(tmp_path.glob("*.parquet"))
    assert len(files) == 2 and not list(tmp_path.glob("*.journal"))
    assert [validate_session(f).n_samples for f in files] == [1501, 1501]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


# -- interrupted simulate and stats ------------------------------------------------------------

def _interrupt_when(command: list[str], ready, sig: int, timeout_s: float = 240) -> int:
    """Start ``command``, send ``sig`` once ``ready()`` holds; return the exit code."""
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + timeout_s
    try:
        while not ready() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        proc.send_signal(sig)
    finally:
        code = proc.wait(timeout=60)
    return code


@pytest.mark.parametrize("sig", [signal.SIGKILL,
                                 pytest.param(signal.SIGINT, marks=pytest.mark.slow)])
def test_interrupted_simulate_leaves_whole_sessions_and_a_rerun_completes(tmp_path: Path,
                                                                           sig: int) -> None:
    command = [str(BIN / "recorder"), "simulate", str(tmp_path), "--sessions", "6",
               "--workers", "1", "--rate", "200"]
    code = _interrupt_when(command, lambda: len(list(tmp_path.glob("static_*.parquet"))) >= 2,
                           sig)
    assert code in (-signal.SIGKILL, 130, -signal.SIGINT, 0), code
    for path in tmp_path.glob("*.parquet"):
        if path.name != "index.parquet":
            validate_session(path)
    again = run_cli("recorder", "simulate", str(tmp_path), "--sessions", "6", "--workers",
                    "1", "--rate", "200")
    assert again.returncode == 0, again.stderr
    assert pq.read_table(tmp_path / "index.parquet").num_rows == 6
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_interrupted_stats_leaves_no_half_written_report(tmp_path: Path) -> None:
    data = tmp_path / "data"
    assert run_cli("recorder", "simulate", str(data), "--sessions", "4", "--workers", "1",
                   "--rate", "200").returncode == 0
    report = tmp_path / "report.json"
    command = [str(BIN / "recorder"), "stats", str(data), "--deep", "--workers", "1",
               "--format", "json", "--out", str(report)]
    _interrupt_when(command, lambda: any(tmp_path.glob(".report.json.*")) or report.exists(),
                    signal.SIGKILL)
    if report.exists():
        json.loads(report.read_text())
    # the killed run may have finished its report first: --out is replaced only when asked
    again = run_cli("recorder", *command[1:], "--overwrite")
    assert again.returncode == 0, again.stderr
    assert json.loads(report.read_text())["sessions"] == 4
