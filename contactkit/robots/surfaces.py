"""A robot's collision surfaces: the triangles a hand can touch, per link.

The simulator draws its contact points on them, contact isolation searches them,
and the viewer draws the links with them (coarse collision meshes: about 150 kB
for a Franka arm, against about 10 MB of visual meshes that every recording would
carry). Meshes are STL files (binary or ASCII) named by the URDF's ``<collision>``
elements: ``package://PKG/PATH`` is looked up in the folders above the URDF (as
example-robot-data installs it), a relative name beside the URDF. A mesh that cannot be
found or read (another format, a package not installed) is left out with a warning,
once per file: its link then has less surface, or none, which contact isolation and
the viewer handle, instead of stopping the replay.
"""

from __future__ import annotations

import hashlib
import logging
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from contactkit.errors import InputError
from contactkit.robots.model import RobotModel
from contactkit.robots.registry import get_robot
from contactkit.robots.spec import RobotSetup, RobotSpec
from contactkit.util.atomic import any_regular_file, write_text
from contactkit.util.cache import cache_dir
from contactkit.util.safe_open import read_input_bytes

log = logging.getLogger(__name__)
_SKIPPED: set[str] = set()

STL_TRIANGLE = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])


@dataclass(frozen=True)
class LinkSurface:
    """Triangles of a link's collision mesh in the link frame: vertices [m] (n, 3, 3),
    unit outward normals (n, 3) and areas [m^2] (n,). Empty (n = 0) for a link without
    a collision mesh."""

    vertices: np.ndarray
    normals: np.ndarray
    areas: np.ndarray

    @property
    def empty(self) -> bool:
        """Whether the link has no collision surface."""
        return len(self.areas) == 0


def read_stl(path: Path) -> np.ndarray:
    """Return the triangles of an STL file (binary or ASCII) as an (n, 3, 3) array [file
    units]. Raises ValueError (InputError for a special or too large file) for a file
    that is neither."""
    raw = read_input_bytes(path, "collision mesh", "mesh")
    count = int(np.frombuffer(raw, "<u4", 1, 80)[0]) if len(raw) >= 84 else -1
    binary = count >= 0 and len(raw) >= 84 + count * STL_TRIANGLE.itemsize
    if binary and len(raw) == 84 + count * STL_TRIANGLE.itemsize:
        return np.frombuffer(raw, STL_TRIANGLE, count, 84)["vertices"].astype(float)
    if raw.lstrip()[:5].lower() == b"solid":  # ASCII (or a binary header saying solid)
        words = raw.decode("ascii", "replace").split()
        values = [words[i + 1:i + 4] for i, w in enumerate(words) if w.lower() == "vertex"]
        try:
            vertices = np.array(values, dtype=float).reshape(-1, 3, 3)
        except ValueError:
            vertices = None
        if vertices is not None and len(vertices):
            return vertices
    if binary:  # trailing bytes after the triangles
        return np.frombuffer(raw, STL_TRIANGLE, count, 84)["vertices"].astype(float)
    raise ValueError("not an STL file (binary or ASCII)")


def _skip_mesh(problem: str) -> None:
    """Warn, once per problem, that a mesh is left out."""
    if problem not in _SKIPPED:
        _SKIPPED.add(problem)
        log.warning("collision mesh left out: %s", problem)


def resolve_mesh(urdf_file: Path, filename: str) -> Path:
    """Return the file a URDF mesh name refers to: ``package://PKG/PATH`` found in a folder
    above the URDF (``PKG/PATH`` below it, or a folder named PKG holding PATH),
    ``file://`` and absolute names as they are, other names beside the URDF. Raises
    FileNotFoundError for a mesh without a name or not found (its link is then drawn and
    searched without it)."""
    if not filename:
        raise FileNotFoundError("a <mesh> has no filename")
    if filename.startswith("file://"):
        return Path(filename[len("file://"):])
    if not filename.startswith("package://"):
        return urdf_file.parent / filename
    package, _, rest = filename[len("package://"):].partition("/")
    for folder in urdf_file.parents:
        if (folder / package / rest).exists():
            return folder / package / rest
        if folder.name == package and (folder / rest).exists():
            return folder / rest
    raise FileNotFoundError(f"mesh {filename} not found in the folders above the URDF")


def _rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy), np.sin(rpy)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _mesh_file(spec: RobotSpec, link_name: str | None, filename: str
               ) -> tuple[Path, np.ndarray] | None:
    """Return the file a collision ``<mesh>`` of link ``link_name`` names and its
    triangles (n, 3, 3) [file units]; None, with a warning once per problem, for a mesh
    that cannot be found or read: the surfaces and the viewer then leave it out."""
    where = f"{spec.urdf_file()}: link {link_name!r}"
    try:
        path = resolve_mesh(spec.urdf_file(), filename)
    except FileNotFoundError as err:
        _skip_mesh(f"{where}: {err}")
        return None
    try:
        return path, read_stl(path)
    except (OSError, ValueError) as err:
        problem = err.problem if isinstance(err, InputError) else (
            getattr(err, "strerror", None) or err)
        _skip_mesh(f"{where}: the collision mesh {path}: {problem}")
        return None


