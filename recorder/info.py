"""What ``recorder info`` reports about one session."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from contactkit.features.limits import session_limit_violation
from contactkit.features.timing import RESTART_STEP_S, rate_warning, sampling_stats
from contactkit.schemas import Session, validate_session
from contactkit.util.text import printable


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
    the feature chain), ground truth and the first sample beyond the robot's limits (None
    when there is none) of a session file."""
    session = validate_session(path)
    stats = sampling_stats(session.t)
    return {
        "file": str(path),
        "metadata": {k: v for k, v in vars(session.meta).items()
                     if k not in ("simulator", "dynamics")},
        "dynamics": dynamics_summary(session.meta.dynamics),
        "columns": session.table.column_names,
        "sampling": stats.as_dict(),
        "rate_warning": rate_warning(stats.rate_hz),
        "contact_interval_s": contact_interval(session),
        "peak_force_n": peak_force_n(session),
        "beyond_limits": session_limit_violation(session),
    }


def print_info(info: dict, console: Console) -> None:
    """Print what :func:`session_info` returns as a table: metadata, sampling, contact."""
    meta, s = info["metadata"], info["sampling"]
    table = Table(title=_shown(info["file"]), show_header=False, title_justify="left")
    for key in ("session_id", "source", "condition", "pose", "target_pose", "speed_rad_s",
                "action", "link", "planned_at_s", "operator", "robot", "with_hand", "recovered",
                "recovered_samples", "created_utc", "notes"):
        if meta.get(key) not in (None, ""):
            table.add_row(key, _shown(meta[key]))
    table.add_row("dynamics", _shown(dynamics_line(info.get("dynamics"))))
    table.add_row("samples", str(s["samples"]))
    table.add_row("duration", f"{s['duration_s']:.3f} s")
    table.add_row("rate", f"{s['rate_hz']:.1f} Hz (median step {s['median_step_s'] * 1e3:.3f} "
                          f"ms, min {s['min_step_s'] * 1e3:.3f}, max {s['max_step_s'] * 1e3:.3f})")
    table.add_row("gaps", f"{s['gaps']} longer than 3x median (~{s['dropped_estimate']} "
                          f"samples missing); {s['restarts']} over "
                          f"{RESTART_STEP_S:g} s, where the observer and detector restart")
    if info["rate_warning"]:
        table.add_row("[yellow]warning[/]", info["rate_warning"])
    if info.get("beyond_limits"):
        table.add_row("[yellow]limits[/]", _shown(info["beyond_limits"]))
    if info["contact_interval_s"]:
        lo, hi = info["contact_interval_s"]
        peak = info["peak_force_n"]
        table.add_row("contact", f"{lo:.3f} s to {hi:.3f} s"
                      + ("" if peak is None else f", peak {peak:.1f} N"))
    elif info["peak_force_n"] is not None:
        table.add_row("contact", "none")
    agreement = meta.get("residual_agreement")
    if isinstance(agreement, dict) and isinstance(agreement.get("correlation"), list):
        table.add_row("residual vs robot", _shown(agreement_line(agreement)))
    events = meta.get("events")
    events = [] if events is None else events if isinstance(events, list) else [events]
    for number, event in enumerate(events, 1):
        table.add_row(f"event {number}", _shown(event_line(event) if isinstance(event, dict)
                                                else event))
    console.print(table)


def dynamics_summary(doc: dict | None) -> dict | str:
    """Return what identified dynamics stored in a session's metadata (checked when it
    was read) say about themselves: arm and hand, the payload at the flange [kg], how
    they were identified (method, sessions, samples, condition number, parameters
    determined), the residual RMS [Nm] before and after, whether they carry detector
    thresholds, tool, date and checksum. "nominal" for a session without them."""
    if doc is None:
        return "nominal"
    provenance = doc.get("provenance")
    provenance = provenance if isinstance(provenance, dict) else {}
    excitation = provenance.get("excitation")
    excitation = excitation if isinstance(excitation, dict) else {}
    determined, undetermined = excitation.get("determined"), excitation.get("undetermined")
    summary = {
        "robot": doc.get("robot"), "with_hand": doc.get("with_hand"),
        "payload_kg": (doc.get("payload") or {}).get("mass_kg"),
        "identified_by": ("the simulator's true parameters" if "simulator" in provenance
                          else "recorder identify" if excitation else "unknown"),
        "sessions": len(provenance["sessions"]) if isinstance(
            provenance.get("sessions"), list) else None,
        "samples": excitation.get("samples"),
        "condition": excitation.get("condition"),
        "determined": None if not isinstance(determined, list) else
        f"{len(determined)} of "
        f"{len(determined) + (len(undetermined) if isinstance(undetermined, list) else 0)}",
        "rms_before_nm": excitation.get("rms_before_nm"),
        "rms_after_nm": excitation.get("rms_after_nm"),
        "detector": doc.get("detector") is not None,
        "tool": provenance.get("tool"), "created_utc": provenance.get("created_utc"),
        "checksum": doc.get("checksum"),
    }
    return {k: v for k, v in summary.items() if v is not None}


