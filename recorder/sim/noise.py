"""Sensor noise of the Panda, measured from real data, for the simulator.

``estimate_noise`` measures, per joint:

* white-noise level of tau [Nm], dq [rad/s] and q [rad]: a robust standard
  deviation (1.4826 x median absolute deviation) of the second difference divided
  by sqrt(6) (the second difference of white noise of variance s^2 has variance
  6 s^2). At 1 kHz the second difference of the smooth motion itself is tiny, so
  what remains is the sensor's white noise;
* the velocity noise grows with speed (on the real free-motion log from about
  0.0015 rad/s at rest to 0.004-0.006 rad/s above 1 rad/s): per joint, the level is
  measured in bands of |dq| and a line sigma = a + b |dq| is fitted; ``b``
  (``dq_sigma_per_speed``, dimensionless) is the growth, ``a`` the level at rest;
* torque bias scale [Nm]: the absolute median of the inverse-dynamics residual
  tau - (M ddq + C dq + g + tau_f), with ddq from smoothed velocities. It lumps
  the torque sensor's offset with the model error that the observer sees as a
  constant; the simulator draws each session's bias from N(0, this scale).

The values the simulator uses by default (``data/panda_noise.json``) were measured
this way on the real recording in ``shared/reference/gaz2019-exciting-traj``, except
the velocity noise at rest: that is :func:`held_pose_dq_sigma` on the no-touch
stretches of the real hand-mounted Panda holding a pose in
``shared/reference/mindlab-contact`` (0.0003-0.001 rad/s, where the free-motion log's
fit gives 0.0013 at rest; with the log's level the simulated robot at rest showed
2-3x the real residual noise, because the observer's residual carries the velocity
noise times K_O times the joint inertia). Tests recompute both from the recordings.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from importlib import resources
from itertools import pairwise
from pathlib import Path

import numpy as np

from contactkit.robots import GAZ_FRICTION, RobotSetup
from contactkit.schemas import InputError
from contactkit.util.safe_open import read_json


@dataclass(frozen=True)
class SensorNoise:
    """Per-joint noise levels (each a list of 7): white-noise standard deviations of
    tau [Nm], dq [rad/s], q [rad], and the scale of a per-session torque bias [Nm]."""

    tau_sigma_nm: list[float]
    dq_sigma_rad_s: list[float]
    q_sigma_rad: list[float]
    tau_bias_nm: list[float]
    source: str = ""
    dq_sigma_per_speed: list[float] = field(default_factory=lambda: [0.0] * 7)

    def dq_sigma(self, speed_rad_s: np.ndarray) -> np.ndarray:
        """Return the velocity noise standard deviation [rad/s] at joint speeds
        ``speed_rad_s`` [rad/s] (shape (7, ...)): the level at rest plus its growth."""
        rest = np.array(self.dq_sigma_rad_s).reshape(7, *([1] * (np.ndim(speed_rad_s) - 1)))
        per_speed = np.array(self.dq_sigma_per_speed).reshape(rest.shape)
        return rest + per_speed * np.abs(speed_rad_s)

    def to_json(self) -> str:
        """Return the noise levels as a JSON document."""
        return json.dumps(asdict(self), indent=2)

    @classmethod
    def from_file(cls, path: str | Path) -> SensorNoise:
        """Read a noise file written by :meth:`to_json` (or by ``recorder stats``)."""
        path = Path(path)
        doc = read_json(path, "noise file")
        try:
            noise = cls(**{k: doc[k] for k in ("tau_sigma_nm", "dq_sigma_rad_s",
                                                 "q_sigma_rad", "tau_bias_nm")},
                        source=doc.get("source", str(path)),
                        dq_sigma_per_speed=doc.get("dq_sigma_per_speed", [0.0] * 7))
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise InputError(f"not a noise file ({err})", path) from err
        for name in ("tau_sigma_nm", "dq_sigma_rad_s", "q_sigma_rad", "tau_bias_nm",
                     "dq_sigma_per_speed"):
            try:
                values = np.asarray(getattr(noise, name), dtype=np.float64)
            except (TypeError, ValueError, OverflowError):
                values = np.zeros(0)
            if values.shape != (7,) or not np.isfinite(values).all() or (values < 0).any():
                raise InputError(f"{name} must be 7 finite non-negative numbers", path)
        if not isinstance(noise.source, str):
            raise InputError("source must be a string", path)
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


SPEED_BANDS_RAD_S = (0.0, 0.05, 0.15, 0.3, 0.6, 1.0, 2.5)
MIN_BAND_SAMPLES = 200


def dq_noise_line(dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fit the velocity noise against speed; return (level at rest [rad/s], growth
    [dimensionless]) per joint.

    ``dq`` (N, 7) [rad/s] at a constant rate. For each joint, the robust noise level
    (see :func:`robust_noise_sigma`) of the samples in each band of |dq|
    (``SPEED_BANDS_RAD_S``, bands with at least ``MIN_BAND_SAMPLES``) is fitted by
    least squares with a line over the band's median speed; both are kept >= 0.
    """
    d = np.diff(dq, n=2, axis=0) / np.sqrt(6.0)
    speed = np.abs(dq[1:-1])
    rest, growth = np.zeros(dq.shape[1]), np.zeros(dq.shape[1])
    for j in range(dq.shape[1]):
        x, y = [], []
        for lo, hi in pairwise(SPEED_BANDS_RAD_S):
            band = (speed[:, j] >= lo) & (speed[:, j] < hi)
            if band.sum() >= MIN_BAND_SAMPLES:
                values = d[band, j]
                x.append(np.median(speed[band, j]))
                y.append(1.4826 * np.median(np.abs(values - np.median(values))))
        slope, intercept = np.polyfit(x, y, 1) if len(x) > 1 else (0.0, np.mean(y))
        rest[j], growth[j] = max(intercept, 0.0), max(slope, 0.0)
    return rest, growth


