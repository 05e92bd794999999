"""Robots in general: 7-joint arms given as ``urdf:PATH`` that differ from the Panda in the
ways real URDFs do (meshes that are not there or not binary STL, relative paths,
continuous joints, branches), through the model, the surfaces, isolation and the
simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contactkit.errors import InputError
from contactkit.features.isolation import NO_SURFACE, ContactIsolator
from contactkit.recorder.sim.forces import Persona, sample_contact
from contactkit.recorder.sim.simulator import SimConfig
from contactkit.robots import PANDA, RobotSetup, canonical_robot_name, get_robot
from contactkit.robots.model import RobotModel
from contactkit.robots.registry import urdf_robot
from contactkit.robots.surfaces import link_surface, read_stl, viewer_urdf_file
from contactkit.schemas import SessionMeta

Q = np.array([0.1, -0.78, 0.2, -2.36, 0.3, 1.57, 0.78])


def _arm(tmp_path: Path, text: str, name: str = "arm.urdf") -> str:
    urdf = tmp_path / name
    urdf.write_text(text)
    return f"urdf:{urdf}"


def test_meshes_that_cannot_be_found_leave_links_bare_not_a_crash(tmp_path: Path) -> None:
    """A URDF whose package:// meshes are not installed (or not STL): the model works,
    the links have no surface, the viewer's URDF leaves those meshes out, isolation
    names the link by its wrench, and a simulated touch there is a one-line error."""
    text = PANDA.urdf_text(False).replace("package://example-robot-data",
                                          "package://not_installed_pkg")
    text = text.replace("collision/link7.stl", "collision/link7.dae")
    robot = _arm(tmp_path, text)
    setup = RobotSetup(robot, with_hand=False)
    assert all(link_surface(setup, k).empty for k in range(1, 8))
    viewer = viewer_urdf_file(setup).read_text()
    assert "not_installed_pkg" not in viewer and "<mesh" not in viewer
    model = RobotModel(setup)
    isolator = ContactIsolator(model, lambda k: None)
    r = model.point_jacobian(Q, 4, np.array([0.0, 0.05, 0.0]))[:3].T @ np.array([0, 0, 30.0])
    est = isolator.estimate(1.0, Q, r)
    assert est.status == NO_SURFACE and est.link is not None and est.force is None
    with pytest.raises(InputError, match="link 4 has no collision mesh"):
        sample_contact(np.random.default_rng(0), "bump", 5.0, 4, link_surface(setup, 4),
                       np.eye(3), Persona.from_name("sim"))



def test_the_viewer_leaves_out_a_mesh_that_exists_but_is_not_stl(tmp_path: Path) -> None:
    """The viewer's URDF had kept a mesh that was found but could not be read (a .dae, a
    corrupt file) while the surfaces left it out: it draws what the surfaces have."""
    mesh = tmp_path / "link3.dae"
    mesh.write_text("<?xml version='1.0'?><COLLADA>" + " " * 200 + "</COLLADA>")
    share = next(p for p in PANDA.urdf_file().parents if p.name == "example-robot-data")
    text = PANDA.urdf_text(False).replace("package://example-robot-data", f"file://{share}")
    start = text.index('<link name="panda_link3"')
    end = text.index("</link>", start)
    link3 = text[start:end]
    fixed = link3.replace(link3[link3.index('filename="', link3.index("<collision")):].split(
        '"')[1], str(mesh))
    setup = RobotSetup(_arm(tmp_path, text[:start] + fixed + text[end:]), with_hand=False)
    viewer = viewer_urdf_file(setup).read_text()
    assert "link3.dae" not in viewer and viewer.count("<mesh") == 7  # links 0-2 and 4-7
    assert link_surface(setup, 3).empty and not link_surface(setup, 4).empty

def test_stl_files_binary_ascii_and_neither(tmp_path: Path) -> None:
    ascii_stl = tmp_path / "tri.stl"
    ascii_stl.write_text("solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n"
                         "   vertex 1 0 0\n   vertex 0 1 0\n  endloop\n endfacet\nendsolid t\n")
    assert np.array_equal(read_stl(ascii_stl), [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]])
    collada = tmp_path / "link.dae"
    collada.write_text("<?xml version='1.0'?><COLLADA>" + " " * 200 + "</COLLADA>")
    with pytest.raises(ValueError, match="not an STL file"):
        read_stl(collada)
    binary = tmp_path / "bin.stl"
    triangle = np.zeros(1, dtype=[("normal", "<f4", 3), ("vertices", "<f4", (3, 3)),
                                  ("attr", "<u2")])
    triangle["vertices"] = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    binary.write_bytes(b"solid header of a binary file".ljust(80, b" ")
                       + np.uint32(1).tobytes() + triangle.tobytes())
    assert np.array_equal(read_stl(binary), read_stl(ascii_stl))


def test_a_relative_urdf_path_is_stored_absolute(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """`--robot urdf:arm.urdf` given in the URDF's folder names the file for good: a
    session's metadata holds its absolute path, readable from any other folder."""
    _arm(tmp_path, PANDA.urdf_text(False))
    monkeypatch.chdir(tmp_path)
    config = SimConfig(robot="urdf:arm.urdf", with_hand=False)
    assert config.robot == f"urdf:{tmp_path / 'arm.urdf'}"
    assert canonical_robot_name("urdf:./arm.urdf") == config.robot
    meta = SessionMeta(session_id="s", source="t", action="none", with_hand=False,
                       robot=config.robot, urdf_sha256=get_robot(config.robot).urdf_sha256(False))
    monkeypatch.chdir(tmp_path.parent)
    assert meta.robot_setup().robot == config.robot