def dynamics_line(summary: dict | str | None) -> str:
    """Return one line for :func:`dynamics_summary`'s result."""
    if not isinstance(summary, dict):
        return "nominal"

    def numbers(key: str) -> str:
        values = summary.get(key)
        return " ".join(format(v, ".2f") if isinstance(v, int | float) else "-"
                        for v in (values if isinstance(values, list) else []))

    parts = [f"{summary.get('robot')} {'with' if summary.get('with_hand') else 'without'} "
             f"hand, from {summary.get('identified_by')}"]
    if isinstance(summary.get("payload_kg"), int | float):
        parts.append(f"payload {summary['payload_kg']:.3f} kg")
    if summary.get("sessions") is not None:
        parts.append(f"{summary['sessions']} sessions, {summary.get('samples', '?')} samples")
    if summary.get("determined"):
        condition = summary.get("condition")
        parts.append(f"{summary['determined']} parameters determined, condition number "
                     + (format(condition, ".3g") if isinstance(condition, int | float)
                        else "?"))
    if summary.get("rms_before_nm") and summary.get("rms_after_nm"):
        parts.append(f"residual RMS {numbers('rms_before_nm')} -> {numbers('rms_after_nm')} "
                     "Nm")
    parts.append("detector thresholds" if summary.get("detector") else "no detector")
    if summary.get("created_utc"):
        parts.append(f"made {summary['created_utc']}")
    parts.append(str(summary.get("checksum", ""))[:19])
    return "; ".join(parts)


def _shown(value: object) -> str:
    """Return a value from a file as table text: control characters escaped (no escape
    sequence reaches the terminal), Rich markup shown as written."""
    return escape(printable(value))


def event_line(event: dict) -> str:
    """Return one line for a contact event stored in the metadata (times in s)."""
    def at(key: str) -> str:
        value = event.get(key)
        return "-" if not isinstance(value, int | float) else f"{value:.3f} s"

    label = str(event.get("label", "?"))
    probabilities = event.get("probabilities")
    p = probabilities.get(label) if isinstance(probabilities, dict) else None
    return (f"{label}" + ("" if not isinstance(p, int | float) else f" (p = {p:.2f})")
            + f", onset {at('onset_s')}, decided {at('decision_s')}, "
              f"released {at('release_s')}"
            + (", outside the training range" if event.get("out_of_range") else
               f", beyond the training range ({event['beyond_range']})"
               if isinstance(event.get("beyond_range"), str) else "")
            + "".join(f"; {when} {contact_line(event[key])}"
                      for when, key in (("at the decision", "contact_at_decision"),
                                        ("at the peak", "contact_at_peak"))
                      if isinstance(event.get(key), dict)))


def contact_line(estimate: dict) -> str:
    """Return one line for a stored contact estimate: link, point (base frame, m),
    force (base frame, N, and its magnitude) and confidence, or why there is none."""
    link, point, force = estimate.get("link"), estimate.get("point_base_m"), \
        estimate.get("force_n")
    if not (isinstance(point, list) and isinstance(force, list)):
        why = estimate.get("status", "?")
        return f"link {link}, no point ({why})" if link else f"no contact estimate ({why})"
    confidence = estimate.get("confidence")
    return (f"link {link} at ({', '.join(f'{v:.3f}' for v in point)}) m, force "
            f"({', '.join(f'{v:.1f}' for v in force)}) N "
            f"|{float(np.linalg.norm(force)):.1f} N|"
            + ("" if not isinstance(confidence, int | float)
               else f", confidence {confidence:.2f}")
            + (", ambiguous" if estimate.get("ambiguous") else ""))


def agreement_line(agreement: dict) -> str:
    """Return one line for the residual's agreement with the robot's own estimate stored
    at import or capture (:mod:`contactkit.features.agreement`): correlation and RMS
    difference [Nm] per joint."""
    def numbers(key: str, fmt: str) -> str:
        values = agreement.get(key)
        return " ".join(format(v, fmt) if isinstance(v, int | float) else "-"
                        for v in (values if isinstance(values, list) else []))

    return (f"correlation {numbers('correlation', '.2f')}; RMS difference "
            f"{numbers('rms_difference_nm', '.2f')} Nm (joints 1-7, against -tau_ext_hat)")
