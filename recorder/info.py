"""What ``recorder info`` reports about one session."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from contactkit.schemas import Session, validate_session
from contactkit.schemas.timing import rate_warning, sampling_stats


def contact_interval(session: Session) -> tuple[float, float] | None:
    """Return (first, last) time [s] of ground-truth contact, or None without contact."""
    if not session.has("contact"):
        return None
    contact = session.column("contact")
    if not contact.any():
        return None
    t = session.t[contact]
    return float(t[0]), float(t[-1])


def peak_force_n(session: Session) -> float | None:
    """Return the peak ground-truth force magnitude [N], or None without force columns."""
    if not session.has("f_ext_x"):
        return None
    force = np.column_stack([session.column(c) for c in ("f_ext_x", "f_ext_y", "f_ext_z")])
    return float(np.linalg.norm(force, axis=1).max())


def session_info(path: str | Path) -> dict:
    """Return metadata, sampling statistics (with a warning when the rate is too slow for
    the feature chain) and ground truth of a session file."""
    session = validate_session(path)
    stats = sampling_stats(session.t)
    return {
        "file": str(path),
        "metadata": {k: v for k, v in vars(session.meta).items() if k != "simulator"},
        "columns": session.table.column_names,
        "sampling": stats.as_dict(),
        "rate_warning": rate_warning(stats.rate_hz),
        "contact_interval_s": contact_interval(session),
        "peak_force_n": peak_force_n(session),
    }
