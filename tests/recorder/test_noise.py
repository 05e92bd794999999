"""The simulator's default sensor noise is what the real reference recording shows."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from contactkit.recorder.importers.arrays import load_joint_arrays
from contactkit.recorder.importers.csv_import import read_csv_columns
from contactkit.recorder.importers.csv_map import load_csv_map, mindlab_map_path
from contactkit.recorder.sim.noise import (
    SensorNoise,
    away_from_contact,
    default_noise,
    estimate_noise,
    held_pose_dq_sigma,
)
from tests.conftest import MINDLAB_FILES


def test_default_noise_is_recomputed_from_reference(reference_dir: Path) -> None:
    arrays = load_joint_arrays(*(reference_dir / f for f in ("time.txt", "positions.txt",
                                                              "velocity.txt", "torques.txt")))
    measured = estimate_noise(arrays["t"], arrays["q"], arrays["dq"], arrays["tau"],
                              with_hand=False)
    baked = default_noise()
    for name in ("tau_sigma_nm", "q_sigma_rad", "tau_bias_nm", "dq_sigma_per_speed"):
        assert np.allclose(getattr(measured, name), getattr(baked, name), rtol=1e-4,
                           atol=1e-7), name
    assert all(0.01 < s < 0.2 for s in baked.tau_sigma_nm)
    # The free-motion log's velocity noise at rest is higher than the held pose's.
    assert (np.array(measured.dq_sigma_rad_s) > np.array(baked.dq_sigma_rad_s)).all()
    assert (np.array(baked.dq_sigma_per_speed) > 0.001).all()


def test_velocity_noise_at_rest_is_recomputed_from_held_pose(mindlab_dir: Path) -> None:
    cmap = load_csv_map(mindlab_map_path())
    stretches = []
    for name in MINDLAB_FILES:
        columns, _ = read_csv_columns(mindlab_dir / f"{name}.csv", cmap)
        keep = away_from_contact(columns["t"], columns["contact"]) & (columns["t"] > 1.0)
        stretches.append(np.column_stack([columns[f"dq_{j}"] for j in range(1, 8)])[keep])
    assert np.allclose(held_pose_dq_sigma(stretches), default_noise().dq_sigma_rad_s,
                       rtol=1e-4, atol=1e-7)


def test_away_from_contact() -> None:
    t = np.arange(0.0, 3.0, 0.1)
    contact = (t > 1.05) & (t < 1.35)
    keep = away_from_contact(t, contact, margin_s=0.5)
    assert np.array_equal(t[~keep].round(1), np.arange(0.7, 1.75, 0.1).round(1))
    assert away_from_contact(t, np.zeros_like(t, dtype=bool)).all()


def test_noise_file_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "noise.json"
    path.write_text(default_noise().to_json())
    assert SensorNoise.from_file(path).tau_sigma_nm == default_noise().tau_sigma_nm
