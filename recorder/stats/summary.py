"""Dataset statistics: ``recorder stats DIR``.

From the index alone (Polars over ``index.parquet``, fast for 100,000 sessions):
counts by condition x pose x action and by link (static) or speed band (dynamic),
as the thesis's Tables 3.5 and 5.3; class balance with warnings; durations;
sources, operators, robots and recovered sessions; problems (unreadable files, duplicate
session ids, sessions too short for a 0.5 s window). Counts are over unique
session ids: a duplicate is reported, not counted twice.

With ``--deep`` every session is read in parallel workers (see
:mod:`contactkit.recorder.stats.deep`): measured sampling, the torque-noise baseline of the
no-contact sessions (thesis section 5.3.5, also written as a noise file the
simulator reads with ``--noise-file``), per-class peak residual norm and estimated
force, estimated force profiles by class (thesis Figure 3.2), how often the
Difference window found the interaction, the planned-to-detected onset delay, and
joint-limit proximity. The fingerprint then hashes every file's bytes.

The JSON report follows ``schemas/stats_report.schema.json``.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Callable
from datetime import UTC, datetime
from functools import partial
from pathlib import Path
from typing import cast

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.errors import ContactkitError
from contactkit.features.limits import POSITION_SLACK_RAD, SPEED_MARGIN, TORQUE_MARGIN
from contactkit.features.timing import rate_warning
from contactkit.recorder.sim.noise import SensorNoise
from contactkit.recorder.stats.deep import session_summary
from contactkit.robots.dynamics import ArmDynamics
from contactkit.schemas import ACTIONS, InputError
from contactkit.schemas.dataset import (
    INDEX_NAME,
    INDEX_SCHEMA,
    build_index,
    session_files,
    write_index,
)
from contactkit.util.atomic import write_text
from contactkit.util.owned import owned_by_marker
from contactkit.util.parallel import map_ordered
from contactkit.util.text import printable

log = logging.getLogger(__name__)

SCHEMA_ID = "contactkit.schemas/stats_report/1"
WINDOW_S = 0.5
BALANCE_RATIO = 0.5
NOISE_FILE = "noise_baseline.json"


def load_index(directory: Path) -> tuple[pl.LazyFrame, list[dict]]:
    """Return the dataset index (rebuilt when missing or out of date, and saved where the
    directory can be written: a read-only dataset is summarised all the same) and the
    files that could not be indexed, as problems."""
    if not directory.is_dir():
        raise InputError("not a directory", directory)
    index_path = directory / INDEX_NAME
    files = {p.name for p in session_files(directory)}
    if _indexed_files(index_path) == files:
        return pl.scan_parquet(index_path), []
    result = build_index(directory)
    problems = [{"file": name, "problem": problem} for name, problem in result.problems]
    try:
        write_index(directory, result.table)
    except ContactkitError as err:  # a read-only dataset: the index is used unwritten
        log.warning("the index is not saved (%s); the statistics use it unsaved",
                    printable(err))
        return cast(pl.DataFrame, pl.from_arrow(result.table)).lazy(), problems  # a table's
    return pl.scan_parquet(index_path), problems


def _indexed_files(index_path: Path) -> set[str] | None:
    """Return the file names an index lists, or None when it is missing, unreadable or
    not an index of this schema version (then it is rebuilt)."""
    try:
        schema = pq.read_schema(index_path)
        if schema.remove_metadata() != INDEX_SCHEMA.remove_metadata():
            return None
        return set(pq.read_table(index_path, columns=["file"]).column("file").to_pylist())
    except (OSError, pa.ArrowException):
        return None


def _records(frame: pl.DataFrame) -> list[dict]:
    return frame.to_dicts()


def index_stats(index: pl.LazyFrame) -> dict:
    """Return the index-only part of the report (see the module docstring)."""
    dupes = (index.group_by("session_id").agg(pl.len().alias("n"), pl.col("file").sort())
             .filter(pl.col("n") > 1).collect())
    unique = index.sort("file").unique(subset="session_id", keep="first", maintain_order=True)
    frame = unique.with_columns(
        pl.when(pl.col("condition") == "dynamic").then(pl.col("target_pose"))
        .otherwise(pl.col("pose")).alias("pose_of_contact"),
        (pl.col("speed_rad_s") * 10).floor().alias("band")).collect()
    total = frame.height
    by_action = (frame.group_by("action").agg(pl.len().alias("sessions"))
                 .with_columns((pl.col("sessions") / max(total, 1)).alias("share"))
                 .sort("action"))
    counts_by_action = dict(zip(by_action["action"], by_action["sessions"], strict=True))
    largest = max(counts_by_action.values(), default=0)
    warnings = []
    for action in ACTIONS:
        n = counts_by_action.get(action, 0)
        if n == 0:
            warnings.append(f"no '{action}' sessions")
        elif n < BALANCE_RATIO * largest:
            warnings.append(f"'{action}' is under-represented: {n} sessions against {largest} "
                            f"for the largest class")
    robots = frame["robot"].unique().sort().to_list()
    if len(robots) > 1:
        warnings.append(f"sessions of {len(robots)} robots ({', '.join(robots)}): the feature "
                        "chain models each with its own robot model, but a classifier trained "
                        "on them all mixes their data")
    problems = [{"file": f, "problem": f"duplicate session id {sid} (also in "
                                       f"{', '.join(g for g in files if g != f)})"}
                for sid, files in zip(dupes["session_id"], dupes["file"].to_list(), strict=True)
                for f in files[1:]]
    short = frame.filter((pl.col("duration_s") < WINDOW_S)
                         | (pl.col("planned_at_s") + WINDOW_S > pl.col("t_end_s")))
    problems += [{"file": f, "problem": f"session too short for a {WINDOW_S} s window at its "
                                        "planned time"} for f in short["file"]]
    rates = frame.select("file", ((pl.col("n_samples") - 1) / pl.col("duration_s"))
                         .alias("rate_hz"))
    problems += [{"file": f, "problem": rate_warning(rate)}
                 for f, rate in zip(rates["file"], rates["rate_hz"], strict=True)
                 if rate is not None and rate_warning(rate)]
    durations = frame["duration_s"]
    return {
        "sessions": total,
        "counts": {
            "by_condition_pose_action": _records(
                frame.group_by("condition", "pose_of_contact", "action")
                .agg(pl.len().alias("sessions"))
                .rename({"pose_of_contact": "pose"}).sort("condition", "pose", "action")),
            "static_by_link": _records(
                frame.filter(pl.col("condition") == "static").group_by("link")
                .agg(pl.len().alias("sessions")).sort("link", nulls_last=True)),
            "dynamic_by_speed": _records(
                frame.filter(pl.col("condition") == "dynamic").group_by("band")
                .agg(pl.len().alias("sessions")).sort("band")
                .select((pl.col("band") / 10).alias("speed_from_rad_s"),
                        ((pl.col("band") + 1) / 10).alias("speed_to_rad_s"), "sessions")),
            "by_action": _records(by_action),
        },
        "class_balance_warnings": warnings,
        "durations": {"total_s": float(cast(float, durations.sum()) or 0.0),
                      "mean_s": float(cast(float, durations.mean()) or 0.0),
                      "median_s": float(cast(float, durations.median()) or 0.0),
                      "min_s": float(cast(float, durations.min()) or 0.0),
                      "max_s": float(cast(float, durations.max()) or 0.0)},
        "sources": _records(frame.group_by("source").agg(pl.len().alias("sessions"))
                            .sort("source")),
        "operators": _records(frame.group_by("operator").agg(pl.len().alias("sessions"))
                              .sort("operator")),
        "robots": _records(frame.group_by("robot").agg(pl.len().alias("sessions"))
                           .sort("robot")),
        "recovered": int(frame["recovered"].sum()),
        "problems": problems,
        "index_fingerprint": hashlib.sha256("\n".join(
            f"{s}:{b}" for s, b in sorted(zip(frame["session_id"], frame["file_bytes"],
                                                strict=True))).encode()).hexdigest(),
        "_durations": durations.to_numpy(),
        "_frame": frame,
    }


def beyond_limits(summary: dict) -> str | None:
    """Return one line when a session's peaks are beyond the robot's limits with their
    margins (see :mod:`contactkit.features.limits`): an unstable simulation or a corrupt
    recording, to be left out of training. None when within."""
    for key, margin, what in (("max_torque_fraction", TORQUE_MARGIN, "torque"),
                              ("max_speed_fraction", SPEED_MARGIN, "speed")):
        fractions = np.asarray(summary.get(key) or [0.0], dtype=float)
        if np.nanmax(fractions) > margin:
            joint = int(np.nanargmax(fractions)) + 1
            return (f"beyond the robot's limits: {what} of joint {joint} reaches "
                    f"{np.nanmax(fractions):.3g} x its limit (unstable simulation or corrupt "
                    "recording?)")
    margins = np.asarray(summary.get("limit_margin_rad") or [0.0], dtype=float)  # None: nan
    if np.any(margins < -POSITION_SLACK_RAD):
        joint = int(np.nanargmin(margins)) + 1
        return (f"beyond the robot's limits: joint {joint} leaves its range by "
                f"{-np.nanmin(margins):.3g} rad")
    return None


def _least_margins(margins: list[list[float | None]]) -> list[float | None]:
    """Return each joint's least margin to its position limits [rad] over the sessions,
    None for a joint without limits (a continuous one)."""
    least = np.fmin.reduce(np.array(margins, dtype=float), axis=0)  # skips None (nan)
    return [None if np.isnan(m) else float(m) for m in least]


def deep_stats(paths: list[Path], workers: int,
               progress: Callable[[int, int], None] | None = None, *,
               scheduler: str | None = None, dynamics: ArmDynamics | None = None) -> dict:
    """Read every session in ``workers`` processes (or on the Dask ``scheduler``) and
    aggregate the summaries (residuals with the arm's identified ``dynamics`` when
    given)."""
    summaries = list(map_ordered(partial(session_summary, dynamics=dynamics),
                                 [str(p) for p in paths], workers=workers,
                                 progress=progress, scheduler=scheduler))
    good = [s for s in summaries if "problem" not in s]
    problems = [{"file": s["file"], "problem": s["problem"]} for s in summaries
                if "problem" in s]
    problems += [{"file": s["file"], "problem": why} for s in good
                 if (why := beyond_limits(s)) is not None]
    return _aggregate(good) | {"problems": problems, "_summaries": good}


def _spread(values: list[float]) -> dict:
    arr = np.array([v for v in values if v is not None and np.isfinite(v)], dtype=float)
    if arr.size == 0:
        return {"n": 0, "median": None, "p10": None, "p90": None}
    return {"n": int(arr.size), "median": float(np.median(arr)),
            "p10": float(np.percentile(arr, 10)), "p90": float(np.percentile(arr, 90))}


def _agreement_by_robot(good: list[dict]) -> list[dict]:
    """Per robot, the median over its sessions with the robot's own estimate of the
    residual's agreement with it (per joint: correlation, RMS difference [Nm])."""
    out = []
    for robot in sorted({s["robot"] for s in good}):
        found = [s["residual_agreement"] for s in good
                 if s["robot"] == robot and s.get("residual_agreement")]
        if not found:
            continue

        def median(key: str, found: list[dict] = found) -> list[float | None]:
            values = np.array([[np.nan if v is None else v for v in a[key]] for a in found])
            return [None if np.isnan(v) else round(float(v), 4)
                    for v in np.nanmedian(values, axis=0)] if values.size else []

        out.append({"robot": robot, "sessions": len(found),
                    "correlation": median("correlation"),
                    "rms_difference_nm": median("rms_difference_nm")})
    return out


