"""Checking the transform frames of an .rrd file from the file itself (no viewer).

Rerun resolves 3-D data through named frames: each ``Transform3D`` with
``child_frame`` / ``parent_frame`` is an edge, an entity's data sit in the frame its
``CoordinateFrame`` names, or else in the implicit frame ``tf#/<entity path>``. The
viewer reports an error when an entity's frame has no path to the view's target frame
("No transform path from ...") and when two entities define the same child frame,
except for one static and one temporal definition ("Two entities define the same
child frame").
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import rerun.chunk as rc

from contactkit.viewer import layout

SPATIAL_3D = ("Arrows3D", "Mesh3D", "Asset3D", "Points3D", "Boxes3D", "LineStrips3D",
              "Ellipsoids3D", "Capsules3D", "Cylinders3D")


def _values(batch, column: str) -> list[str]:
    return [v for row in batch.column(column).to_pylist() for v in (row or []) if v]


def frame_problems(path: Path, root: str = layout.BASE_FRAME) -> list[str]:
    """Return one line per frame problem in the recording at ``path``: a 3-D entity whose
    frame has no transform path to ``root``, or a child frame defined by two entities of
    the same kind (static or temporal). Empty when the viewer has nothing to report."""
    parents: dict[str, set[str]] = defaultdict(set)
    definers: dict[tuple[str, bool], set[str]] = defaultdict(set)
    frames: dict[str, set[str]] = defaultdict(set)
    spatial: set[str] = set()
    for chunk in rc.RrdReader(path).stream():
        batch = chunk.to_record_batch()
        names = batch.schema.names
        entity = chunk.entity_path
        if "Transform3D:child_frame" in names:
            children = _values(batch, "Transform3D:child_frame")
            for child, parent in zip(children, _values(batch, "Transform3D:parent_frame"),
                                     strict=True):
                parents[child].add(parent)
            for child in set(children):
                definers[(child, chunk.is_static)].add(entity)
        if "CoordinateFrame:frame" in names:
            frames[entity].update(_values(batch, "CoordinateFrame:frame"))
        if any(n.split(":")[0] in SPATIAL_3D for n in names):
            spatial.add(entity)
    problems = [f"frame {child!r} is defined {'statically' if static else 'over time'} by "
                f"{len(who)} entities: {', '.join(sorted(who))}"
                for (child, static), who in sorted(definers.items()) if len(who) > 1]
    for entity in sorted(spatial):
        for frame in sorted(frames.get(entity) or {f"tf#{entity}"}):
            if not _reaches(frame, root, parents):
                problems.append(f"{entity}: no transform path from {frame!r} to {root!r}")
    return problems


def _reaches(frame: str, root: str, parents: dict[str, set[str]]) -> bool:
    seen, todo = set(), [frame]
    while todo:
        current = todo.pop()
        if current == root:
            return True
        if current in seen:
            continue
        seen.add(current)
        todo += parents.get(current, ())
    return False


def verify_problems(*paths: Path) -> list[str]:
    """Return what ``rerun rrd verify`` (the SDK's own check that the viewer can load
    and interpret a file) reports on ``paths``; empty when they pass."""
    if not paths:
        return []
    rerun = Path(sys.executable).with_name("rerun")
    done = subprocess.run([str(rerun), "rrd", "verify", *map(str, paths)],
                          capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, RERUN_ANALYTICS="0"))
    if done.returncode == 0:
        return []
    return [line for line in (done.stdout + done.stderr).splitlines()
            if "Failed" in line or "rror" in line][:20] or [done.stderr[-2000:]]


def assert_frames_ok(path: Path) -> None:
    """Fail with the list of problems when the recording at ``path`` has frame problems
    or fails ``rerun rrd verify``."""
    problems = frame_problems(path) + verify_problems(path)
    assert not problems, f"{path}:\n" + "\n".join(problems)
