"""Robot models chosen by name, like python-can's interfaces.

A session names its robot in its metadata (``robot``). The name is looked up here:

* the built-in ``panda`` and ``fr3`` (:mod:`contactkit.robots.builtin`); sessions
  written before robots were chosen per session say ``franka_panda``, an alias of
  ``panda``;
* robots that installed packages declare in the ``contactkit.robots`` entry-point
  group, each pointing at a :class:`~contactkit.robots.spec.RobotSpec` (or a
  function returning one)::

      [project.entry-points."contactkit.robots"]
      myarm = "mylab.myarm:MYARM"

  Listing the names reads the entry points' names only; a plugin is imported when
  its robot is used;
* ``urdf:PATH``: any 7-joint serial arm described by a URDF file
  (:func:`urdf_robot`). A session stores the URDF's SHA-256, and reading it on a
  machine whose file at PATH differs is an error, since a stored path does not
  travel.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from functools import cache
from pathlib import Path
from typing import cast

from contactkit.errors import InputError
from contactkit.robots.builtin import BUILTIN
from contactkit.robots.spec import N_JOINTS, RobotSpec
from contactkit.util.plugins import Registry
from contactkit.util.safe_open import read_input_text

ENTRY_POINT_GROUP = "contactkit.robots"
URDF_PREFIX = "urdf:"
DEFAULT_ROBOT = "panda"
_ALIASES = {alias: spec.name for spec in BUILTIN for alias in spec.aliases}


def _check(name: str, target: str, loaded: object) -> RobotSpec:
    spec = loaded() if callable(loaded) and not isinstance(loaded, RobotSpec) else loaded
    if not isinstance(spec, RobotSpec) or len(spec.joint_names) != N_JOINTS:
        raise InputError(f"robot {name!r} ({target}) is not a 7-joint RobotSpec")
    return spec


REGISTRY: Registry[RobotSpec] = Registry("robot", ENTRY_POINT_GROUP,
                                         {spec.name: spec for spec in BUILTIN}, _check,
                                         reserved=_ALIASES)
"""The named robots, built-in and plugins (:class:`contactkit.util.plugins.Registry`);
``urdf:PATH`` is not in it."""


def robot_names() -> list[str]:
    """Return the names of every known robot: built-in first, then plugins (names only,
    nothing is imported)."""
    return REGISTRY.names()


def canonical_robot_name(name: str) -> str:
    """Return the registry name of ``name`` (an alias such as ``franka_panda`` becomes
    ``panda``; ``urdf:PATH`` gets the absolute path, so that a session recorded with a
    relative one names its file from any folder). Raises InputError listing the known
    robots for an unknown name."""
    if not isinstance(name, str) or not name:
        raise InputError(f"robot name {name!r} is not a name")
    name = _ALIASES.get(name, name)
    if name.startswith(URDF_PREFIX):
        path = name[len(URDF_PREFIX):]
        if not path:
            raise InputError(f"robot {name!r} names no URDF file ({URDF_PREFIX}PATH)")
        return URDF_PREFIX + os.path.abspath(os.path.expanduser(path))
    if name in REGISTRY:
        return name
    shown = name if len(name) <= 60 else name[:57] + "..."
    raise InputError(f"unknown robot {shown!r} (known: {', '.join(robot_names())}, or "
                     f"{URDF_PREFIX}PATH for a 7-joint arm's URDF)")


def get_robot(name: str) -> RobotSpec:
    """Return the :class:`RobotSpec` registered under ``name`` (or an alias, or
    ``urdf:PATH``). Raises InputError for an unknown name or a plugin that cannot load."""
    name = canonical_robot_name(name)
    if name.startswith(URDF_PREFIX):
        return urdf_robot(name[len(URDF_PREFIX):])
    return REGISTRY.get(name)


@cache
def urdf_robot(path: str) -> RobotSpec:
    """Return a spec for the 7-joint serial arm in the URDF file at ``path``.

    The arm's joints are the first 7 revolute (or continuous) joints along the chain
    from the root link (side branches without such joints, frames of cameras or
    sensors, are left beside it); links 1..7 are their child links and the flange is
    the last link of the chain. No hand, friction or armature. Raises InputError for a file
    that cannot be read or holds no such chain.
    """
    file = Path(path).expanduser()
    root = parse_urdf(read_input_text(file, "robot's URDF", "urdf"), file)
    children: dict[str | None, list[ET.Element]] = {}
    for joint in root.iter("joint"):
        parent = joint.find("parent")
        assert parent is not None  # parse_urdf checked every joint's parent and child
        children.setdefault(parent.get("link"), []).append(joint)
    child_links = {cast(ET.Element, joint.find("child")).get("link")
                   for joint in root.iter("joint")}
    roots = [link.get("name") for link in root.iter("link")
             if link.get("name") not in child_links]

    def moves(joint: ET.Element) -> bool:
        """Whether ``joint`` or a joint below it turns (a side branch of fixed frames,
        a camera's or a sensor's, does not)."""
        stack, visited = [joint], set()
        while stack:
            joint = stack.pop()
            if joint.get("type") in ("revolute", "continuous"):
                return True
            if id(joint) not in visited:
                visited.add(id(joint))
                child = joint.find("child")
                assert child is not None  # every joint's child was checked above
                stack += children.get(child.get("link"), [])
        return False

    joints: list[str | None] = []
    links: list[str | None] = []
    seen: set[str] = set()
    link = roots[0] if len(roots) == 1 else None
    while link is not None:
        if link in seen:
            raise InputError(f"the URDF's joints form a loop at link {link!r}", file)
        seen.add(link)
        following = children.get(link, [])
        if len(following) > 1 and len(joints) < N_JOINTS:
            following = [j for j in following if moves(j)]
            if len(following) > 1:
                raise InputError(f"the URDF branches at link {link!r} before its 7th joint",
                                 file)
        if not following:
            break
        joint = following[0]
        child = joint.find("child")
        assert child is not None  # every joint's child was checked above
        link = child.get("link")
        if joint.get("type") in ("revolute", "continuous") and len(joints) < N_JOINTS:
            joints.append(joint.get("name"))
            links.append(link)
        elif len(joints) == N_JOINTS:
            break
    if len(joints) != N_JOINTS:
        raise InputError(f"the URDF has no serial chain of {N_JOINTS} revolute joints "
                         f"(found {len(joints)})", file)
    resolved = file.resolve()
    # a joint or link without a name (None) fails the limits check below
    spec = RobotSpec(name=f"{URDF_PREFIX}{path}", description=f"7-joint arm from {resolved}",
                     urdf_file=lambda: resolved, joint_names=cast("tuple[str, ...]", tuple(joints)),
                     link_frames=cast("tuple[str, ...]", tuple(links)), flange=cast(str, link),
                     provenance=str(resolved))
    try:
        spec.limits  # noqa: B018 - checks the joints' limits once, here
    except ValueError as err:
        raise InputError(str(err), file) from err
    return spec


MAX_LINK_MASS_KG = 1e4
"""Largest mass [kg] of one link accepted in a URDF (an arm's links weigh 0.1-10 kg)."""
MAX_LINK_INERTIA = 1e4
"""Largest inertia tensor entry [kg m^2] of one link accepted in a URDF."""


def parse_urdf(text: str, file: Path) -> ET.Element:
    """Return the root of the URDF ``text`` of ``file`` after checking what pinocchio and
    the viewer take for granted: XML whose links and joints have unique names, every
    joint's parent and child a declared link, no link the child of two joints, one root
    link from which every link is reached (no loop through the joints), and finite,
    bounded inertial values (mass in [0, :data:`MAX_LINK_MASS_KG`] kg, inertia entries
    at most :data:`MAX_LINK_INERTIA` kg m^2). Raises one InputError naming the file."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise InputError(f"the robot's URDF is not XML: {err}", file) from err
    links = [link.get("name") for link in root.iter("link")]
    for kind, names in (("link", links), ("joint", [j.get("name") for j in root.iter("joint")])):
        if len(set(names)) != len(names) or None in names:
            raise InputError(f"the URDF has a {kind} without a name or two of one name", file)
    parent_of: dict[str | None, str | None] = {}
    below: dict[str | None, list[str | None]] = {}
    for joint in root.iter("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise InputError(f"joint {joint.get('name')!r} lacks a parent or child", file)
        up, down = parent.get("link"), child.get("link")
        if up not in links or down not in links:
            raise InputError(f"joint {joint.get('name')!r} names a link the URDF does not "
                             "declare", file)
        if down in parent_of:
            raise InputError(f"the URDF's joints form a loop: link {down!r} is the child of "
                             "two joints", file)
        parent_of[down] = up
        below.setdefault(up, []).append(down)
    roots = [link for link in links if link not in parent_of]
    if len(roots) != 1:
        raise InputError(f"the URDF has {len(roots)} root links, not 1"
                         + (" (its joints form a loop)" if not roots else ""), file)
    reached, stack = set(), [roots[0]]
    while stack:
        link = stack.pop()
        reached.add(link)
        stack += below.get(link, [])
    if len(reached) != len(links):
        loop = next(link for link in links if link not in reached)
        raise InputError(f"the URDF's joints form a loop at link {loop!r}", file)
    for element in root.iter("link"):
        _check_inertial(element, file)
    return root


def _check_inertial(link: ET.Element, file: Path) -> None:
    """Raise InputError when ``link``'s inertial values are not finite or absurd."""
    inertial = link.find("inertial")
    if inertial is None:
        return
    where = f"link {link.get('name')!r}"
    mass = inertial.find("mass")
    values = {"mass": mass.get("value", "0") if mass is not None else "0"}
    tensor = inertial.find("inertia")
    if tensor is not None:
        values |= {k: tensor.get(k, "0") for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    numbers = {}
    for key, text in values.items():
        try:
            numbers[key] = float(text)
        except ValueError:
            raise InputError(f"{where}: inertial {key} {text[:40]!r} is not a number",
                             file) from None
        if not math.isfinite(numbers[key]):
            raise InputError(f"{where}: inertial {key} is not finite", file)
    if not 0 <= numbers["mass"] <= MAX_LINK_MASS_KG:
        raise InputError(f"{where}: mass of {numbers['mass']:g} kg is outside [0, "
                         f"{MAX_LINK_MASS_KG:g}] kg", file)
    for key, number in numbers.items():
        if key != "mass" and abs(number) > MAX_LINK_INERTIA:
            raise InputError(f"{where}: inertia {key} = {number:g} kg m^2 exceeds "
                             f"{MAX_LINK_INERTIA:g}", file)
