"""One bad session never stops the rest (issue 25): directory commands list each failed
session, process the others and exit with code 2; an import that yields no complete
sample is an error that says why."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import can
import numpy as np
import pytest

from contactkit.cli.classify import app as classify_app
from contactkit.cli.common import run_app
from contactkit.cli.recorder import app as recorder_app
from contactkit.recorder.importers.can_codec import session_frames, session_values
from contactkit.recorder.importers.can_map import load_map
from contactkit.schemas import read_session, write_session
from tests.conftest import make_session


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """Three good no-contact sessions and one without a single complete sample."""
    directory = tmp_path_factory.mktemp("dataset")
    for seed in (3, 4, 5):
        make_session(directory, seed=seed, action="none", duration_s=4.0)
    good = read_session(directory / "none_3.parquet")
    columns = {n: good.column(n).copy() for n in good.table.column_names}
    columns["tau_2"][:] = np.nan
    meta = replace(good.meta, session_id="hollow",
                   source_info={"incomplete_samples": good.n_samples})
    write_session(directory / "hollow.parquet", columns, meta)
    return directory


def _run(app, prog, capsys, *argv) -> tuple[int, str, str]:
    code = run_app(app, prog, [str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("command", ["features", "per-sample", "calibrate", "stats"])
def test_a_session_without_complete_samples_does_not_stop_the_rest(command, dataset,
                                                                   tmp_path, capsys) -> None:
    if command == "stats":
        code, _, err = _run(recorder_app, "recorder", capsys, "stats", dataset, "--deep",
                            "--workers", "1", "--out", tmp_path / "r.json", "--format",
                            "json")
        assert code == 0, err
        assert "hollow.parquet" in (tmp_path / "r.json").read_text()
        return
    out = tmp_path / ("c.json" if command == "calibrate" else "f.parquet")
    argv = {"features": ("features", dataset, "--out", out, "--workers", "2"),
            "per-sample": ("features", dataset, "--per-sample", "--out", out),
            "calibrate": ("calibrate", dataset, "--out", out)}[command]
    code, _, err = _run(classify_app, "classify", capsys, *argv)
    err = " ".join(err.split())  # the console wraps long lines
    assert code == 2, err
    assert "Traceback" not in err and "hollow.parquet" in err and "complete sample" in err
    assert out.is_file()


def test_can_ids_that_do_not_match_the_map_are_an_error_saying_so(tmp_path, capsys) -> None:
    fmap = load_map()
    recorded = read_session(make_session(tmp_path, duration_s=1.0, planned_at_s=0.5))
    log = tmp_path / "other.asc"
    with can.Logger(log) as writer:
        for msg in session_frames(fmap, recorded.t, session_values(recorded.q, recorded.dq,
                                                                   recorded.tau)):
            ident = msg.arbitration_id
            writer.on_message_received(can.Message(
                timestamp=msg.timestamp, data=msg.data, is_extended_id=False,
                arbitration_id=ident if ident == fmap.sync_id else ident + 0x10))
    code, _, err = _run(recorder_app, "recorder", capsys, "import-can", log, "--pose", "C",
                        "--action", "shove", "--out", tmp_path / "o")
    err = " ".join(err.split())
    assert code == 2, err
    assert "no complete sample" in err and "unknown ids" in err and "map" in err, err
    assert not list((tmp_path / "o").glob("*.parquet"))


def test_training_on_one_class_is_one_line(dataset, tmp_path, capsys) -> None:
    """Sessions of a single class cannot train a classifier: one line naming the class,
    exit 2, not scikit-learn's traceback."""
    code, _, err = _run(classify_app, "classify", capsys, "train", dataset, "--out",
                        tmp_path / "m.skops")
    err = " ".join(err.split())
    assert code == 2 and "Traceback" not in err, err
    assert "training needs at least two classes in the data; it has only 'none'" in err
    assert not (tmp_path / "m.skops").exists()


@pytest.mark.parametrize(("flag", "value"), [("--margin", "nan"), ("--margin", "inf"),
                                             ("--margin", "0.5"), ("--motion-margin", "nan")])
def test_calibration_margins_are_checked_before_any_work(flag, value, dataset, tmp_path,
                                                         capsys) -> None:
    code, _, err = _run(classify_app, "classify", capsys, "calibrate", dataset, "--out",
                        tmp_path / "c.json", flag, value)
    assert code == 2 and "Traceback" not in err, err
    assert f"{flag} must be a finite number of at least 1, got {value}" in err
