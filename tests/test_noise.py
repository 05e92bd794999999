"""The simulator's default sensor noise is what the real reference recording shows."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from contactkit.recorder.arrays import load_joint_arrays
from contactkit.recorder.noise import SensorNoise, default_noise, estimate_noise


def test_default_noise_is_recomputed_from_reference(reference_dir: Path) -> None:
    arrays = load_joint_arrays(*(reference_dir / f for f in ("time.txt", "positions.txt",
                                                              "velocity.txt", "torques.txt")))
    measured = estimate_noise(arrays["t"], arrays["q"], arrays["dq"], arrays["tau"],
                              with_hand=False)
    baked = default_noise()
    for name in ("tau_sigma_nm", "dq_sigma_rad_s", "q_sigma_rad", "tau_bias_nm"):
        assert np.allclose(getattr(measured, name), getattr(baked, name), rtol=1e-4,
                           atol=1e-7), name
    assert all(0.01 < s < 0.2 for s in baked.tau_sigma_nm)


def test_noise_file_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "noise.json"
    path.write_text(default_noise().to_json())
    assert SensorNoise.from_file(path).tau_sigma_nm == default_noise().tau_sigma_nm
