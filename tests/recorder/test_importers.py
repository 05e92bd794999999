"""Importers as registered readers: the registry, one `recorder import` command with the
old verbs as aliases, and a tiny plugin format registered through an entry point and
imported end to end."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from contactkit.recorder.importers.jobs import ImportJob, format_options, import_file, protocol_from
from contactkit.recorder.importers.registry import (
    IMPORTERS,
    importer_class,
    importer_for,
    registered_importers,
)
from contactkit.schemas import InputError, validate_session
from tests.conftest import make_session

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[2]

# One module: a toy text format (a line per sample: t [s], then q, dq, tau of joints 1-7).
PLUGIN = '''
"""Toy text recordings, for contactkit's importer registry."""

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from contactkit.errors import InputError
from contactkit.recorder.importers.base import Importer

if os.environ.get("TOY_IMPORTED"):
    Path(os.environ["TOY_IMPORTED"]).touch()


class ToyImporter(Importer):
    """A line per sample: t [s], then q [rad], dq [rad/s] and tau [Nm] of joints 1-7."""

    name = "toy"
    source = "toy-text"
    suffixes = (".toy",)
    description = "Toy text, a line per sample."

    @dataclass(frozen=True)
    class Config:
        scale: float = field(default=1.0, metadata={"help": "Multiply the torques by this."})

    def __init__(self, rows, path, scale):
        self.rows, self.path, self.scale = rows, path, scale

    @classmethod
    def open(cls, path, config):
        try:
            rows = np.loadtxt(path, ndmin=2)
        except ValueError as err:
            raise InputError("not toy text", path) from err
        if rows.shape[1] != 22:
            raise InputError(f"{rows.shape[1]} values a line, expected 22", path)
        return cls(rows, path, config.scale)

    def times(self):
        yield self.rows[:, 0]

    def chunks(self):
        for start in range(0, len(self.rows), 4):
            block = self.rows[start:start + 4]
            columns = {"t": block[:, 0]}
            for k, prefix in enumerate(("q", "dq", "tau")):
                factor = self.scale if prefix == "tau" else 1.0
                for j in range(7):
                    columns[f"{prefix}_{j + 1}"] = block[:, 1 + 7 * k + j] * factor
            yield columns

    def source_info(self):
        return {"toy": str(self.path), "samples": len(self.rows)}