def test_a_session_whose_urdf_is_gone_names_the_missing_file(tmp_path: Path) -> None:
    robot = _arm(tmp_path, PANDA.urdf_text(False))
    meta = SessionMeta(session_id="s", source="t", action="none", with_hand=False,
                       robot=robot, urdf_sha256=get_robot(robot).urdf_sha256(False))
    (tmp_path / "arm.urdf").rename(tmp_path / "moved.urdf")
    urdf_robot.cache_clear()  # as a later process, which reads the file anew
    with pytest.raises(InputError, match=r"^s\.parquet: .*arm\.urdf: cannot read the robot's"):
        meta.robot_setup("s.parquet")


def _continuous(text: str, joints: tuple[int, ...]) -> str:
    """The Panda's URDF with ``joints`` made continuous, their limits as real URDFs of
    such arms (Kinova Gen3's joints 1, 3, 5, 7) have them: effort and velocity only."""
    import re

    for j in joints:
        text = re.sub(rf'(<joint name="panda_joint{j}") type="revolute">(.*?)<limit [^>]*/>',
                      r'\1 type="continuous">\2<limit effort="12.0" velocity="2.61"/>',
                      text, count=1, flags=re.S)
    return text


def test_continuous_joints_are_revolute_joints_without_position_limits(tmp_path: Path
                                                                       ) -> None:
    """The docs take "the first 7 revolute (or continuous) joints"; a continuous joint
    was a 'has 8 joints, not 7' error (pinocchio's cos/sin joint) or a missing limit."""
    text = _continuous(PANDA.urdf_text(False), (1, 3, 5, 7))
    assert text.count('type="continuous"') == 4
    robot = _arm(tmp_path, text)
    spec = get_robot(robot)
    assert spec.joint_names == PANDA.joint_names
    limits = spec.limits
    assert np.isinf(limits.q_min[[0, 2, 4, 6]]).all() and np.isinf(limits.q_max[0])
    assert np.isfinite(limits.q_min[[1, 3, 5]]).all() and limits.dq_max[6] == 2.61
    model = RobotModel(RobotSetup(robot, with_hand=False))
    panda = RobotModel(RobotSetup(with_hand=False))
    assert model.model.nq == 7
    far = Q + np.array([4.0, 0, -5.0, 0, 7.0, 0, 9.0])  # beyond a revolute joint's range
    np.testing.assert_allclose(model.gravity(far), panda.gravity(far), atol=1e-9)
    rotation, _ = model.frame_placements(far[None], 7)
    np.testing.assert_allclose(rotation[0], panda.frame_placement(far, 7).rotation,
                               atol=1e-12)



