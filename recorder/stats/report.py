"""Rendering a statistics report: plots, terminal summary, HTML, Markdown or JSON.

HTML is one self-contained file (plots embedded as PNG data) with plain styled
tables; Markdown comes with its PNGs beside it; JSON
(``schemas/stats_report.schema.json``) is for machines. Tables are built as Polars
data frames and rendered here, numbers formatted with the unit in the column
header. Plots use the viewer's class colours (:mod:`contactkit.viewer.layout`).
"""

from __future__ import annotations

import base64
import html
import json
import os
from io import BytesIO
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import polars as pl
from rich.console import Console
from rich.table import Table

from contactkit.recorder.stats.deep import PROFILE_T
from contactkit.schemas import ACTIONS
from contactkit.util.atomic import Owned, check_target, write_bytes, write_text
from contactkit.util.owned import owned_by_marker
from contactkit.util.text import console_text
from contactkit.viewer.palette import CLASS_COLORS, JOINT_COLORS

FORMATS = ("html", "md", "json")


NEUTRAL = "#707070"
PAGE_STYLE = (
    "body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;color:#222;"
    "line-height:1.45}h1{font-size:1.6em}h2{font-size:1.2em;margin-top:1.8em;"
    "border-bottom:1px solid #ddd;padding-bottom:.2em}table{border-collapse:collapse;"
    "margin:.5em 0;font-size:.92em}th,td{padding:.3em .8em;border-bottom:1px solid #e4e4e4}"
    "th{background:#f3f3f3;text-align:left;font-weight:600}td.num{text-align:right;"
    "font-variant-numeric:tabular-nums}tr:hover td{background:#fafafa}img{max-width:100%}"
    "code{background:#f3f3f3;padding:0 .2em}")


def _color(action: str) -> tuple[float, float, float]:
    r, g, b = CLASS_COLORS.get(action, (0, 0, 0))
    return r / 255, g / 255, b / 255


REPORT_MARK = "contactkit dataset report"
"""Written into every report file (and its plots), so that ``stats`` recognises its own
default report and replaces it, but no other file."""
OWNED_REPORT: Owned = owned_by_marker(REPORT_MARK.encode(), within=1 << 16)


def report_path(out: Path, fmt: str) -> Path:
    """Return ``out`` with the format's extension added when it has none."""
    return out if out.suffix else out.with_name(f"{out.name}.{fmt}")


def format_cell(value, column: str) -> str:
    """Return a table cell as text: shares in percent, floats to 4 significant digits,
    nothing for a missing value."""
    if value is None or (isinstance(value, float) and np.isnan(value)):
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{100 * value:.0f}" if column.endswith("[%]") else f"{value:.4g}"
    return str(value)


def make_plots(report: dict) -> list[tuple[str, str, bytes]]:
    """Return (title, caption, PNG bytes) for every plot of the report."""
    plots = []
    counts = pl.DataFrame(report["counts"]["by_condition_pose_action"])
    if counts.height:
        fig, (ax, balance) = plt.subplots(1, 2, figsize=(11, 3.8),
                                          gridspec_kw={"width_ratios": [3, 1]})
        # imported sessions may name no pose (None), listed last
        poses = sorted(set(counts["pose"].to_list()), key=lambda p: (p is None, p or ""))
        x = np.arange(len(poses))
        conditions = [c for c in ("static", "dynamic") if (counts["condition"] == c).any()]
        width = 0.8 / len(conditions)
        for i, condition in enumerate(conditions):
            part = counts.filter(pl.col("condition") == condition)
            bottom = np.zeros(len(poses))
            for action in ACTIONS:
                values = np.array([part.filter(pl.col("pose").eq_missing(p)
                                               & (pl.col("action") == action))["sessions"].sum()
                                   for p in poses])
                ax.bar(x + i * width, values, width, bottom=bottom, color=_color(action),
                       label=action if i == 0 else None,
                       hatch="//" if condition == "dynamic" else None)
                bottom += values
        ax.set_xticks(x + width * (len(conditions) - 1) / 2,
                      ["no pose" if p is None else p for p in poses])
        ax.set_title("sessions by pose (hatched: dynamic, by target pose)")
        ax.set_ylabel("sessions")
        ax.legend(fontsize=8)
        actions = [r["action"] for r in report["counts"]["by_action"]]
        balance.bar(actions, [r["sessions"] for r in report["counts"]["by_action"]],
                    color=[_color(a) for a in actions])
        balance.set_title("class balance")
        plots.append(("Sessions", "Sessions per pose and action, and per class. Static "
                      "sessions are grouped by the held pose, dynamic ones by the target of "
                      "the move.", _png(fig)))
    durations = report["_private"]["durations"]
    if len(durations):
        fig, ax = plt.subplots(figsize=(6, 3))
        ax.hist(durations, bins=30, color=NEUTRAL)
        ax.set_xlabel("session duration [s]")
        ax.set_ylabel("sessions")
        plots.append(("Durations", "How long the sessions are.", _png(fig)))
    summaries = report["_private"]["summaries"]
    if summaries:
        plots += _deep_plots(summaries)
    return plots