'''


@pytest.fixture(scope="module")
def toy_site(tmp_path_factory) -> Path:
    """A folder for PYTHONPATH holding the toy plugin and its one entry-point line."""
    site = tmp_path_factory.mktemp("site")
    (site / "toyformat.py").write_text(textwrap.dedent(PLUGIN))
    dist = site / "toyformat-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: toyformat\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[contactkit.importers]\ntoy = toyformat:ToyImporter\nbroken = no_such_module:X\n")
    return site


def _recorder(site: Path, *args: str, marker: Path | None = None
              ) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(site), COLUMNS="200")
    if marker is not None:
        env["TOY_IMPORTED"] = str(marker)
    return subprocess.run([str(BIN / "recorder"), *map(str, args)], capture_output=True,
                          text=True, env=env, timeout=300)


def test_plugin_importer_end_to_end(toy_site: Path, tmp_path: Path) -> None:
    t = np.arange(10) * 0.002 + 5.0
    rows = np.column_stack([t, *[np.full(10, 0.1 * j) for j in range(1, 22)]])
    rows[:, 8] = np.linspace(0, 0.9, 10)  # dq_1
    toy = tmp_path / "run.toy"
    np.savetxt(toy, rows)
    marker = tmp_path / "imported"
    assert _recorder(toy_site, "import", "--help", marker=marker).returncode == 0
    assert not marker.exists(), "--help imported the plugin"

    result = _recorder(toy_site, "import", toy, "--pose", "B", "--action", "bump", "--link",
                       "3", "--option", "scale=2", "--out", tmp_path / "out", marker=marker)
    assert result.returncode == 0, result.stderr
    assert marker.exists()
    session = validate_session(result.stdout.strip())
    assert session.n_samples == 10 and session.t[0] == 0.0
    assert np.allclose(session.t, t - 5.0)
    assert np.allclose(session.dq[:, 0], rows[:, 8])
    assert np.allclose(session.tau, 2 * rows[:, 15:22])
    meta = session.meta
    assert (meta.source, meta.pose, meta.action, meta.link) == ("toy-text", "B", "bump", 3)
    assert meta.source_info == {"toy": str(toy), "samples": 10}
    assert meta.nominal_rate_hz == 500.0
    assert f"{toy}: samples 10" in result.stderr

    listing = _recorder(toy_site, "importers")
    assert listing.returncode == 0, listing.stderr
    assert "toy: Toy text, a line per sample. (.toy)" in listing.stdout
    assert "--option scale=VALUE" in listing.stdout and "broken: unusable" in listing.stdout

    (tmp_path / "bad.toy").write_text("1 2 3\n")
    bad = _recorder(toy_site, "import", tmp_path / "bad.toy", "--out", tmp_path / "out")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert bad.stderr.strip() == f"recorder: error: {tmp_path / 'bad.toy'}: 3 values a " \
                                 "line, expected 22"
    wrong = _recorder(toy_site, "import", toy, "--map", toy, "--out", tmp_path / "out")
    assert wrong.returncode == 2 and "format 'toy' takes no option 'map'" in wrong.stderr
    typed = _recorder(toy_site, "import", toy, "--option", "scale=twice", "--out",
                      tmp_path / "out")
    assert typed.returncode == 2 and "Traceback" not in typed.stderr
    assert "import format 'toy': scale must be float, got 'twice'" in typed.stderr


def test_registry_chooses_by_suffix_or_name(tmp_path: Path) -> None:
    assert list(registered_importers())[:4] == list(IMPORTERS)
    for name, suffix in (("csv", ".csv"), ("can", ".asc"), ("can", ".BLF"), ("bag", ".mcap"),
                         ("bag", ".bag")):
        assert importer_for(tmp_path / f"x{suffix}").name == name
    ros2 = tmp_path / "ros2"
    ros2.mkdir()
    (ros2 / "metadata.yaml").write_text("")
    assert importer_for(ros2).name == "bag"
    with pytest.raises(InputError, match=r"no import format reads '\.xyz' files"):
        importer_for(tmp_path / "x.xyz")
    with pytest.raises(InputError, match="unknown import format 'nope'"):
        importer_class("nope")
    for name in IMPORTERS:
        cls = importer_class(name)
        assert cls.name == name and cls.source and cls.__doc__


def test_protocol_and_format_options() -> None:
    assert protocol_from({"pose": "B", "link": None}, ["with_hand=false", "pose_q=[1]"]) == \
        {"pose": "B", "with_hand": False, "pose_q_rad": [1]}
    with pytest.raises(InputError, match="--meta pose='C' disagrees"):
        protocol_from({"pose": "B"}, ["pose=C"])
    assert format_options({"map": None, "topic": "/j"}, ["label-topic=/l"]) == \
        {"topic": "/j", "label_topic": "/l"}
    with pytest.raises(InputError, match="bad format option"):
        format_options({}, ["novalue"])


def test_every_importer_streams_through_the_one_writer(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch
                                                       ) -> None:
    """No importer module writes a session itself: the only session writer they reach is
    write_imported_chunks, which import_file calls."""
    folder = ROOT / "recorder" / "importers"
    for path in folder.glob("*.py"):
        if path.name == "writer.py":
            continue
        names = {n.id if isinstance(n, ast.Name) else n.attr
                 for n in ast.walk(ast.parse(path.read_text()))
                 if isinstance(n, ast.Name | ast.Attribute)}
        assert not names & {"write_session", "write_session_batches",
                            "write_imported_session"}, path.name
    from contactkit.recorder.importers import writer

    calls = []
    real = writer.write_imported_chunks
    monkeypatch.setattr(writer, "write_imported_chunks",
                        lambda *a, **k: calls.append(a[2].source) or real(*a, **k))
    session = validate_session(make_session(tmp_path, duration_s=0.5, planned_at_s=0.2))
    from contactkit.recorder.importers.can_map import load_map
    from contactkit.recorder.importers.can_tools import bridge_session

    bridge_session(session, load_map(), log=tmp_path / "x.asc")
    (tmp_path / "out").mkdir()
    written = import_file(ImportJob(tmp_path / "x.asc", tmp_path / "out",
                                    {"pose": "C", "action": "shove"}))
    assert calls == ["can-log"]
    assert validate_session(written.session).n_samples == session.n_samples
    assert "samples" in written.summary


def _recorder_here(capsys: pytest.CaptureFixture, *argv: object) -> tuple[int, str, str]:
    from contactkit.cli.common import run_app
    from contactkit.cli.recorder import app

    code = run_app(app, "recorder", [str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, " ".join(err.split())


def test_one_command_many_files_and_the_aliases(tmp_path: Path,
                                                capsys: pytest.CaptureFixture) -> None:
    """Several files: each bad one listed, the others written, exit code 2; the old verbs
    are the same command with the format fixed; the protocol options and --meta agree."""
    rows = 40
    files = {}
    for key, values in {"t": 0.002 * np.arange(rows)[:, None], "q": np.zeros((rows, 7)),
                        "dq": np.zeros((rows, 7)), "tau": np.ones((rows, 7))}.items():
        np.savetxt(tmp_path / f"{key}.txt", values)
        files[key] = tmp_path / f"{key}.txt"
    joints = ["--q", files["q"], "--dq", files["dq"], "--tau", files["tau"]]
    out = tmp_path / "out"
    code, stdout, err = _recorder_here(capsys, "import-arrays", "--t", files["t"], *joints,
                                       "--pose", "C", "--action", "bump", "--no-hand",
                                       "--meta", "speed_rad_s=0.5", "--out", out)
    assert code == 0, err
    meta = validate_session(stdout.strip()).meta
    assert (meta.source, meta.pose, meta.action, meta.with_hand, meta.speed_rad_s) == \
        ("arrays", "C", "bump", False, 0.5)
    assert meta.nominal_rate_hz == 500.0

    (tmp_path / "short.txt").write_text("0\n0.002\n")
    code, stdout, err = _recorder_here(capsys, "import", files["t"], tmp_path / "short.txt",
                                       "--format", "arrays", *joints, "--out", out,
                                       "--workers", "1")
    assert code == 2
    assert len(stdout.split()) == 1 and validate_session(stdout.strip()).n_samples == rows
    assert f"skipped {tmp_path / 'short.txt'}" in err and "1 of 2 files imported" in err

    code, _, err = _recorder_here(capsys, "import-csv", files["t"], "--format", "bag")
    assert code == 2 and "import-csv reads format csv" in err
    code, _, err = _recorder_here(capsys, "import", files["t"], *joints, "--format", "arrays",
                                  "--pose", "C", "--meta", "pose=D", "--out", out)
    assert code == 2 and "--meta pose='D' disagrees" in err
    code, _, err = _recorder_here(capsys, "import", tmp_path, "--out", out)
    assert code == 2 and "give --format" in err


def test_format_options_are_typed_and_required_ones_named(tmp_path: Path) -> None:
    from contactkit.recorder.importers.jobs import open_importer

    with pytest.raises(InputError, match=r"import format 'arrays' needs the option\(s\) "
                                         "q, dq, tau"):
        open_importer(tmp_path / "t.txt", "arrays")
    with pytest.raises(InputError, match="import format 'csv' needs the option"):
        open_importer(tmp_path / "x.csv")
    with pytest.raises(InputError, match="import format 'bag' takes no option 'scale' "
                                         r"\(its options: topic, label_topic\)"):
        open_importer(tmp_path / "x.bag", options={"scale": "2"})
