"""Feature matrices: scikit-learn transformer, dataset tables, and the features command."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from sklearn.base import clone
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

from contactkit.features.extract import SessionFeatures, feature_rows
from contactkit.recorder.importers import arrays
from contactkit.schemas import InputError, read_session
from contactkit.schemas.features import read_feature_table
from tests.conftest import import_array_files, make_session, run_command


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("small")
    for seed in range(8):
        action = ("none", "bump", "adjust", "shove")[seed % 4]
        make_session(directory, seed=seed, action=action, link=(seed % 7) + 1, duration_s=4.0,
                     planned_at_s=2.5, rate_hz=500.0)
    return directory


def test_transformer_names_and_pipeline(small_dataset: Path) -> None:
    files = sorted(small_dataset.glob("*.parquet"))
    extractor = SessionFeatures()
    names = list(extractor.get_feature_names_out())
    assert len(names) == 21 and names[0] == "range(dq_1)" and names[-1] == "range(r_7)"
    X = extractor.fit_transform(files)
    assert X.shape == (8, 21) and np.isfinite(X).all()
    labels = [f.name.split("_")[0] for f in files]
    model = make_pipeline(clone(extractor), StandardScaler(), SVC()).fit(files, labels)
    assert set(model.predict(files[:3])) <= set(labels)
    wide = SessionFeatures(timeseries=["model", "workspace"], scalars=["mean", "fft"],
                           window="fixed")
    assert "fft2(m_norm)" in wide.get_feature_names_out()
    assert wide.fit_transform(files[:2]).shape == (2, len(wide.get_feature_names_out()))


def test_bad_parameters_are_input_errors() -> None:
    with pytest.raises(InputError, match="unknown timeseries feature 'torque'"):
        SessionFeatures(timeseries=["torque"]).fit(None)
    with pytest.raises(InputError, match="unknown scalar feature 'median'"):
        SessionFeatures(scalars=["median"]).fit(None)


def test_parallel_rows_equal_serial_and_bad_files_are_listed(small_dataset: Path,
                                                            tmp_path: Path) -> None:
    files = sorted(small_dataset.glob("*.parquet"))
    broken = tmp_path / "broken.parquet"
    broken.write_bytes(b"nope")
    serial = feature_rows(files, SessionFeatures(), workers=1)
    parallel = feature_rows([*files, broken], SessionFeatures(), workers=2)
    assert serial.problems == []
    ((name, problem),) = parallel.problems
    assert name == "broken.parquet" and "not a readable Parquet file" in problem
    assert serial.info == parallel.info and np.array_equal(serial.X, parallel.X)


def test_features_command_on_dataset_and_per_sample(small_dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "features.parquet"
    result = run_command("classify", "features", str(small_dataset), "--out", str(out), "--workers",
                         "2")
    assert result.returncode == 0, result.stderr
    table, doc = read_feature_table(out)
    assert table.num_rows == 8 and doc["features"][0] == "range(dq_1)"
    frame = pl.read_parquet(out)
    assert frame["window_found"].dtype == pl.Boolean
    assert set(frame["action"]) == {"none", "bump", "adjust", "shove"}
    again = run_command("classify", "features", str(small_dataset), "--out", str(out))
    assert again.returncode == 2 and "already exists" in again.stderr
    session = sorted(small_dataset.glob("*.parquet"))[0]
    per_sample = tmp_path / "ps.parquet"
    result = run_command("classify", "features", str(session), "--out", str(per_sample),
                         "--per-sample")
    assert result.returncode == 0, result.stderr
    columns = pl.read_parquet_schema(per_sample)
    for name in ("r_1", "g_7", "tau_inv_3", "ddq_2", "p_int_5", "p_ext_6", "f_x", "m_z",
                 "f_norm", "m_norm"):
        assert name in columns
    bad = run_command("classify", "features", str(session), "--out", str(tmp_path / "x.parquet"),
                      "--scalars", "median")
    assert bad.returncode == 2 and "unknown scalar feature 'median'" in bad.stderr


def test_import_arrays_round_trip(reference_dir: Path, tmp_path: Path) -> None:
    args = ["recorder", "import-arrays", "--t", str(reference_dir / "time.txt"), "--q",
            str(reference_dir / "positions.txt"), "--dq", str(reference_dir / "velocity.txt"),
            "--tau", str(reference_dir / "torques.txt"), "--meta", "with_hand=false", "--meta",
            "planned_at_s=10", "--meta", "condition=dynamic", "--out", str(tmp_path)]
    result = run_command(*args)
    assert result.returncode == 0, result.stderr
    frame = pl.read_parquet(result.stdout.strip())
    assert frame.height == 20544 and frame["t"][0] == 0.0
    assert frame["q_1"][0] == pytest.approx(-0.9584)
    npy = tmp_path / "tau.npy"
    np.save(npy, np.zeros((20544, 6)))
    bad = run_command(*args[:-2], "--out", str(tmp_path / "o"), "--tau", str(npy))
    assert bad.returncode == 2 and "wrong joint count" in bad.stderr
    bad_meta = run_command(*args[:-2], "--out", str(tmp_path / "o"), "--meta", "colour=red")
    assert bad_meta.returncode == 2 and "bad metadata pair 'colour=red'" in bad_meta.stderr
    times = tmp_path / "time.npy"  # a stamp that goes back: the error names the file
    np.save(times, np.r_[0.0, 0.002, 0.001, np.arange(3, 20544) * 1e-3])
    bad_time = run_command(*args[:2], str(times), *args[3:-2], "--out", str(tmp_path / "o"))
    assert bad_time.returncode == 2
    assert f"{times}: t is not strictly increasing at row 2" in bad_time.stderr


def test_import_arrays_streamed_in_blocks(reference_dir: Path, tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Text and .npy files read, and the session written, a few rows at a time give the
    table of one block for the whole recording (and of the arrays loaded whole)."""
    whole = arrays.load_joint_arrays(*(reference_dir / f for f in (
        "time.txt", "positions.txt", "velocity.txt", "torques.txt")))
    for name, values in whole.items():
        np.save(tmp_path / f"{name}.npy", values[:3000])
    texts = [reference_dir / f for f in ("time.txt", "positions.txt", "velocity.txt",
                                         "torques.txt")]
    npys = [tmp_path / f"{name}.npy" for name in ("t", "q", "dq", "tau")]
    tables = {}
    for block in (5, 1_000_000):
        monkeypatch.setattr(arrays, "BLOCK_LINES", block)
        monkeypatch.setattr(arrays, "BLOCK_ROWS", block)
        for kind, files in (("text", texts), ("npy", npys)):
            out = tmp_path / f"{kind}{block}"
            out.mkdir()
            tables[kind, block] = read_session(import_array_files(
                *files, out, ["with_hand=false"])).table
    for kind in ("text", "npy"):
        assert tables[kind, 5].equals(tables[kind, 1_000_000])
    assert np.array_equal(tables["npy", 5].column("q_3").to_numpy(), whole["q"][:3000, 2])


@pytest.mark.parametrize("params", [
    {}, {"window": "change"}, {"window": "difference", "calibration": "thesis"},
    {"window": "fixed", "shift_s": 0.1}, {"window": "planned", "window_s": 0.3},
    {"signal": "r", "timeseries": ["r", "f"], "scalars": ["range", "mean", "variance", "fft"]},
])
def test_long_session_window_features_streamed(tmp_path: Path, params: dict,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """Read batch by batch (97-sample batches), keeping only what the window needs, the
    features equal those of the whole session (to 1e-9), for every window method."""
    from contactkit.features import chain_cache, window_features

    monkeypatch.setenv("CONTACTKIT_CHAIN_CACHE", "0")
    path = make_session(tmp_path, duration_s=3.0, planned_at_s=1.5)
    extractor = SessionFeatures(**params)
    whole, names, window = extractor.session_row(path)
    monkeypatch.setattr(window_features, "STREAMED_ABOVE_ROWS", 0)
    monkeypatch.setattr(chain_cache, "BATCH_ROWS", 97)
    streamed, streamed_names, streamed_window = extractor.session_row(path)
    assert streamed_names == names and streamed_window == window
    np.testing.assert_allclose(streamed, whole, rtol=1e-9, atol=1e-9)