def _deep_plots(summaries: list[dict]) -> list[tuple[str, str, bytes]]:
    plots = []
    by_action = {a: [s for s in summaries if s["action"] == a] for a in ACTIONS}
    present = [a for a in ACTIONS if by_action[a]]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, key, label in ((axes[0], "peak_residual_norm_nm", "peak |r| [Nm]"),
                           (axes[1], "peak_force_n", "peak estimated |f| [N]")):
        data = [[s[key] for s in by_action[a]] for a in present]
        parts = ax.boxplot(data, tick_labels=present, patch_artist=True, showfliers=True)
        for patch, action in zip(parts["boxes"], present, strict=True):
            patch.set_facecolor(_color(action))
        ax.set_ylabel(label)
        ax.set_yscale("log")
    plots.append(("Peaks by class", "Per session, the largest observer-residual norm and the "
                  "largest estimated end-effector force. A class whose box overlaps 'none' "
                  "holds contacts the robot barely felt.", _png(fig)))
    fig, axes = plt.subplots(1, len(present), figsize=(3.2 * len(present), 3.2), sharey=True,
                             squeeze=False)
    for ax, action in zip(axes[0], present, strict=True):
        profiles = [s["force_profile_n"] for s in by_action[action] if s["force_profile_n"]]
        for profile in profiles[:40]:
            ax.plot(PROFILE_T, profile, color=_color(action), alpha=0.35, linewidth=0.8)
        ax.set_title(action)
        ax.set_xlabel("time from onset [s]")
    axes[0][0].set_ylabel("estimated |f| [N]")
    plots.append(("Force profiles", "Estimated end-effector force magnitude around the onset "
                  "(detected, or planned when nothing was detected), up to 40 sessions per "
                  "class, in the style of the thesis's Figure 3.2.", _png(fig)))
    delays = [s["onset_delay_s"] for s in summaries if s["onset_delay_s"] is not None]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.2))
    found = [sum(bool(s["window_found"]) for s in by_action[a]) for a in present]
    fallback = [sum(s["window_found"] is False for s in by_action[a]) for a in present]
    axes[0].bar(present, found, color="#55a868", label="detected")
    axes[0].bar(present, fallback, bottom=found, color="#c44e52", label="fell back to planned")
    axes[0].legend(fontsize=8)
    axes[0].set_title("Difference window method")
    if delays:
        axes[1].hist(delays, bins=30, color=NEUTRAL)
    axes[1].set_xlabel("detected minus planned onset [s]")
    axes[1].set_title("onset delay")
    plots.append(("Windows", "Left: how often the Difference method (Algorithm 4) found the "
                  "interaction per class; for 'none' every detection is a false alarm. Right: "
                  "the delay from the planned to the detected onset.", _png(fig)))
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.2))
    joints = np.arange(1, 8)
    for ax, key, label in ((axes[0], "limit_margin_rad", "distance to position limit [rad]"),
                           (axes[1], "max_speed_fraction", "max |dq| / limit"),
                           (axes[2], "max_torque_fraction", "max |tau| / limit")):
        values = np.array([s[key] for s in summaries], dtype=float)
        # a continuous joint has no margin (None, here nan): no position limit to approach
        parts = ax.boxplot([v[np.isfinite(v)] for v in values.T], tick_labels=joints,
                           patch_artist=True)
        for patch, color in zip(parts["boxes"], JOINT_COLORS, strict=True):
            patch.set_facecolor(tuple(c / 255 for c in color))
        ax.set_xlabel("joint")
        ax.set_title(label, fontsize=9)
    plots.append(("Joint limits", "Per session and joint: the closest approach to a position "
                  "limit, and the largest speed and torque as fractions of their limits.",
                  _png(fig)))
    none = by_action.get("none") or []
    if none:
        fig, ax = plt.subplots(figsize=(6, 3))
        ax.bar(joints, np.mean([s["tau_std_nm"] for s in none], axis=0),
               color=[tuple(c / 255 for c in color) for color in JOINT_COLORS])
        ax.set_xlabel("joint")
        ax.set_ylabel("std of tau [Nm]")
        plots.append(("Torque noise baseline", "Thesis section 5.3.5: the standard deviation "
                      "of each joint's torque over a no-contact session, averaged over "
                      "sessions.", _png(fig)))
    return plots


