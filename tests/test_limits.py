"""Values beyond physical bounds (issue 25): hard limits refused where data enter and on
read, robot limits enforced on simulated sessions and flagged by stats."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from contactkit.errors import InputError
from contactkit.features.limits import limit_violation, robot_limits
from contactkit.recorder.sim import dataset
from contactkit.recorder.sim.simulator import SimConfig, plan_session
from contactkit.recorder.stats.summary import beyond_limits
from contactkit.schemas import SessionMeta, read_session
from tests.conftest import make_session, run_command


def test_hard_limits_are_refused_on_read_naming_column_and_row(tmp_path: Path) -> None:
    path = make_session(tmp_path)
    table = pq.read_table(path)
    tau = table.column("tau_3").to_numpy().copy()
    tau[17] = 1.19e103
    bad = tmp_path / "bad.parquet"
    pq.write_table(table.set_column(table.column_names.index("tau_3"), "tau_3",
                                    pa.array(tau)), bad)
    with pytest.raises(InputError, match=r"impossible value 1\.19e\+103 in column 'tau_3' "
                                         r"at row 17"):
        read_session(bad)


def test_a_blown_up_simulation_is_named_and_not_written(tmp_path, monkeypatch) -> None:
    config = SimConfig(rate_hz=100.0)
    spec = plan_session(seed=1, condition="static", action="shove", pose="D", duration_s=1.0,
                        planned_at_s=0.5)
    real = dataset._simulated

    def blown_up(specs, cfg):
        for index, data, reflex in real(specs, cfg):
            data = dict(data)
            data["dq_3"] = data["dq_3"].copy()
            data["dq_3"][60:] = 240.0  # the arm spinning away after the shove
            yield index, data, reflex

    monkeypatch.setattr(dataset, "_simulated", blown_up)
    paths, problems = dataset.simulate_batch([spec], config, tmp_path)
    assert paths == [] and len(problems) == 1
    assert "unstable" in problems[0][1] and "dq_3 = 240" in problems[0][1]
    assert not list(tmp_path.glob("*.parquet"))


def test_limit_violation_names_the_first_sample() -> None:
    limits = robot_limits(SessionMeta(session_id="s", source="t", action="none"))
    t = np.arange(10) * 0.01
    q, dq, tau = np.zeros((10, 7)), np.zeros((10, 7)), np.zeros((10, 7))
    assert limit_violation(t, q, dq, tau, limits) is None
    tau[7, 2] = 823.0
    dq[8, 0] = 100.0
    why = limit_violation(t, q, dq, tau, limits)
    assert why.startswith("tau_3 = 823 Nm at 0.070 s (row 7)")
    summary = {"file": "x", "max_torque_fraction": [0.1] * 2 + [823 / 87] + [0.1] * 4,
               "max_speed_fraction": [0.1] * 7, "limit_margin_rad": [0.1] * 7}
    assert "torque of joint 3" in beyond_limits(summary)


def test_recorder_info_flags_a_sample_beyond_the_robots_limits(tmp_path: Path) -> None:
    """Plain `recorder info` (not only `stats --deep`) names the first sample beyond the
    session robot's limits: physically impossible, yet below the hard limits of read."""
    from contactkit.recorder.info import session_info

    path = make_session(tmp_path)
    assert session_info(path)["beyond_limits"] is None
    table = pq.read_table(path)
    dq = table.column("dq_4").to_numpy().copy()
    dq[42] = 9.0  # rad/s: 3.6x the Panda's joint 4 speed limit
    bad = tmp_path / "fast.parquet"
    pq.write_table(table.set_column(table.column_names.index("dq_4"), "dq_4", pa.array(dq)),
                   bad)
    why = session_info(bad)["beyond_limits"]
    assert why.startswith("dq_4 = 9 rad/s") and "(row 42)" in why
    result = run_command("recorder", "info", str(bad))
    assert result.returncode == 0 and "limits" in result.stdout and "dq_4" in result.stdout


def test_calibration_leaves_out_a_session_beyond_the_robots_limits(tmp_path: Path) -> None:
    """A mis-scaled session (torques scaled 100x) would set thresholds of hundreds of
    Nm: calibrate names it, leaves it out, calibrates on the rest and exits 2."""
    from contactkit.classify.events.calibrate import calibrate_sessions

    good = make_session(tmp_path, action="none", duration_s=2.0)
    table = pq.read_table(good)
    scaled = table
    for j in range(1, 8):
        name = f"tau_{j}"
        scaled = scaled.set_column(scaled.column_names.index(name), name,
                                   pa.array(table.column(name).to_numpy() * 100.0))
    pq.write_table(scaled, tmp_path / "scaled.parquet")
    problems: list[tuple[str, str]] = []
    config = calibrate_sessions([good, tmp_path / "scaled.parquet"], problems=problems)
    assert [Path(name).name for name, _ in problems] == ["scaled.parquet"]
    assert "beyond the robot's limit" in problems[0][1]
    assert config.source["sessions"] == 1 and max(config.noise) < 5.0
    result = run_command("classify", "calibrate", str(tmp_path), "--out", str(tmp_path / "c.json"))
    assert result.returncode == 2 and "scaled.parquet" in result.stderr
    assert "Traceback" not in result.stderr and (tmp_path / "c.json").is_file()