def _aggregate(good: list[dict]) -> dict:
    if not good:
        return {"sampling": None, "noise_baseline": None, "peaks_by_class": [],
                "window_detection": [], "onset_delay_s": _spread([]),
                "residual_agreement": [], "joint_limits": None}
    steps = [s["sampling"] for s in good]
    none = [s for s in good if s["action"] == "none"]
    noise = None
    if none:
        noise = {"sessions": len(none),
                 "tau_std_nm": np.mean([s["tau_std_nm"] for s in none], axis=0).tolist(),
                 "tau_sigma_nm": np.mean([s["tau_sigma_nm"] for s in none], axis=0).tolist(),
                 "dq_sigma_rad_s": np.mean([s["dq_sigma_rad_s"] for s in none], axis=0).tolist(),
                 "q_sigma_rad": np.mean([s["q_sigma_rad"] for s in none], axis=0).tolist(),
                 "tau_bias_nm": np.std([s["r_median_nm"] for s in none], axis=0).tolist()}
    peaks, windows = [], []
    for action in ACTIONS:
        group = [s for s in good if s["action"] == action]
        if not group:
            continue
        peaks.append({"action": action, "sessions": len(group),
                      "peak_residual_norm_nm": _spread([s["peak_residual_norm_nm"]
                                                        for s in group]),
                      "peak_force_n": _spread([s["peak_force_n"] for s in group])})
        found = [s["window_found"] for s in group if s["window_found"] is not None]
        windows.append({"action": action, "found": int(sum(found)),
                        "fallback": int(len(found) - sum(found))})
    return {
        "sampling": {"rate_hz": _spread([s["rate_hz"] for s in steps]),
                     "median_step_s": _spread([s["median_step_s"] for s in steps]),
                     "jitter_s": _spread([s["jitter_s"] for s in steps]),
                     "max_step_s": max(s["max_step_s"] for s in steps),
                     "sessions_with_gaps": int(sum(s["gaps"] > 0 for s in steps)),
                     "gaps": int(sum(s["gaps"] for s in steps)),
                     "dropped_estimate": int(sum(s["dropped_estimate"] for s in steps)),
                     "restarts": int(sum(s["restarts"] for s in steps))},
        "noise_baseline": noise,
        "peaks_by_class": peaks,
        "window_detection": windows,
        "onset_delay_s": _spread([s["onset_delay_s"] for s in good]),
        "residual_agreement": _agreement_by_robot(good),
        "joint_limits": {
            "min_margin_rad": _least_margins([s["limit_margin_rad"] for s in good]),
            "max_speed_fraction": np.max([s["max_speed_fraction"] for s in good],
                                         axis=0).tolist(),
            "max_torque_fraction": np.max([s["max_torque_fraction"] for s in good],
                                          axis=0).tolist()},
    }