def _png(fig) -> bytes:
    fig.tight_layout()
    buffer = BytesIO()
    fig.savefig(buffer, format="png", dpi=110, metadata={"Software": REPORT_MARK})
    plt.close(fig)
    return buffer.getvalue()


def public(report: dict) -> dict:
    """Return the report without its private, non-JSON parts."""
    return {k: v for k, v in report.items() if not k.startswith("_")}


def _tables(report: dict) -> list[tuple[str, pl.DataFrame]]:
    tables = [("Sessions by condition, pose and action",
               pl.DataFrame(report["counts"]["by_condition_pose_action"]).pivot(
                   on="action", index=["condition", "pose"], values="sessions")
               if report["counts"]["by_condition_pose_action"] else pl.DataFrame()),
              ("Static sessions by touched link (empty: no contact)",
               pl.DataFrame(report["counts"]["static_by_link"])),
              ("Dynamic sessions by speed band [rad/s]",
               pl.DataFrame(report["counts"]["dynamic_by_speed"])),
              ("Class balance", pl.DataFrame(report["counts"]["by_action"]).rename(
                  {"share": "share [%]"}, strict=False)),
              ("Sources", pl.DataFrame(report["sources"])),
              ("Operators", pl.DataFrame(report["operators"])),
              ("Robots", pl.DataFrame(report["robots"]))]
    deep = report["deep"]
    if deep:
        rows = [{"action": p["action"], "sessions": p["sessions"],
                 "peak |r| median [Nm]": p["peak_residual_norm_nm"]["median"],
                 "peak |f| median [N]": p["peak_force_n"]["median"]}
                for p in deep["peaks_by_class"]]
        tables.append(("Peaks by class", pl.DataFrame(rows)))
        tables.append(("Difference window method", pl.DataFrame(deep["window_detection"])))
        if deep["noise_baseline"]:
            noise = deep["noise_baseline"]
            tables.append(("Torque noise of no-contact sessions", pl.DataFrame({
                "joint": list(range(1, 8)), "std over session (thesis 5.3.5) [Nm]":
                noise["tau_std_nm"], "white-noise sigma [Nm]": noise["tau_sigma_nm"]})))
        for agreement in deep["residual_agreement"]:
            tables.append((f"Observer residual against the robot's own estimate "
                           f"(-tau_ext_hat), {agreement['robot']}, median over "
                           f"{agreement['sessions']} sessions", pl.DataFrame({
                               "joint": list(range(1, 8)),
                               "correlation": agreement["correlation"],
                               "RMS difference [Nm]": agreement["rms_difference_nm"]})))
        limits = deep["joint_limits"]
        if limits is not None:  # None when no session could be read
            tables.append(("Joint-limit proximity", pl.DataFrame({
                "joint": list(range(1, 8)), "min margin [rad]": limits["min_margin_rad"],
                "max |dq| / limit [%]": limits["max_speed_fraction"],
                "max |tau| / limit [%]": limits["max_torque_fraction"]})))
    return [(title, table) for title, table in tables if table.height]


