"""Sensor noise of the Panda, measured from real data, for the simulator.

``estimate_noise`` measures, per joint:

* white-noise level of tau [Nm], dq [rad/s] and q [rad]: a robust standard
  deviation (1.4826 x median absolute deviation) of the second difference divided
  by sqrt(6) (the second difference of white noise of variance s^2 has variance
  6 s^2). At 1 kHz the second difference of the smooth motion itself is tiny, so
  what remains is the sensor's white noise;
* torque bias scale [Nm]: the absolute median of the inverse-dynamics residual
  tau - (M ddq + C dq + g + tau_f), with ddq from smoothed velocities. It lumps
  the torque sensor's offset with the model error that the observer sees as a
  constant; the simulator draws each session's bias from N(0, this scale).

The values the simulator uses by default (``data/panda_noise.json``) were measured
this way on the real recording in ``shared/reference/gaz2019-exciting-traj``, and
a test recomputes them from it.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.signal import butter, sosfiltfilt

from contactkit.features.dynamics import GAZ_FRICTION, PandaModel
from contactkit.schemas import InputError


@dataclass(frozen=True)
class SensorNoise:
    """Per-joint noise levels (each a list of 7): white-noise standard deviations of
    tau [Nm], dq [rad/s], q [rad], and the scale of a per-session torque bias [Nm]."""

    tau_sigma_nm: list[float]
    dq_sigma_rad_s: list[float]
    q_sigma_rad: list[float]
    tau_bias_nm: list[float]
    source: str = ""

    def to_json(self) -> str:
        """Return the noise levels as a JSON document."""
        return json.dumps(asdict(self), indent=2)

    @classmethod
    def from_file(cls, path: str | Path) -> SensorNoise:
        """Read a noise file written by :meth:`to_json` (or by ``recorder stats``)."""
        path = Path(path)
        try:
            doc = json.loads(path.read_text())
            noise = cls(**{k: doc[k] for k in ("tau_sigma_nm", "dq_sigma_rad_s",
                                                 "q_sigma_rad", "tau_bias_nm")},
                        source=doc.get("source", str(path)))
        except (OSError, json.JSONDecodeError, KeyError, TypeError) as err:
            raise InputError(f"not a noise file ({err})", path) from err
        for name in ("tau_sigma_nm", "dq_sigma_rad_s", "q_sigma_rad", "tau_bias_nm"):
            if len(getattr(noise, name)) != 7:
                raise InputError(f"{name} must have 7 values", path)
        return noise


def default_noise() -> SensorNoise:
    """Return the noise measured on the real Panda reference recording."""
    text = resources.files("contactkit.recorder").joinpath("data/panda_noise.json").read_text()
    doc = json.loads(text)
    return SensorNoise(**{k: v for k, v in doc.items() if k != "how"})


def robust_noise_sigma(x: np.ndarray) -> np.ndarray:
    """Return each column's white-noise standard deviation, estimated as
    1.4826 x MAD of the second difference / sqrt(6) (same unit as ``x``)."""
    d = np.diff(x, n=2, axis=0)
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(6.0)


def estimate_noise(t: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray,
                   with_hand: bool, source: str = "") -> SensorNoise:
    """Measure per-joint sensor noise and torque bias scale from a free-motion recording.

    ``t`` [s] (N,), ``q`` [rad], ``dq`` [rad/s], ``tau`` [Nm] (N, 7). See the module
    docstring for the method.
    """
    model = PandaModel(with_hand)
    step = float(np.median(np.diff(t)))
    sos = butter(2, min(20.0 * 2.0 * step, 0.9), output="sos")
    dq_smooth = sosfiltfilt(sos, dq, axis=0)
    ddq = np.gradient(dq_smooth, t, axis=0)
    predicted = np.array([model.inverse_dynamics(q[k], dq_smooth[k], ddq[k])
                          for k in range(len(t))])
    residual = tau - predicted - GAZ_FRICTION.torque(dq_smooth)
    return SensorNoise(
        tau_sigma_nm=robust_noise_sigma(tau).round(6).tolist(),
        dq_sigma_rad_s=robust_noise_sigma(dq).round(7).tolist(),
        q_sigma_rad=robust_noise_sigma(q).round(8).tolist(),
        tau_bias_nm=np.abs(np.median(residual, axis=0)).round(6).tolist(),
        source=source,
    )
