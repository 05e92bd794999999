"""recorder stats --deep in bounded memory: the summary streamed batch by batch equals
the summary computed from the whole session held at once (exact medians, 1e-9)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from contactkit.features import chain_cache
from contactkit.features.timeseries import TimeseriesChain
from contactkit.features.timing import sampling_stats, streamed_sampling_stats
from contactkit.features.windows import WindowSpec, find_window
from contactkit.recorder.sim.noise import robust_noise_sigma
from contactkit.recorder.stats import deep as stats_deep
from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.schemas import read_session, write_session
from contactkit.schemas.session import table_from_columns
from contactkit.util import exact_median
from contactkit.util.exact_median import exact_medians
from tests.conftest import make_session


def _whole_session_summary(path: Path) -> dict:
    """The summary as computed before streaming: the whole session in memory."""
    session = read_session(path).complete()
    meta, t = session.meta, session.t
    series = TimeseriesChain(robot=RobotSetup(with_hand=meta.with_hand)).compute(
        t, session.q, session.dq, session.tau, ["r", "fm_norm"])
    force = series["fm_norm"][:, 0]
    settled = t > t[0] + 1.0
    out = {"duration_s": session.duration_s, "sampling": sampling_stats(t).as_dict(),
           "tau_std_nm": session.tau.std(axis=0).tolist(),
           "tau_sigma_nm": robust_noise_sigma(session.tau).tolist(),
           "dq_sigma_rad_s": robust_noise_sigma(session.dq).tolist(),
           "q_sigma_rad": robust_noise_sigma(session.q).tolist(),
           "r_median_nm": np.median(series["r"][settled], axis=0).tolist()
           if settled.any() else [0.0] * 7,
           "peak_residual_norm_nm": float(np.linalg.norm(series["r"], axis=1).max()),
           "peak_force_n": float(force.max())}
    window = find_window(t, meta.planned_at_s, WindowSpec("difference"), session.tau)
    onset = window.onset_s if window.found else meta.planned_at_s
    out.update({"window_found": window.found,
                "onset_delay_s": None if not window.found
                else window.onset_s - meta.planned_at_s,
                "short_for_window": bool(t[-1] < meta.planned_at_s + 0.5),
                "force_profile_n": np.interp(onset + stats_deep.PROFILE_T, t, force,
                                             left=np.nan, right=np.nan).tolist()})
    limits = RobotModel(RobotSetup(with_hand=meta.with_hand)).limits
    out["limit_margin_rad"] = np.minimum(session.q.min(axis=0) - limits.q_min,
                                         limits.q_max - session.q.max(axis=0)).tolist()
    out["max_speed_fraction"] = (np.abs(session.dq).max(axis=0) / limits.dq_max).tolist()
    out["max_torque_fraction"] = (np.abs(session.tau).max(axis=0) / limits.tau_max).tolist()
    return out


EXACT = ("tau_sigma_nm", "dq_sigma_rad_s", "q_sigma_rad", "limit_margin_rad",
         "max_speed_fraction", "max_torque_fraction", "duration_s", "window_found",
         "onset_delay_s", "short_for_window")


def _with_gaps(path: Path) -> Path:
    """The session with a few samples lacking a torque (as a CAN source leaves them)."""
    session = read_session(path)
    columns = {name: session.column(name).copy() for name in session.table.column_names}
    columns["tau_4"][[5, 400, 401, 1200]] = np.nan
    meta = replace(session.meta, source_info={"incomplete_samples": 4})
    out = path.with_name("gaps.parquet")
    write_session(out, columns, meta)
    return out


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> list[Path]:
    directory = tmp_path_factory.mktemp("deep")
    shove = make_session(directory, seed=3, action="shove", duration_s=4.0)
    return [shove, make_session(directory, seed=5, action="none", duration_s=3.0),
            make_session(directory, seed=8, action="bump", link=3, rate_hz=1000.0,
                         duration_s=2.2, planned_at_s=1.0),
            _with_gaps(shove)]


@pytest.mark.parametrize("kept_up_to_rows", [0, stats_deep.ROW_GROUP_ROWS],
                         ids=["read-on-each-pass", "read-once"])
@pytest.mark.parametrize("batch_rows", [97, 1000, chain_cache.BATCH_ROWS])
def test_streamed_summary_equals_the_whole_session(sessions, batch_rows, kept_up_to_rows,
                                                   monkeypatch) -> None:
    monkeypatch.setattr(chain_cache, "BATCH_ROWS", batch_rows)
    monkeypatch.setattr(stats_deep, "ROW_GROUP_ROWS", kept_up_to_rows)
    monkeypatch.setattr(exact_median, "COLLECT_AT", 40)  # radix passes, not one partition
    for path in sessions:
        got, want = stats_deep.session_summary(str(path)), _whole_session_summary(path)
        for key in EXACT:
            assert got[key] == want[key], (path.name, key)
        assert got["sampling"] == pytest.approx(want["sampling"], rel=1e-12, abs=1e-18)
        for key in ("tau_std_nm", "r_median_nm", "peak_residual_norm_nm", "peak_force_n",
                    "force_profile_n"):
            assert np.allclose(got[key], want[key], rtol=1e-9, atol=1e-12, equal_nan=True), \
                (path.name, key)


def test_exact_medians_equal_numpy_bit_for_bit(monkeypatch) -> None:
    rng = np.random.default_rng(1)
    for collect in (3, 100, exact_median.COLLECT_AT):
        monkeypatch.setattr(exact_median, "COLLECT_AT", collect)
        for rows in (1, 2, 7, 1000):
            values = np.column_stack([rng.standard_normal(rows),
                                      np.round(rng.standard_normal(rows), 1),
                                      np.full(rows, 0.001), np.arange(rows) / 1000.0,
                                      -np.abs(rng.standard_normal(rows)) * 1e-300])
            chunks = [values[i:i + 37] for i in range(0, rows, 37)]
            assert np.array_equal(exact_medians(lambda c=chunks: iter(c)),
                                  np.median(values, axis=0))


def test_streamed_sampling_stats_of_irregular_steps() -> None:
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.choice([0.001, 0.001, 0.0011, 0.005], size=5000))
    chunks = [t[i:i + 333] for i in range(0, len(t), 333)]
    got = streamed_sampling_stats(lambda: iter(chunks)).as_dict()
    assert got == pytest.approx(sampling_stats(t).as_dict(), rel=1e-12)
    one = streamed_sampling_stats(lambda: iter([t[:1]])).as_dict()
    assert one == pytest.approx(sampling_stats(t[:1]).as_dict(), nan_ok=True)


def test_a_bad_batch_is_a_problem_not_a_crash(sessions, monkeypatch, tmp_path) -> None:
    monkeypatch.setattr(chain_cache, "BATCH_ROWS", 200)
    session = read_session(sessions[1])
    columns = {name: session.column(name).copy() for name in session.table.column_names}
    columns["q_2"][700] = np.inf
    bad = tmp_path / "bad.parquet"
    pq.write_table(table_from_columns(columns, session.meta), bad)
    summary = stats_deep.session_summary(str(bad))
    assert summary == {"file": "bad.parquet",
                       "problem": "infinite value in column 'q_2' at row 100 "
                                  "(counted from row 600)"}