def _summary_lines(report: dict) -> list[str]:
    d = report["durations"]
    lines = [f"{report['sessions']} sessions, {d['total_s'] / 60:.1f} min in all (median "
             f"{d['median_s']:.1f} s, {d['min_s']:.1f}-{d['max_s']:.1f} s); "
             f"{report['recovered']} recovered",
             f"fingerprint ({report['fingerprint']['kind']}): {report['fingerprint']['sha256']}"]
    deep = report["deep"]
    if deep and deep["sampling"]:
        s = deep["sampling"]
        lines.append(f"sampling: median {s['rate_hz']['median']:.1f} Hz, jitter "
                     f"{1e3 * s['jitter_s']['median']:.3f} ms, {s['gaps']} gaps in "
                     f"{s['sessions_with_gaps']} sessions (~{s['dropped_estimate']} samples "
                     f"missing), {s['restarts']} restarts of the observer and detector")
        for agreement in deep["residual_agreement"]:
            corr = " ".join("-" if c is None else f"{c:.2f}" for c in agreement["correlation"])
            lines.append(f"residual vs the robot's own estimate ({agreement['robot']}, "
                         f"{agreement['sessions']} sessions): correlation per joint {corr}")
        delay = deep["onset_delay_s"]
        if delay["n"]:
            lines.append(f"onset delay (detected - planned): median {delay['median']:.3f} s "
                         f"over {delay['n']} detections")
    return lines


def print_summary(report: dict, console: Console) -> None:
    """Print a compact summary: counts, warnings, problems and the fingerprint."""
    table = Table(title=f"dataset {report['dataset']}", title_justify="left")
    table.add_column("action")
    table.add_column("sessions", justify="right")
    table.add_column("share", justify="right")
    for row in report["counts"]["by_action"]:
        table.add_row(row["action"], str(row["sessions"]), f"{100 * row['share']:.0f} %")
    console.print(table)
    for line in _summary_lines(report):
        console.print(line)
    for warning in report["class_balance_warnings"]:
        console.print(f"[yellow]warning:[/] {warning}")
    if report["problems"]:
        console.print(f"[red]{len(report['problems'])} problems[/] (see the report):")
        for problem in report["problems"][:10]:
            console.print(f"  {console_text(problem['file'])}: "
                          f"{console_text(problem['problem'])}")


def _markdown_table(frame: pl.DataFrame) -> str:
    lines = ["| " + " | ".join(frame.columns) + " |", "|" + "---|" * frame.width]
    lines += ["| " + " | ".join(format_cell(v, c) for v, c in zip(row, frame.columns,
                                                                  strict=True)) + " |"
              for row in frame.iter_rows()]
    return "\n".join(lines)