def test_deep_stats_of_an_arm_with_continuous_joints_is_valid_json(tmp_path: Path) -> None:
    """A continuous joint has no position limit: its margin is null, where it was an
    infinite float that json wrote as Infinity (not JSON for jq or a browser)."""
    import json

    from tests.conftest import make_session, run_command

    robot = _arm(tmp_path, _continuous(PANDA.urdf_text(False), (1, 3, 5, 7)))
    data = tmp_path / "data"
    data.mkdir()
    make_session(data, action="none", link=None, robot=robot, with_hand=False,
                 duration_s=1.0, planned_at_s=0.5, rate_hz=200.0)
    out = tmp_path / "deep.json"
    done = run_command("recorder", "stats", str(data), "--deep", "--format", "json", "--out",
                       str(out), "--workers", "1")
    assert done.returncode == 0, done.stderr

    def refuse(constant: str) -> None:
        raise AssertionError(f"{constant} in the report")

    for path in (out, tmp_path / "deep_noise.json"):
        json.loads(path.read_text(), parse_constant=refuse)
    margins = json.loads(out.read_text())["deep"]["joint_limits"]["min_margin_rad"]
    assert [m is None for m in margins] == [True, False] * 3 + [True]

def test_a_fixed_side_branch_before_the_7th_joint_is_not_the_chain(tmp_path: Path) -> None:
    """A camera or sensor frame fixed to link 3 (a second child of that link) was 'the
    URDF branches at link panda_link3'; the chain is the branch that moves. A second
    branch with a revolute joint is still refused."""
    camera = ('<link name="camera"/><joint name="camera_joint" type="fixed">'
              '<parent link="panda_link3"/><child link="camera"/>'
              '<origin xyz="0 0.1 0"/></joint>')
    text = PANDA.urdf_text(False).replace('<joint name="panda_joint4"',
                                          camera + '<joint name="panda_joint4"', 1)
    robot = _arm(tmp_path, text)
    spec = get_robot(robot)
    assert spec.joint_names == PANDA.joint_names and spec.flange == "panda_link8"
    np.testing.assert_allclose(RobotModel(RobotSetup(robot, False)).gravity(Q),
                               RobotModel(RobotSetup(with_hand=False)).gravity(Q), atol=1e-9)
    moving = camera.replace('type="fixed">', 'type="revolute"><limit lower="-1" '
                            'upper="1" effort="1" velocity="1"/>')
    text = PANDA.urdf_text(False).replace('<joint name="panda_joint4"',
                                          moving + '<joint name="panda_joint4"', 1)
    with pytest.raises(InputError, match="branches at link 'panda_link3'"):
        get_robot(_arm(tmp_path, text, "two.urdf"))


@pytest.mark.timeout(20)
def test_a_urdf_whose_joints_form_a_loop_is_refused_not_followed_forever(tmp_path: Path
                                                                         ) -> None:
    links = "".join(f'<link name="{n}"/>' for n in "rab")
    joints = "".join(f'<joint name="j{i}" type="fixed"><parent link="{p}"/>'
                     f'<child link="{c}"/></joint>' for i, (p, c) in enumerate(("ra", "ab", "ba")))
    with pytest.raises(InputError, match="loop"):
        get_robot(_arm(tmp_path, f'<robot name="x">{links}{joints}</robot>'))
    # a loop in a side branch, past the chain's 7 joints, is refused too: pinocchio and
    # Rerun's URDF loader take the tree for granted (Rerun crashed on it in replay)
    loop = ('<link name="s"/><joint name="side" type="fixed"><parent link="panda_link3"/>'
            '<child link="s"/></joint><joint name="back" type="fixed"><parent link="s"/>'
            '<child link="s"/></joint>')
    text = PANDA.urdf_text(False).replace('<joint name="panda_joint4"',
                                          loop + '<joint name="panda_joint4"', 1)
    with pytest.raises(InputError, match=r"side\.urdf: the URDF's joints form a loop"):
        get_robot(_arm(tmp_path, text, "side.urdf"))
