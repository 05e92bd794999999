"""Generate the Franka Research 3 (FR3) URDF files shipped in ``contactkit/robots/data/fr3``.

This is a one-off maintenance script, not used at run time: contactkit reads the plain
URDF files it writes. Run it again only to update the description::

    pip install xacro              # the PyPI package; no ROS installation is needed
    git clone https://github.com/frankaemika/franka_description /tmp/franka_description
    python tools/make_fr3_urdf.py --source /tmp/franka_description

It expands ``robots/fr3/fr3.urdf.xacro`` of franka_description (Apache-2.0) twice with
xacro, ``$(find franka_description)`` resolving to ``--source``:

- ``fr3.urdf``: the arm alone (``hand:=false``);
- ``fr3_hand.urdf``: the arm with the Franka Hand (``hand:=true ee_id:=franka_hand``);

both with ``ros2_control:=false gazebo:=false with_sc:=false`` and the default arm id
``fr3`` (links ``fr3_link0`` .. ``fr3_link8``, ``fr3_hand``, ``fr3_hand_tcp``,
``fr3_leftfinger``, ``fr3_rightfinger``; joints ``fr3_joint1`` .. ``fr3_joint7``,
``fr3_finger_joint1``/``2``). Then it

- drops every ``<visual>`` and gives each link one visual per collision element, with the
  same origin and geometry, so a viewer draws the small collision meshes (the upstream
  visual meshes are large .dae files and are not shipped);
- rewrites mesh references from ``package://franka_description/...`` to paths relative to
  the URDF file's folder (``meshes/collision/link3.stl``) and copies those STL files;
- drops the comments xacro carried over (they name local paths) and puts a header
  comment naming the source and commit in their place;
- copies LICENSE and NOTICE and writes PROVENANCE.md.

Kinematics, inertials, joint limits and the ``<dynamics>`` tags are left as xacro wrote
them.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import importlib.metadata
import shutil
import subprocess
import sys
import xml.dom.minidom
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = REPO_ROOT / "contactkit" / "robots" / "data" / "fr3"
SOURCE_URL = "https://github.com/frankaemika/franka_description"
PACKAGE = "franka_description"
XACRO_FILE = "robots/fr3/fr3.urdf.xacro"
MESH_DIR = "meshes/collision"

COMMON_ARGS = {
    "ee_id": "franka_hand",
    "ros2_control": "false",
    "gazebo": "false",
    "with_sc": "false",
}
VARIANTS = {
    "fr3.urdf": {"hand": "false", **COMMON_ARGS},
    "fr3_hand.urdf": {"hand": "true", **COMMON_ARGS},
}
# Elements that only matter to ROS tooling; none is expected with the arguments above,
# and any that appear are removed.
DROP_TAGS = ("ros2_control", "gazebo", "transmission")


def xacro_command(mappings: dict[str, str]) -> str:
    args = " ".join(f"{k}:={v}" for k, v in mappings.items())
    return f"xacro {XACRO_FILE} {args}"


def run_xacro(source: Path, mappings: dict[str, str]) -> xml.dom.minidom.Document:
    """Expand the FR3 xacro with ``$(find franka_description)`` pointing at ``source``."""
    try:
        import xacro
        import xacro.substitution_args
    except ImportError:
        sys.exit("this script needs the xacro package: pip install xacro")

    def find(pkg: str) -> str:
        if pkg != PACKAGE:
            raise xacro.substitution_args.SubstitutionException(
                f"$(find {pkg}): only {PACKAGE} is known here"
            )
        return str(source)

    # $(find ...) normally asks ament_index (ROS 2); without ROS, resolve it ourselves.
    xacro.substitution_args._eval_find = find
    return xacro.process_file(str(source / XACRO_FILE), mappings=dict(mappings))


def elements(node: xml.dom.minidom.Node, tag: str) -> list[xml.dom.minidom.Element]:
    return list(node.getElementsByTagName(tag))


def strip_comments_and_blanks(node: xml.dom.minidom.Node) -> None:
    for child in list(node.childNodes):
        if child.nodeType == child.COMMENT_NODE or (
            child.nodeType == child.TEXT_NODE and not child.data.strip()
        ):
            node.removeChild(child)
        else:
            strip_comments_and_blanks(child)


def relative_mesh(filename: str, source: Path, meshes: dict[str, Path]) -> str:
    """Map ``package://franka_description/x/y/link3.stl`` to ``meshes/collision/link3.stl``
    and record the file to copy."""
    prefix = f"package://{PACKAGE}/"
    if not filename.startswith(prefix):
        raise ValueError(f"unexpected mesh reference {filename!r}")
    src = source / filename[len(prefix) :]
    name = src.name
    if name in meshes and meshes[name] != src:
        raise ValueError(f"two meshes named {name}: {meshes[name]} and {src}")
    if not src.is_file():
        raise FileNotFoundError(src)
    meshes[name] = src
    return f"{MESH_DIR}/{name}"


def postprocess(doc: xml.dom.minidom.Document, source: Path, meshes: dict[str, Path]) -> None:
    robot = doc.documentElement
    strip_comments_and_blanks(doc)
    for tag in DROP_TAGS:
        for el in elements(robot, tag):
            el.parentNode.removeChild(el)

    for link in elements(robot, "link"):
        for visual in [c for c in link.childNodes if getattr(c, "tagName", "") == "visual"]:
            link.removeChild(visual)
        collisions = [c for c in link.childNodes if getattr(c, "tagName", "") == "collision"]
        for mesh in (m for c in collisions for m in elements(c, "mesh")):
            path = relative_mesh(mesh.getAttribute("filename"), source, meshes)
            mesh.setAttribute("filename", path)
        # visuals go first, each a copy of one collision element
        first = collisions[0] if collisions else None
        link_name = link.getAttribute("name")
        for i, collision in enumerate(collisions):
            visual = doc.createElement("visual")
            for child in collision.childNodes:
                visual.appendChild(child.cloneNode(deep=True))
            suffix = "" if len(collisions) == 1 else f"_{i}"
            visual.setAttribute("name", f"{link_name}_visual{suffix}")
            link.insertBefore(visual, first)

    text = doc.toxml()
    for tag in DROP_TAGS:
        assert f"<{tag}" not in text, tag
    assert "package://" not in text


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def source_commit(source: Path, given: str | None) -> tuple[str, str]:
    """The source's commit id and commit date (``git -C source``), or ``given``."""
    if given:
        return given, ""
    try:
        out = subprocess.run(
            ["git", "-C", str(source), "log", "-1", "--format=%H %cI"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.split()
        return out[0], out[1]
    except (subprocess.CalledProcessError, FileNotFoundError, IndexError):
        sys.exit(f"{source} is not a git checkout: pass --commit SHA of the snapshot")


def write_provenance(
    out: Path, commit: str, commit_date: str, xacro_version: str, files: list[str]
) -> None:
    today = datetime.datetime.now(datetime.UTC).date().isoformat()
    rows = "\n".join(
        f"| `{f}` | {(out / f).stat().st_size} | `{sha256(out / f)[:16]}` |" for f in files
    )
    commands = "\n".join(f"    {xacro_command(m)}    # -> {name}" for name, m in VARIANTS.items())
    date_note = f" (committed {commit_date})" if commit_date else ""
    text = f"""# FR3 robot description: provenance

Generated on {today} by `tools/make_fr3_urdf.py`; do not edit these files by hand, run
the script again instead.

- Source: {SOURCE_URL}, commit `{commit}`{date_note}.
- Licence: Apache License 2.0, copyright 2023 Franka Robotics GmbH; see `LICENSE` and
  `NOTICE`, copied unchanged from the source.
- Expanded with xacro {xacro_version} (PyPI package `xacro`), `$(find {PACKAGE})`
  resolved to the source checkout, from the source's root:

{commands}

  `arm_id` is left at its default, `fr3`.

## Changes made to xacro's output

- Every `<visual>` is replaced by copies of the link's `<collision>` elements (same
  origin and geometry): viewers draw the collision meshes, and the large upstream visual
  meshes (`meshes/robot_arms/fr3/visual/*.dae`, `meshes/robot_ee/franka_hand_white/visual/*.dae`)
  are not shipped. The fingers' visuals are therefore their collision boxes.
- Mesh references `package://{PACKAGE}/meshes/robot_arms/fr3/collision/linkN.stl` and
  `package://{PACKAGE}/meshes/robot_ee/franka_hand_white/collision/hand.stl` are rewritten
  to paths relative to the URDF file's folder, `{MESH_DIR}/linkN.stl` and
  `{MESH_DIR}/hand.stl`; the STL files are copied unchanged.
- XML comments are removed (xacro's banner names the local path of the source) and a
  header comment naming the source is added.
- Nothing else: kinematics, inertials, joint limits, `<safety_controller>` and the
  `<dynamics>` tags (with franka's extra attributes `D`, `K`, `mu_coulomb`, `mu_viscous`)
  are as xacro wrote them.

## Files

| file | bytes | sha256 (first 16 hex) |
|---|---|---|
{rows}
"""
    (out / "PROVENANCE.md").write_text(text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--source", type=Path, required=True, help="franka_description checkout")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"default: {DEFAULT_OUT}")
    parser.add_argument("--commit", help="commit id of the source, when it is not a git checkout")
    args = parser.parse_args(argv)
    source = args.source.resolve()
    out = args.out
    if not (source / XACRO_FILE).is_file():
        parser.error(f"{source / XACRO_FILE} not found")
    commit, commit_date = source_commit(source, args.commit)

    try:
        xacro_version = importlib.metadata.version("xacro")
    except importlib.metadata.PackageNotFoundError:
        sys.exit("this script needs the xacro package: pip install xacro")
    (out / MESH_DIR).mkdir(parents=True, exist_ok=True)
    meshes: dict[str, Path] = {}
    written: list[str] = []
    for name, mappings in VARIANTS.items():
        doc = run_xacro(source, mappings)
        postprocess(doc, source, meshes)
        header = doc.createComment(
            f" Generated by tools/make_fr3_urdf.py from {SOURCE_URL} at commit {commit}"
            f" (Apache-2.0, see LICENSE and NOTICE), robots/fr3/fr3.urdf.xacro with"
            f" hand:={mappings['hand']}; visuals replaced by the collision geometry, mesh paths"
            " relative to this file. See PROVENANCE.md for the xacro arguments."
            " Do not edit by hand. "
        )
        doc.insertBefore(header, doc.documentElement)
        (out / name).write_text(doc.toprettyxml(indent="  "))
        written.append(name)

    for name, src in sorted(meshes.items()):
        shutil.copyfile(src, out / MESH_DIR / name)
        written.append(f"{MESH_DIR}/{name}")
    for name in ("LICENSE", "NOTICE"):
        shutil.copyfile(source / name, out / name)
        written.append(name)
    write_provenance(out, commit, commit_date, xacro_version, written)
    written.append("PROVENANCE.md")
    total = sum((out / f).stat().st_size for f in written)
    print(f"wrote {len(written)} files, {total} bytes, to {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