def _html_table(frame: pl.DataFrame) -> str:
    numeric = [dtype.is_numeric() for dtype in frame.dtypes]
    head = "".join(f"<th>{html.escape(c)}</th>" for c in frame.columns)
    rows = []
    for row in frame.iter_rows():
        cells = "".join(f"<td{' class=num' if n else ''}>{html.escape(format_cell(v, c))}</td>"
                        for v, c, n in zip(row, frame.columns, numeric, strict=True))
        rows.append(f"<tr>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"


def session_recordings(report: dict, catalog: Path, out: Path) -> pl.DataFrame:
    """Return the dataset's sessions (id, file, action) with the path of each one's
    recording in the Rerun catalog folder ``catalog`` (``<session id>.rrd``, see
    ``recorder catalog``) relative to the report file ``out``'s folder, null where the
    catalog has none; and the command that opens the session in the catalog's viewer."""
    frame = report["_private"]["frame"].select("session_id", "file", "action")
    base = os.path.dirname(os.path.abspath(out))
    links = []
    for sid in frame["session_id"].to_list():
        path = Path(catalog) / f"{sid}.rrd"
        links.append(Path(os.path.relpath(os.path.abspath(path), base)).as_posix()
                     if path.is_file() else None)
    return frame.with_columns(pl.Series("recording", links, dtype=pl.String),
                              pl.Series("open", [f"recorder browse {catalog} --session {sid}"
                                                 for sid in frame["session_id"].to_list()]))


def _html_sessions(frame: pl.DataFrame) -> str:
    rows = []
    for sid, file, action, link, command in frame.iter_rows():
        cell = (f'<a href="{html.escape(link, quote=True)}">{html.escape(sid)}</a>'
                if link else html.escape(sid))
        rows.append(f"<tr><td>{cell}</td><td>{html.escape(file)}</td>"
                    f"<td>{html.escape(action)}</td><td><code>{html.escape(command)}</code>"
                    "</td></tr>")
    return ("<table><thead><tr><th>session (its recording)</th><th>file</th><th>action</th>"
            f"<th>open in the catalog's viewer</th></tr></thead><tbody>{''.join(rows)}"
            "</tbody></table>")


def write_report(report: dict, out: Path, fmt: str, *, overwrite: bool = False,
                 default: bool = False, catalog: Path | None = None) -> Path:
    """Write the report in ``fmt`` (html, md or json) to ``out`` (the format's extension
    added when it has none); return the path written. With a Rerun ``catalog`` folder
    (``recorder catalog``), the HTML and Markdown reports list every session linked to
    its recording there (:func:`session_recordings`).

    An existing file (the report or, for md, its plots) is replaced only with
    ``overwrite``, or, for the ``default`` output, when it is a report ``stats`` wrote.
    """
    out = report_path(out, fmt)
    owned = OWNED_REPORT if default else None

    def put(path: Path, text: str) -> Path:
        return write_text(path, text, overwrite=overwrite, owned=owned)

    if fmt == "json":
        return put(out, json.dumps({"generator": REPORT_MARK} | public(report), indent=2,
                                   default=float))
    plots = make_plots(report)
    intro = _summary_lines(report)
    problems = report["problems"]
    if fmt == "md":
        names = [f"{out.stem}_plot{i + 1}.png" for i in range(len(plots))]
        for path in [out, *(out.parent / name for name in names)]:  # all, before any is written
            check_target(path, overwrite=overwrite, owned=owned)
        parts = [f"<!-- {REPORT_MARK} -->", f"# Dataset report: {report['dataset']}", "",
                 *[f"- {x}" for x in intro]]
        parts += ["", "## Warnings", ""] + [f"- {w}" for w in report["class_balance_warnings"]
                                             or ["none"]]
        parts += ["", "## Problems", ""] + [f"- `{p['file']}`: {p['problem']}"
                                             for p in problems or [{"file": "-",
                                                                    "problem": "none"}]]
        for title, table in _tables(report):
            parts += ["", f"## {title}", "", _markdown_table(table)]
        if catalog is not None:
            parts += ["", f"## Sessions in the Rerun catalog {catalog}", ""]
            parts += [f"- [{sid}]({link}) `{file}` ({action}): `{command}`" if link else
                      f"- {sid} `{file}` ({action}): not in the catalog"
                      for sid, file, action, link, command
                      in session_recordings(report, catalog, out).iter_rows()]
        for name, (title, caption, png) in zip(names, plots, strict=True):
            write_bytes(out.parent / name, png, overwrite=overwrite, owned=owned)
            parts += ["", f"## {title}", "", caption, "", f"![{title}]({name})"]
        return put(out, "\n".join(parts) + "\n")
    body = [f"<h1>Dataset report: {html.escape(report['dataset'])}</h1>", "<ul>"]
    body += [f"<li>{html.escape(x)}</li>" for x in intro] + ["</ul>", "<h2>Warnings</h2><ul>"]
    body += [f"<li>{html.escape(w)}</li>" for w in report["class_balance_warnings"] or ["none"]]
    body += ["</ul>", "<h2>Problems</h2><ul>"]
    body += [f"<li><code>{html.escape(p['file'])}</code>: {html.escape(p['problem'])}</li>"
             for p in problems] or ["<li>none</li>"]
    body.append("</ul>")
    for title, table in _tables(report):
        body += [f"<h2>{html.escape(title)}</h2>", _html_table(table)]
    if catalog is not None:
        body += [f"<h2>Sessions in the Rerun catalog {html.escape(str(catalog))}</h2>",
                 _html_sessions(session_recordings(report, catalog, out))]
    for title, caption, png in plots:
        data = base64.b64encode(png).decode()
        body += [f"<h2>{html.escape(title)}</h2>", f"<p>{html.escape(caption)}</p>",
                 f'<img alt="{html.escape(title)}" src="data:image/png;base64,{data}">']
    page = ("<!doctype html><html><head><meta charset='utf-8'>"
            f"<meta name='generator' content='{REPORT_MARK}'><title>contactkit dataset "
            f"report</title><style>{PAGE_STYLE}</style></head><body>" + "\n".join(body)
            + "</body></html>")
    return put(out, page)
