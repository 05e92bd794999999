"""recorder import-csv: CSV exports with a TOML column map, checked on the MindLab files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from contactkit.recorder.importers import csv_import
from contactkit.recorder.importers.csv_import import CsvImporter, read_csv_columns
from contactkit.recorder.importers.csv_map import load_csv_map, mindlab_map_path
from contactkit.recorder.metadata import session_meta
from contactkit.schemas import InputError, validate_session
from tests.conftest import MINDLAB_FILES, run_command, write_imported

MAP = mindlab_map_path()


def _expected(csv: Path) -> tuple[np.ndarray, int]:
    """Rows kept (first of each run of identical q, dq, tau_J) and the label on them."""
    frame = pl.read_csv(csv)
    cols = [f"{p}{j}" for p in ("q", "dq", "tau_J") for j in range(7)]
    values = frame.select(cols).to_numpy()
    repeated = np.r_[False, (np.diff(values, axis=0) == 0).all(axis=1)]
    return frame["label"].to_numpy()[~repeated] == 1, int(repeated.sum())


def test_import_csv_of_every_mindlab_file(mindlab_dir: Path, tmp_path: Path) -> None:
    files = [str(mindlab_dir / f"{name}.csv") for name in MINDLAB_FILES]
    result = run_command("recorder", "import-csv", *files, "--map", str(MAP), "--out",
                         str(tmp_path))
    assert result.returncode == 0, result.stderr
    paths = result.stdout.split()
    assert len(paths) == len(files)
    for csv, path in zip(files, paths, strict=True):
        session = validate_session(path)
        label, repeated = _expected(Path(csv))
        info = session.meta.source_info
        assert info["repeated_rows"] == repeated > 0.4 * info["rows"]
        assert info["samples"] == session.n_samples == info["rows"] - repeated
        assert session.meta.source == "csv" and session.meta.with_hand
        assert np.array_equal(session.column("contact"), label)
        assert 0 < label.mean() < 1
        assert 95 < session.meta.nominal_rate_hz < 105
        assert session.has("tau_ext_hat_1") and session.has("q_d_7")
        assert (np.diff(session.t) > 0).all() and session.t[0] == 0.0


def test_units_sign_and_kept_rows(tmp_path: Path) -> None:
    csv = tmp_path / "log.csv"
    header = ["ms"] + [f"{p}{j}" for p in ("pos", "vel", "trq", "ext") for j in range(1, 8)]
    rows = [[0.0] + [1.0] * 28, [1.0] + [1.0] * 28, [2.0] + [2.0] * 28]
    csv.write_text("\n".join(";".join(map(str, r)) for r in [header, *rows]) + "\n")
    cmap_path = tmp_path / "map.toml"
    cmap_path.write_text('delimiter = ";"\n[time]\ncolumn = "ms"\nunit = "ms"\n'
                         '[q]\ncolumns = "pos{j}"\nunit = "deg"\n[dq]\ncolumns = "vel{j}"\n'
                         '[tau]\ncolumns = "trq{j}"\nunit = "mNm"\n'
                         '[tau_ext_hat]\ncolumns = "ext{j}"\nsign = -1\n')
    columns, counts = read_csv_columns(csv, load_csv_map(cmap_path))
    assert counts == {"rows": 3, "repeated_rows": 1, "samples": 2}
    assert np.allclose(columns["t"], [0.0, 0.002])
    assert np.isclose(columns["q_3"][1], np.deg2rad(2.0))
    assert np.isclose(columns["tau_7"][0], 1e-3) and columns["tau_ext_hat_1"][1] == -2.0
    assert "contact" not in columns


def _write_map(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    return path


GOOD_MAP = ('index_base = 0\n[time]\ncolumn = "time"\n[q]\ncolumns = "q{j}"\n'
            '[dq]\ncolumns = "dq{j}"\n[tau]\ncolumns = "tau_J{j}"\n')


@pytest.mark.parametrize("text, problem", [
    ("not = [toml", "not a valid TOML"),
    ('[time]\ncolumn = "time"\n[q]\ncolumns = "q{j}"\n[dq]\ncolumns = "dq{j}"\n',
     "no columns for tau"),
    (GOOD_MAP.replace("index_base = 0", "index_base = 2"), "index_base must be 0 or 1"),
    (GOOD_MAP.replace('"q{j}"', '"q"'), "lacks {j}"),
    (GOOD_MAP.replace('"q{j}"', '["q0", "q1"]'), "q needs 7 columns"),
    (GOOD_MAP + 'unit = "furlong"\n', "tau unit must be Nm or mNm, got 'furlong'"),
    (GOOD_MAP.replace('column = "time"', 'column = "time"\nunit = "h"'),
     "time unit must be s, ms, us or ns, got 'h'"),
    (GOOD_MAP + "sign = -1\n", "tau sign must be 1"),
    (GOOD_MAP + "[frobnicate]\n", "unknown key 'frobnicate'"),
    (GOOD_MAP.replace('column = "time"', 'col = "time"'), "missing key 'column'"),
    (GOOD_MAP.replace('[time]\ncolumn = "time"\n', 'time = 5\n'), "[time] must be a table"),
])
def test_bad_map(tmp_path: Path, text: str, problem: str) -> None:
    path = _write_map(tmp_path, text)
    with pytest.raises(InputError, match=r"bad column map|not a valid TOML") as err:
        load_csv_map(path)
    assert problem in str(err.value) and str(err.value).startswith(str(path))


def _mindlab_like(tmp_path: Path, mindlab_dir: Path, edit) -> Path:
    frame = pl.read_csv(mindlab_dir / "a4.csv", n_rows=50, infer_schema=False)
    path = tmp_path / "broken.csv"
    edit(frame).write_csv(path)
    return path


@pytest.mark.parametrize("edit, problem", [
    (lambda f: f.drop("tau_J3"), "no column 'tau_J3' (tau joint 4 in the map)"),
    (lambda f: f.with_columns(pl.when(pl.col("index") == "7").then(pl.lit("x"))
                              .otherwise(pl.col("dq2")).alias("dq2")),
     "column 'dq2' (dq joint 3) holds 'x' at data row 7"),
    (lambda f: f.with_columns(pl.when(pl.col("index") == "9").then(pl.lit(""))
                              .otherwise(pl.col("q0")).alias("q0")),
     "column 'q0' (q joint 1) holds"),
    (lambda f: f.with_columns(pl.when(pl.col("index") == "4").then(pl.lit("2"))
                              .otherwise(pl.col("label")).alias("label")),
     "column 'label' (contact label) holds 2 at data row 4"),
    (lambda f: f.with_columns(pl.when(pl.col("index") == "20").then(pl.lit("0.0"))
                              .otherwise(pl.col("time")).alias("time")),
     "column 'time' (time) does not increase at data row 20"),
])
@pytest.mark.parametrize("block_rows", [6, csv_import.BLOCK_ROWS])
def test_bad_csv(mindlab_dir: Path, tmp_path: Path, edit, problem: str, block_rows: int,
                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(csv_import, "BLOCK_ROWS", block_rows)  # rows counted across blocks
    path = _mindlab_like(tmp_path, mindlab_dir, edit)
    with pytest.raises(InputError) as err:
        read_csv_columns(path, load_csv_map(MAP))
    assert str(err.value).startswith(f"{path}: ") and problem in str(err.value)


def test_bad_input_exits_2_with_one_line(mindlab_dir: Path, tmp_path: Path) -> None:
    broken = _mindlab_like(tmp_path, mindlab_dir, lambda f: f.drop("q6"))
    bad_map = _write_map(tmp_path, GOOD_MAP.replace("index_base = 0", "index_base = 5"))
    for args, needle in [((str(broken), "--map", str(MAP)), "no column 'q6'"),
                         ((str(mindlab_dir / "a4.csv"), "--map", str(bad_map)),
                          "index_base must be 0 or 1")]:
        result = run_command("recorder", "import-csv", *args, "--out", str(tmp_path / "o"))
        assert result.returncode == 2, result.stderr
        assert needle in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_import_refuses_to_overwrite(mindlab_dir: Path, tmp_path: Path) -> None:
    meta = session_meta(source="csv", action="none")
    path = write_imported(CsvImporter.read(mindlab_dir / "d3.csv", load_csv_map(MAP)), meta,
                          tmp_path)
    with pytest.raises(InputError, match="already exists"):
        write_imported(CsvImporter.read(mindlab_dir / "d3.csv", load_csv_map(MAP)), meta,
                       tmp_path)
    assert path.name.startswith("d3_static_x_none_")


def test_streamed_import_does_not_depend_on_the_block(mindlab_dir: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The file is parsed and written a block at a time: blocks of 7 rows give the
    table and counts of one block for the whole file (repeated rows across blocks, a
    quoted field over two lines)."""
    frame = pl.read_csv(mindlab_dir / "a4.csv", infer_schema=False)
    notes = [f"line one\nline two, {i}" if i % 50 == 3 else "" for i in range(frame.height)]
    csv = tmp_path / "a4_notes.csv"
    frame.with_columns(pl.Series("note", notes)).write_csv(csv)
    written = []
    for block_rows in (7, 1_000_000):
        monkeypatch.setattr(csv_import, "BLOCK_ROWS", block_rows)
        meta = session_meta(source="csv", action="none", condition="static", pose="A")
        out = tmp_path / str(block_rows)
        out.mkdir()
        written.append(validate_session(write_imported(CsvImporter.read(csv, load_csv_map(MAP)),
                                                       meta, out)))
    assert written[0].table.equals(written[1].table)
    assert written[0].meta.source_info == written[1].meta.source_info
    assert written[0].meta.nominal_rate_hz == written[1].meta.nominal_rate_hz
    assert written[0].n_samples == written[0].meta.source_info["samples"] > 1000
