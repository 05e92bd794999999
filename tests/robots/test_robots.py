"""Robot models chosen per session: the registry, the FR3 model against published values,
the urdf:PATH form and plugins."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from contactkit.errors import InputError
from contactkit.robots import (
    FR3,
    PANDA,
    RobotSetup,
    RobotSpec,
    canonical_robot_name,
    get_robot,
    robot_names,
    urdf_robot,
)
from contactkit.robots.model import RobotModel
from contactkit.robots.registry import REGISTRY
from contactkit.robots.surfaces import link_surface, viewer_urdf_file
from contactkit.schemas import SessionMeta

# libfranka's model tests (frankaemika/libfranka test/robot_model_tests.cpp, 0.15.0): gravity
# of the FR3 arm without a hand at q = 0, without and with its test load (0.73 kg at
# [0.01, 0, 0.03] m in the flange frame), tolerance 1e-5 Nm; and its "baseline" values at
# other poses, tolerance 0.2 Nm (gravity) and 0.1 (mass matrix).
LIBFRANKA_LOAD = {"payload_kg": 0.73, "payload_com_m": (0.01, 0.0, 0.03)}
GRAVITY_AT_ZERO = [0, -3.52387, 0, -3.44254, 0, 1.63362, 0]
GRAVITY_AT_ZERO_LOADED = [0, -4.22568, 0, -3.33154, 0, 2.33543, 0]
Q_DEFAULT = np.array([0, 0, 0, -0.75 * np.pi, 0, 0.75 * np.pi, 0])
GRAVITY_AT_DEFAULT = [0, -24.5858, 0, 17.6880, 0.5095, 1.6428, 0]
MASS_AT_DEFAULT = np.array([
    [0.9831, -0.0078, 0.9742, -0.0254, -0.0351, -0.0040, -0.0004],
    [-0.0078, 1.5390, 0.0053, -0.6641, -0.0147, -0.0828, -0.0012],
    [0.9742, 0.0053, 0.9742, -0.0254, -0.0351, -0.0040, -0.0004],
    [-0.0254, -0.6641, -0.0254, 0.8185, 0.0268, 0.0888, -0.0016],
    [-0.0351, -0.0147, -0.0351, 0.0268, 0.0114, 0.0047, 0.0002],
    [-0.0040, -0.0828, -0.0040, 0.0888, 0.0047, 0.0202, 0.0003],
    [-0.0004, -0.0012, -0.0004, -0.0016, 0.0002, 0.0003, 0.0002]])


def test_built_in_robots_and_aliases() -> None:
    assert robot_names()[:2] == ["panda", "fr3"]
    assert canonical_robot_name("franka_panda") == "panda"
    assert get_robot("franka_fr3") is FR3 and get_robot("panda") is PANDA


def test_unknown_robot_is_one_line_listing_the_known_ones() -> None:
    with pytest.raises(InputError, match=r"unknown robot 'ur5' \(known: panda, fr3"):
        get_robot("ur5")


def test_limits_load_without_pinocchio() -> None:
    code = ("import sys; from contactkit.robots import get_robot; "
            "l = get_robot('fr3').limits; assert 'pinocchio' not in sys.modules; "
            "print(l.q_min[5], l.q_max[5], l.dq_max[0])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert [float(v) for v in out] == [0.5445, 4.5169, 2.62]


@pytest.mark.parametrize("with_hand", [True, False])
def test_fr3_kinematics_equal_the_pandas(with_hand: bool) -> None:
    fr3, panda = RobotModel(RobotSetup("fr3", with_hand)), RobotModel(RobotSetup("panda",
                                                                                with_hand))
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(np.maximum(fr3.limits.q_min, panda.limits.q_min),
                        np.minimum(fr3.limits.q_max, panda.limits.q_max))
        for link in range(1, 8):
            a, b = fr3.frame_placement(q, link), panda.frame_placement(q, link)
            assert np.abs(a.translation - b.translation).max() < 1e-12
            assert np.abs(a.rotation - b.rotation).max() < 1e-12
        tcp = fr3.frame_placement(q, fr3.end_effector).translation
        assert np.abs(tcp - panda.frame_placement(q, panda.end_effector).translation).max() \
            < 1e-12


def test_fr3_inertias_and_limits_differ_from_the_pandas() -> None:
    fr3, panda = RobotModel(RobotSetup("fr3")), RobotModel(RobotSetup("panda"))
    assert fr3.model.inertias[2].mass == pytest.approx(2.9355, abs=1e-3)
    assert panda.model.inertias[2].mass == pytest.approx(0.6461, abs=1e-3)
    assert fr3.limits.q_min[5] == pytest.approx(0.5445)
    assert FR3.friction is None and PANDA.friction is not None


def test_fr3_gravity_matches_libfrankas_published_values() -> None:
    bare = RobotModel(RobotSetup("fr3", with_hand=False))
    loaded = RobotModel(RobotSetup("fr3", with_hand=False, **LIBFRANKA_LOAD))
    assert np.abs(bare.gravity(np.zeros(7)) - GRAVITY_AT_ZERO).max() <= 1e-5
    assert np.abs(loaded.gravity(np.zeros(7)) - GRAVITY_AT_ZERO_LOADED).max() <= 1e-5
    assert np.abs(bare.gravity(Q_DEFAULT) - GRAVITY_AT_DEFAULT).max() <= 0.2
    assert np.abs(bare.mass_matrix(Q_DEFAULT) - MASS_AT_DEFAULT).max() <= 0.1


def test_every_link_has_a_collision_surface() -> None:
    for robot in ("panda", "fr3"):
        for link in range(1, 8):
            surface = link_surface(RobotSetup(robot), link)
            assert len(surface.areas) >= 100 and surface.areas.sum() > 0.01
            assert np.allclose(np.linalg.norm(surface.normals, axis=1), 1.0)
    hand = link_surface(RobotSetup("fr3"), 7).areas.sum()
    assert hand > link_surface(RobotSetup("fr3", with_hand=False), 7).areas.sum()
    text = viewer_urdf_file(RobotSetup("fr3")).read_text()
    assert "fr3_link3" in text and "package://" not in text


def _panda_urdf_copy(tmp_path: Path) -> Path:
    urdf = tmp_path / "myarm.urdf"
    urdf.write_text(PANDA.urdf_text(False))
    return urdf


def test_urdf_form_describes_any_seven_joint_arm(tmp_path: Path) -> None:
    spec = urdf_robot(str(_panda_urdf_copy(tmp_path)))
    assert spec.joint_names == PANDA.joint_names and spec.flange == "panda_link8"
    model = RobotModel(RobotSetup(f"urdf:{tmp_path / 'myarm.urdf'}"))
    q = np.array([0.0, -0.78, 0.0, -2.36, 0.0, 1.57, 0.78])
    assert np.allclose(model.gravity(q), RobotModel(RobotSetup(with_hand=False)).gravity(q))
    (tmp_path / "three.urdf").write_text(
        "<robot name='x'><link name='a'/><link name='b'/>"
        "<joint name='j' type='revolute'><parent link='a'/><child link='b'/>"
        "<limit lower='-1' upper='1' effort='1' velocity='1'/></joint></robot>")
    with pytest.raises(InputError, match="no serial chain of 7 revolute joints"):
        urdf_robot(str(tmp_path / "three.urdf"))


def test_vectorised_kinematics_equal_pinocchios_per_sample(tmp_path: Path) -> None:
    """frame_placements (all rows at once) against frame_placement (one pinocchio call per
    row) on the built-in arms and on an arm whose joint axes are not the z axis."""
    text = PANDA.urdf_text(False)
    tilted = tmp_path / "tilted.urdf"
    tilted.write_text(text.replace('<axis xyz="0 0 1" />', '<axis xyz="0.6 0 0.8" />', 4))
    assert tilted.read_text() != text
    setups = [RobotSetup(), RobotSetup(with_hand=False), RobotSetup("fr3"),
              RobotSetup(f"urdf:{tilted}", with_hand=False)]
    q = np.random.default_rng(0).uniform(-2.5, 2.5, (50, 7))
    for setup in setups:
        model = RobotModel(setup)
        for link in [*range(1, 8), model.end_effector]:
            rotation, translation = model.frame_placements(q, link)
            placements = [model.frame_placement(row, link) for row in q]
            assert np.abs(rotation - [p.rotation for p in placements]).max() < 1e-12
            assert np.abs(translation - [p.translation for p in placements]).max() < 1e-12


def test_a_session_whose_urdf_changed_is_refused(tmp_path: Path) -> None:
    urdf = _panda_urdf_copy(tmp_path)
    name = f"urdf:{urdf}"
    meta = SessionMeta(session_id="s", source="t", action="none", with_hand=False,
                       robot=name, urdf_sha256=get_robot(name).urdf_sha256(False))
    assert meta.robot_setup().robot == name
    stale = SessionMeta(**{**vars(meta), "urdf_sha256": "0" * 64})
    with pytest.raises(InputError, match="not the one the session was recorded with"):
        stale.robot_setup("s.parquet")


def test_old_sessions_read_as_panda() -> None:
    meta = SessionMeta.from_dict({"session_id": "s", "source": "t", "action": "none",
                                  "robot": "franka_panda", "schema_version": 1})
    assert meta.robot_setup() == RobotSetup("panda", True)
    with pytest.raises(InputError, match="unknown robot 'kuka'"):
        SessionMeta.from_dict({"session_id": "s", "source": "t", "action": "none",
                               "robot": "kuka", "schema_version": 1})


TINY_ARM = RobotSpec(name="tinyarm", description="a Panda under another name",
                     urdf_file=PANDA.urdf_file, joint_names=PANDA.joint_names,
                     link_frames=PANDA.link_frames, flange="panda_link8")


def test_a_plugin_robot_is_one_module_and_one_entry_point(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch
                                                          ) -> None:
    entry = importlib.metadata.EntryPoint("tinyarm", "tests.robots.test_robots:TINY_ARM",
                                          "contactkit.robots")
    real = importlib.metadata.entry_points

    def entry_points(**select):
        found = real(**select)
        return [*found, entry] if select.get("group") == "contactkit.robots" else found

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2]))
    REGISTRY.refresh()
    try:
        assert "tinyarm" in robot_names()
        model = RobotModel(RobotSetup("tinyarm", with_hand=False))
        assert model.model.nq == 7 and model.end_effector == "panda_link8"
    finally:
        REGISTRY.refresh()  # the next test sees the real entry points again


def test_friction_is_finite_and_silent_at_any_velocity() -> None:
    """An unstable simulation once reached |dq| > 41 rad/s, where exp() in the logistic
    overflowed and numpy warned on the user's terminal; the model is now exact without
    overflow, and unchanged where it was fine."""
    import warnings

    from contactkit.robots import GAZ_FRICTION

    dq = np.array([[-1e4] * 7, [-50.0] * 7, [-0.3] * 7, [0.0] * 7, [0.3] * 7, [1e4] * 7])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tau = GAZ_FRICTION.torque(dq)
    assert np.isfinite(tau).all()
    np.testing.assert_allclose(tau[3], 0.0, atol=1e-12)
    f = GAZ_FRICTION
    naive = f.phi1 / (1 + np.exp(-f.phi2 * (dq[2:5] + f.phi3))) \
        - f.phi1 / (1 + np.exp(-f.phi2 * f.phi3))
    np.testing.assert_allclose(tau[2:5], naive, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(tau[0], -f.at_rest, atol=1e-9)  # the sigmoid's floor, 0
    np.testing.assert_allclose(tau[-1], f.phi1 - f.at_rest, atol=1e-9)  # and its top, phi1