def _collision_meshes(spec: RobotSpec, with_hand: bool, link_name: str
                      ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Return (triangles [file units], rotation, translation, scale) of each collision
    mesh of a link that can be read."""
    root = ET.fromstring(spec.urdf_text(with_hand))
    found = []
    for link in root.iter("link"):
        if link.get("name") != link_name:
            continue
        for collision in link.findall("collision"):
            mesh = collision.find("geometry/mesh")
            if mesh is None:
                continue
            origin = collision.find("origin")
            if origin is None:
                origin = ET.Element("origin")
            xyz = _vector(spec, link_name, origin, "xyz", "0 0 0")
            rpy = _vector(spec, link_name, origin, "rpy", "0 0 0")
            scale = _vector(spec, link_name, mesh, "scale", "1 1 1")
            read = _mesh_file(spec, link_name, mesh.get("filename", ""))
            if read is not None:
                found.append((read[1], _rpy_matrix(rpy), xyz, scale))
    return found


def _vector(spec: RobotSpec, link_name: str, element: ET.Element, attribute: str,
            default: str) -> np.ndarray:
    """Return the 3 finite numbers of a collision element's attribute; raise InputError
    naming the URDF otherwise."""
    text = element.get(attribute, default)
    try:
        value = np.array(text.split(), dtype=float)
    except ValueError:
        value = np.zeros(0)
    if value.shape != (3,) or not np.isfinite(value).all():
        raise InputError(f"the collision {element.tag} {attribute}={text[:60]!r} of link "
                         f"{link_name!r} is not 3 finite numbers", spec.urdf_file())
    return value


def _mesh_triangles(spec: RobotSpec, with_hand: bool, link_name: str) -> list[np.ndarray]:
    return [(mesh * scale) @ rotation.T + xyz
            for mesh, rotation, xyz, scale in _collision_meshes(spec, with_hand, link_name)]


@cache
def link_surface(setup: RobotSetup, link: int) -> LinkSurface:
    """Return the collision surface of link 1..7 of ``setup`` in the link's frame (link 7
    includes the hand when it is mounted). A link without a collision mesh gives an
    empty surface."""
    spec = get_robot(setup.robot)
    triangles = _mesh_triangles(spec, setup.with_hand, spec.link_frames[link - 1])
    if link == 7 and setup.with_hand and spec.hand_frame:
        model = RobotModel(setup)
        hand = model.model.frames[model.frame_id(spec.hand_frame)].placement
        to_link7 = model.model.frames[model.frame_id(7)].placement.actInv(hand)
        triangles += [tri @ to_link7.rotation.T + to_link7.translation
                      for tri in _mesh_triangles(spec, True, spec.hand_frame)]
    if not triangles:
        empty = np.zeros((0, 3))
        return LinkSurface(vertices=np.zeros((0, 3, 3)), normals=empty, areas=np.zeros(0))
    tri = np.concatenate(triangles)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    areas = 0.5 * np.linalg.norm(cross, axis=1)
    keep = areas > 1e-10
    return LinkSurface(vertices=tri[keep], normals=cross[keep] / (2 * areas[keep, None]),
                       areas=areas[keep])


def viewer_urdf_file(setup: RobotSetup) -> Path:
    """Return a URDF file of ``setup``'s arm for viewers (Rerun), written once into the
    cache: links drawn with their collision meshes, mesh names made absolute paths."""
    text, name = _viewer_urdf(setup)
    path = cache_dir() / name
    if not path.exists():
        write_text(path, text, owned=any_regular_file)
    return path


@cache
def _viewer_urdf(setup: RobotSetup) -> tuple[str, str]:
    """Return the viewer URDF of ``setup``'s arm (see :func:`viewer_urdf_file`) and its
    file name, which holds a digest of the text (built once per process)."""
    spec = get_robot(setup.robot)
    root = ET.fromstring(spec.urdf_text(setup.with_hand))
    for link in root.iter("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
        for collision in link.findall("collision"):
            collision.tag = "visual"
            mesh = collision.find("geometry/mesh")
            if mesh is not None:
                # the viewer draws the meshes the surfaces have (with the same warnings)
                read = _mesh_file(spec, link.get("name"), mesh.get("filename", ""))
                if read is None:
                    link.remove(collision)
                    continue
                mesh.set("filename", str(read[0]))
    text = ET.tostring(root, encoding="unicode")
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    stem = re.sub(r"[^A-Za-z0-9_-]", "_", spec.name)[:40]
    variant = "hand" if setup.with_hand and spec.has_hand else "nohand"
    return text, f"{stem}_{variant}_{digest}.urdf"