def away_from_contact(t: np.ndarray, contact: np.ndarray, margin_s: float = 0.5) -> np.ndarray:
    """Return a mask of the samples at least ``margin_s`` [s] from any labelled contact
    sample (``t`` [s] (N,) increasing, ``contact`` (N,) bool): stretches where nobody
    touches and the observer has settled from the last touch."""
    touching = t[contact]
    if touching.size == 0:
        return np.ones(t.shape, dtype=bool)
    k = np.clip(np.searchsorted(touching, t), 1, touching.size - 1)
    nearest = np.minimum(np.abs(t - touching[k - 1]), np.abs(t - touching[k]))
    if touching.size == 1:
        nearest = np.abs(t - touching[0])
    return nearest >= margin_s


def held_pose_dq_sigma(dq_stretches: list[np.ndarray]) -> np.ndarray:
    """Return the velocity noise at rest [rad/s] per joint: the median over recordings of
    :func:`robust_noise_sigma` of each recording's held-pose samples (each (N, 7))."""
    return np.median([robust_noise_sigma(dq) for dq in dq_stretches], axis=0)


def estimate_noise(t: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray,
                   with_hand: bool, source: str = "") -> SensorNoise:
    """Measure per-joint sensor noise, its growth with speed (velocity) and the torque
    bias scale from a free-motion recording.

    ``t`` [s] (N,), ``q`` [rad], ``dq`` [rad/s], ``tau`` [Nm] (N, 7). See the module
    docstring for the method.
    """
    from scipy.signal import butter, sosfiltfilt  # here: the simulator's import needs no scipy

    from contactkit.robots.model import RobotModel

    model = RobotModel(RobotSetup("panda", with_hand))
    step = float(np.median(np.diff(t)))
    sos = butter(2, min(20.0 * 2.0 * step, 0.9), output="sos")
    dq_smooth = sosfiltfilt(sos, dq, axis=0)
    ddq = np.gradient(dq_smooth, t, axis=0)
    predicted = np.array([model.inverse_dynamics(q[k], dq_smooth[k], ddq[k])
                          for k in range(len(t))])
    residual = tau - predicted - GAZ_FRICTION.torque(dq_smooth)
    dq_rest, dq_growth = dq_noise_line(dq)
    return SensorNoise(
        tau_sigma_nm=robust_noise_sigma(tau).round(6).tolist(),
        dq_sigma_rad_s=dq_rest.round(7).tolist(),
        dq_sigma_per_speed=dq_growth.round(6).tolist(),
        q_sigma_rad=robust_noise_sigma(q).round(8).tolist(),
        tau_bias_nm=np.abs(np.median(residual, axis=0)).round(6).tolist(),
        source=source,
    )