def file_fingerprint(summaries: list[dict]) -> str:
    """Return the SHA-256 over the sorted (session id, file SHA-256) pairs."""
    pairs = sorted(f"{s['session_id']}:{s['sha256']}" for s in summaries)
    return hashlib.sha256("\n".join(pairs).encode()).hexdigest()


def write_noise_file(path: Path, noise: dict, dataset: Path, *, overwrite: bool = False,
                     default: bool = False) -> Path:
    """Write the no-contact noise baseline as a simulator noise file (--noise-file);
    return its path. An existing file is replaced only with ``overwrite``, or for the
    ``default`` report's noise file when ``stats`` wrote it."""
    sensor = SensorNoise(tau_sigma_nm=noise["tau_sigma_nm"],
                         dq_sigma_rad_s=noise["dq_sigma_rad_s"],
                         q_sigma_rad=noise["q_sigma_rad"], tau_bias_nm=noise["tau_bias_nm"],
                         source=f"recorder stats --deep {dataset} ({noise['sessions']} "
                                "no-contact sessions)")
    doc = json.loads(sensor.to_json()) | {"thesis_tau_std_nm": noise["tau_std_nm"]}
    return write_text(path, json.dumps(doc, indent=2), overwrite=overwrite,
                      owned=owned_by_marker(b"recorder stats --deep") if default else None)


