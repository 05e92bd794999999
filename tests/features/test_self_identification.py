"""Which sessions identify their own arm, and how they are split for cross-fitting
(contactkit.features.self_identification); the command's use of it is tested in
tests/features/test_identify.py, on moving sessions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contactkit.features import self_identification as own
from contactkit.features.self_identification import SessionSurvey, halves, moving_dataset
from contactkit.schemas import read_session
from tests.conftest import make_session


def _surveyed(groups: str, motion_s: float = 40.0, carries: bool = False
              ) -> list[SessionSurvey]:
    return [SessionSurvey(Path(f"s{k}.parquet"), group, motion_s, carries)
            for k, group in enumerate(groups)]


def test_halves_keep_whole_poses_and_deal_them_alternately() -> None:
    sessions = _surveyed("ABCABCD")
    first, second = halves(sessions)
    assert [p.name for p in first] == ["s0.parquet", "s2.parquet", "s3.parquet",
                                       "s5.parquet"]  # poses A and C
    assert [p.name for p in second] == ["s1.parquet", "s4.parquet", "s6.parquet"]  # B, D


def test_one_pose_is_split_session_by_session() -> None:
    first, second = halves(_surveyed("AAAAA"))
    assert [p.name for p in first] == ["s0.parquet", "s2.parquet", "s4.parquet"]
    assert [p.name for p in second] == ["s1.parquet", "s3.parquet"]
    assert halves(_surveyed("A")) == ([Path("s0.parquet")], [])


def test_a_moving_dataset_needs_motion_in_both_halves(monkeypatch) -> None:
    monkeypatch.setattr(own, "MIN_MOTION_S", 60.0)
    assert moving_dataset(_surveyed("ABAB", motion_s=30.0)) is None  # 60 s per half
    assert "29 s in a half, 60 s needed" in moving_dataset(_surveyed("ABAB", motion_s=14.5))
    assert "0 s in a half" in moving_dataset(_surveyed("A", motion_s=600.0))  # one session
    assert moving_dataset([]) is not None


def test_sessions_that_carry_dynamics_are_not_identified_again() -> None:
    sessions = _surveyed("AB", motion_s=600.0)
    sessions[1] = SessionSurvey(sessions[1].path, "B", 600.0, True)
    assert moving_dataset(sessions) == "a session carries identified dynamics"


def test_survey_measures_motion_and_skips_what_is_not_a_session(tmp_path) -> None:
    path = make_session(tmp_path, pose="C")
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"not parquet")
    surveyed = own.survey([path, bad])
    assert [s.path for s in surveyed] == [path]
    session = read_session(path)
    moving = np.linalg.norm(session.dq, axis=1) >= own.REST_SPEED
    assert surveyed[0].group == "C" and not surveyed[0].carries_dynamics
    step = float(np.median(np.diff(session.t)))
    assert surveyed[0].motion_s == pytest.approx(moving.sum() * step, abs=step)
