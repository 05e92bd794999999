"""Per-session measurements for ``recorder stats --deep``.

Each worker reads one session and returns a small summary (a few hundred numbers),
so memory stays bounded however large the dataset: sampling, the thesis's
torque-noise statistic, peak residual norm and estimated force, the estimated
force profile around the interaction, how the Difference window was found, the
delay between planned and detected onset, joint-limit proximity and the file's
SHA-256.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from contactkit.features.dynamics import PandaModel
from contactkit.features.timeseries import TimeseriesChain
from contactkit.features.windows import WindowSpec, find_window
from contactkit.recorder.noise import robust_noise_sigma
from contactkit.schemas import InputError, read_session
from contactkit.schemas.timing import sampling_stats

PROFILE_BEFORE_S = 0.25
PROFILE_AFTER_S = 2.0
PROFILE_HZ = 100.0
PROFILE_T = np.arange(-PROFILE_BEFORE_S, PROFILE_AFTER_S, 1.0 / PROFILE_HZ)


def file_sha256(path: Path) -> str:
    """Return the SHA-256 of a file's bytes (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def session_summary(path: str) -> dict:
    """Measure one session; on a bad file return ``{"file": name, "problem": text}``."""
    name = Path(path).name
    try:
        session = read_session(path).complete()
    except InputError as err:
        return {"file": name, "problem": err.problem}
    meta = session.meta
    t = session.t
    sampling = sampling_stats(t).as_dict()
    chain = TimeseriesChain(with_hand=meta.with_hand)
    series = chain.compute(t, session.q, session.dq, session.tau, ["r", "fm_norm"])
    r_norm = np.linalg.norm(series["r"], axis=1)
    force = series["fm_norm"][:, 0]
    out = {"file": name, "session_id": meta.session_id, "action": meta.action,
           "condition": meta.condition, "sha256": file_sha256(Path(path)),
           "duration_s": session.duration_s, "sampling": sampling,
           "tau_std_nm": session.tau.std(axis=0).tolist(),
           "tau_sigma_nm": robust_noise_sigma(session.tau).tolist(),
           "dq_sigma_rad_s": robust_noise_sigma(session.dq).tolist(),
           "q_sigma_rad": robust_noise_sigma(session.q).tolist(),
           "r_median_nm": np.median(series["r"][t > t[0] + 1.0], axis=0).tolist()
           if (t > t[0] + 1.0).any() else [0.0] * 7,
           "peak_residual_norm_nm": float(r_norm.max()),
           "peak_force_n": float(force.max())}
    planned = meta.planned_at_s
    if planned is not None:
        window = find_window(t, planned, WindowSpec("difference"), session.tau)
        onset = window.onset_s if window.found else planned
        out.update({"window_found": window.found,
                    "onset_delay_s": None if not window.found else window.onset_s - planned,
                    "short_for_window": bool(t[-1] < planned + 0.5),
                    "force_profile_n": np.interp(onset + PROFILE_T, t, force,
                                                 left=np.nan, right=np.nan).tolist()})
    else:
        out.update({"window_found": None, "onset_delay_s": None,
                    "short_for_window": bool(session.duration_s < 0.5),
                    "force_profile_n": None})
    limits = PandaModel(meta.with_hand).limits
    q = session.q
    out["limit_margin_rad"] = np.minimum(q.min(axis=0) - limits.q_min,
                                         limits.q_max - q.max(axis=0)).tolist()
    out["max_speed_fraction"] = (np.abs(session.dq).max(axis=0) / limits.dq_max).tolist()
    out["max_torque_fraction"] = (np.abs(session.tau).max(axis=0) / limits.tau_max).tolist()
    return out