def build_report(directory: Path, deep: bool, workers: int,
                 progress: Callable[[int, int], None] | None = None, *,
                 scheduler: str | None = None, dynamics: ArmDynamics | None = None) -> dict:
    """Compute the whole report of a dataset directory (see the module docstring); the
    deep part reads the sessions in ``workers`` processes or on the Dask ``scheduler``,
    with the arm's identified ``dynamics`` (``--dynamics``) when given."""
    index, index_problems = load_index(directory)
    stats = index_stats(index)
    report = {"schema": SCHEMA_ID, "dataset": str(directory),
              "generated_utc": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
              **{k: v for k, v in stats.items() if not k.startswith("_")}}
    report["problems"] = index_problems + stats["problems"]
    report["fingerprint"] = {"kind": "index (session ids and file sizes)",
                             "sha256": stats["index_fingerprint"]}
    del report["index_fingerprint"]
    report["deep"] = None
    private = {"durations": stats["_durations"], "frame": stats["_frame"], "summaries": []}
    if deep:
        files = [directory / name for name in stats["_frame"]["file"].to_list()]
        deep_part = deep_stats(files, workers, progress, scheduler=scheduler,
                               dynamics=dynamics)
        report["problems"] += deep_part.pop("problems")
        private["summaries"] = deep_part.pop("_summaries")
        report["deep"] = deep_part
        report["fingerprint"] = {"kind": "files (session ids and file SHA-256)",
                                 "sha256": file_fingerprint(private["summaries"])}
    report["_private"] = private
    return report

