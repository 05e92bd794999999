"""More hostile input for the commands: each bad file is one line naming it, exit code 2,
no traceback (the readers' rule in docs/reference/guarantees.md)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from contactkit.cli.classify import app as classify_app
from contactkit.cli.common import run_app
from contactkit.cli.recorder import app as recorder_app
from contactkit.cli.replay import app as replay_app
from contactkit.errors import InputError
from contactkit.schemas.session import METADATA_KEY
from tests.conftest import make_session, run_cli


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    """A 2 s simulated bump on link 5 at 200 Hz."""
    return make_session(tmp_path_factory.mktemp("good"), seed=4, action="bump", link=5,
                        duration_s=2.0, planned_at_s=1.0, rate_hz=200.0)


def _run(app, prog: str, capsys, *argv) -> tuple[int, str, str]:
    code = run_app(app, prog, [str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, " ".join(err.split())  # the console wraps long lines


def _one_line(code: int, err: str, *texts: str) -> None:
    assert code == 2, err
    assert "Traceback" not in err, err
    for text in texts:
        assert text in err, err


def _edit_meta(source: Path, target: Path, edit) -> Path:
    table = pq.read_table(source)
    doc = json.loads(table.schema.metadata[METADATA_KEY])
    edit(doc)
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: json.dumps(doc).encode()}),
                   target)
    return target


def _set_contact(value):
    def edit(doc):
        doc["simulator"]["session"]["contact"] = value
    return edit


def _set_sim_session(value):
    def edit(doc):
        doc["simulator"]["session"] = value
    return edit


@pytest.mark.parametrize("edit", [
    _set_sim_session([1]), _set_sim_session("x"), _set_contact({}),
    _set_contact({"link": "x", "point_local": [0, 0, 0]}),
    _set_contact({"link": 99, "point_local": [0, 0, 0]}),
    _set_contact({"link": 0, "point_local": [0, 0, 0]}),
    _set_contact({"link": 3, "point_local": [1]}),
    _set_contact({"link": 3, "point_local": "abc"}),
    _set_contact({"link": 3, "point_local": None}),
    _set_contact({"link": 3, "point_local": [1e308, 0, 0]}),
    _set_contact("x")], ids=["session-list", "session-str", "contact-empty", "link-str",
                             "link-99", "link-0", "point-short", "point-str", "point-none",
                             "point-huge", "contact-str"])
def test_simulated_contact_metadata_of_the_wrong_shape_is_one_line(good, tmp_path, capsys,
                                                                   edit) -> None:
    bad = _edit_meta(good, tmp_path / "bad sim.parquet", edit)
    for app, prog, argv in ((recorder_app, "recorder", ["info", bad]),
                            (replay_app, "replay", [bad, "--viewer", "none", "--save",
                                                    tmp_path / "r.rrd"])):
        code, _, err = _run(app, prog, capsys, *argv)
        _one_line(code, err, "bad sim.parquet", "simulator.session")
        assert not (tmp_path / "r.rrd").exists()


# -- urdf:PATH robots --------------------------------------------------------------------

FR3_DATA = Path(__file__).resolve().parents[1] / "contactkit" / "robots" / "data" / "fr3"


@pytest.fixture
def urdf_dir(tmp_path: Path) -> Path:
    """A copy of the bundled FR3 URDF (no hand) with its collision meshes."""
    directory = tmp_path / "arm"
    shutil.copytree(FR3_DATA / "meshes", directory / "meshes")
    shutil.copy(FR3_DATA / "fr3.urdf", directory / "arm.urdf")
    return directory


def _replay_with(robot_file: Path, session: Path, tmp_path: Path, capsys):
    return _run(replay_app, "replay", capsys, session, "--robot", f"urdf:{robot_file}",
                "--viewer", "none", "--save", tmp_path / "u.rrd")


def test_urdf_that_is_not_utf8_is_one_line(urdf_dir, good, tmp_path, capsys) -> None:
    bad = urdf_dir / "latin.urdf"
    bad.write_bytes((urdf_dir / "arm.urdf").read_text().replace("fr3_link1", "fr3_l\xe9nk1")
                    .encode("latin-1"))
    code, _, err = _replay_with(bad, good, tmp_path, capsys)
    _one_line(code, err, "not UTF-8")
    assert not (tmp_path / "u.rrd").exists()


def test_urdf_errors_name_the_urdf_as_well_as_the_session(urdf_dir, good, tmp_path,
                                                          capsys) -> None:
    six = urdf_dir / "six joints.urdf"
    six.write_text((urdf_dir / "arm.urdf").read_text().replace(
        'name="fr3_joint7" type="revolute"', 'name="fr3_joint7" type="fixed"'))
    code, _, err = _replay_with(six, good, tmp_path, capsys)
    _one_line(code, err, "six joints.urdf", good.name, "no serial chain of 7")
    code, _, err = _run(classify_app, "classify", capsys, "features", good, "--robot",
                        f"urdf:{six}", "--out", tmp_path / "f.parquet")
    _one_line(code, err, "six joints.urdf", "no serial chain of 7")
    gone = urdf_dir / "gone.urdf"
    named = _edit_meta(good, tmp_path / "named.parquet",
                       lambda doc: doc.update(robot=f"urdf:{gone}"))
    code, _, err = _run(replay_app, "replay", capsys, named, "--viewer", "none", "--save",
                        tmp_path / "u.rrd")
    _one_line(code, err, "gone.urdf", "named.parquet", "cannot read the robot's URDF")
    assert not (tmp_path / "u.rrd").exists()


@pytest.mark.parametrize(("mesh", "text"), [
    ('filename="meshes/collision/nothere.stl"', "No such file"),
    ('filename="meshes"', "is a directory, not a regular file"),
    ('filename="../../../../../../etc/hostname"', "not an STL file"),
    ('filename="package://nothere/x.stl"', "not found")],
    ids=["missing", "directory", "not-stl", "package"])
def test_urdf_with_an_unreadable_collision_mesh_leaves_it_out(urdf_dir, good, tmp_path,
                                                              capsys, mesh, text) -> None:
    """A mesh that cannot be found or read is left out with a warning naming the URDF, the
    link and the mesh: the replay runs (its dynamics need no mesh); a simulated touch on
    the link that has lost its only mesh is one line."""
    bad = urdf_dir / "bad mesh.urdf"
    bad.write_text((urdf_dir / "arm.urdf").read_text().replace(
        'filename="meshes/collision/link3.stl"', mesh))
    code, _, err = _replay_with(bad, good, tmp_path, capsys)
    assert code == 0 and "Traceback" not in err, err
    for part in ("collision mesh left out", "bad mesh.urdf", "fr3_link3", text):
        assert part in err, err
    assert (tmp_path / "u.rrd").is_file()
    code, _, err = _run(recorder_app, "recorder", capsys, "capture", "--robot", f"urdf:{bad}",
                        "--pose", "A", "--action", "bump", "--link", "3", "--duration", "2",
                        "--planned-at", "1", "--out", tmp_path / "cap")
    _one_line(code, err, "link 3 has no collision mesh to touch")
    assert not list(tmp_path.rglob("*.parquet"))


def test_urdf_with_a_malformed_collision_mesh_is_one_line(urdf_dir, good, tmp_path,
                                                          capsys) -> None:
    bad = urdf_dir / "bad mesh.urdf"
    bad.write_text((urdf_dir / "arm.urdf").read_text().replace(
        'filename="meshes/collision/link3.stl"',
        'filename="meshes/collision/link3.stl" scale="a b c"'))
    code, _, err = _replay_with(bad, good, tmp_path, capsys)
    _one_line(code, err, "bad mesh.urdf", "scale")
    assert not (tmp_path / "u.rrd").exists()


@pytest.mark.parametrize(("old", "new"), [
    ('<link name="fr3_link8"/>', '<link name="fr3_link8"/><link name="fr3_link3"/>'),
    ('ixx="0.02410142547240885"', 'ixx="abc"'),
    ('xyz="0 0 0.333"', 'xyz="a b c"')], ids=["duplicate-link", "inertia", "origin"])
def test_urdf_that_urdfdom_cannot_parse_is_one_line(urdf_dir, good, tmp_path,
                                                    old, new) -> None:
    """urdfdom prints its parse errors to fd 2 (and pinocchio may go on without the
    inertia it could not parse): they are the one line's detail, not extra lines."""
    bad = urdf_dir / "unparsed.urdf"
    text = (urdf_dir / "arm.urdf").read_text()
    assert old in text
    bad.write_text(text.replace(old, new))
    result = run_cli("replay", str(good), "--robot", f"urdf:{bad}", "--viewer", "none",
                     "--save", str(tmp_path / "u.rrd"))
    lines = [line for line in result.stderr.splitlines() if line.strip() and "━" not in line]
    assert result.returncode == 2 and len(lines) == 1, result.stderr
    assert "unparsed.urdf" in lines[0], lines  # refused by urdfdom, or checked before it
    assert any(why in lines[0] for why in ("cannot build its URDF", "two of one name",
                                           "is not a number")), lines
    assert not (tmp_path / "u.rrd").exists()


def test_urdf_with_a_negative_mass_is_one_line(urdf_dir, good, tmp_path, capsys) -> None:
    """A negative mass crashed contact isolation (argmin of an empty sequence) in replay
    and let capture simulate and write a session of an impossible arm."""
    bad = urdf_dir / "negative.urdf"
    bad.write_text(re.sub(r'<mass value="[^"]*"/>', '<mass value="-1"/>',
                          (urdf_dir / "arm.urdf").read_text(), count=3))
    code, _, err = _replay_with(bad, good, tmp_path, capsys)
    _one_line(code, err, "negative.urdf", "mass of -1 kg")
    code, _, err = _run(recorder_app, "recorder", capsys, "capture", "--robot", f"urdf:{bad}",
                        "--pose", "A", "--action", "bump", "--duration", "2",
                        "--planned-at", "1", "--out", tmp_path / "cap")
    _one_line(code, err, "negative.urdf", "mass of -1 kg")
    assert not list(tmp_path.rglob("*.parquet")) and not (tmp_path / "u.rrd").exists()


def test_urdf_with_an_inertia_that_is_not_positive_is_one_line(urdf_dir, good, tmp_path,
                                                               capsys) -> None:
    """A negative principal inertia passed the mass check and crashed the simulator
    ('The 3d inertia should be positive', a traceback)."""
    bad = urdf_dir / "inertia.urdf"
    bad.write_text((urdf_dir / "arm.urdf").read_text().replace(
        'ixx="0.02410142547240885"', 'ixx="-5.0"'))
    assert bad.read_text() != (urdf_dir / "arm.urdf").read_text()
    code, _, err = _run(recorder_app, "recorder", capsys, "capture", "--robot", f"urdf:{bad}",
                        "--pose", "A", "--action", "bump", "--duration", "2",
                        "--planned-at", "1", "--out", tmp_path / "cap")
    _one_line(code, err, "inertia.urdf", "positive semi-definite")
    assert not list(tmp_path.rglob("*.parquet"))


# -- directories of mixed files ----------------------------------------------------------

@pytest.mark.parametrize("command", ["train", "evaluate"])
def test_dataset_with_a_dangling_or_looping_link_lists_it(good, tmp_path, capsys,
                                                          command) -> None:
    """A dataset directory holding a link named *.parquet that leads nowhere (or to
    itself): the session is listed as a problem, not a FileNotFoundError traceback from
    the feature cache's key."""
    dataset = tmp_path / "ds"
    dataset.mkdir()
    for seed, action in enumerate(("none", "bump", "none", "bump")):
        make_session(dataset, seed=seed, action=action, link=5, duration_s=2.0,
                     planned_at_s=1.0, rate_hz=200.0)
    (dataset / "gone.parquet").symlink_to(tmp_path / "nowhere.parquet")
    (dataset / "loop.parquet").symlink_to(dataset / "loop.parquet")
    argv = [command, dataset] + (["--out", tmp_path / "m.skops"] if command == "train" else [])
    code, _, err = _run(classify_app, "classify", capsys, *argv)
    assert code == 2 and "Traceback" not in err, err
    if command == "train":  # evaluate then stops at its too small split
        assert "gone.parquet" in err and "loop.parquet" in err, err


# -- noise files of the augmentation experiment --------------------------------------------

@pytest.mark.parametrize("text", ["[1, 2]", '{"tau_sigma_nm": "abc"}', '{"tau_sigma_nm": [1, 2]}',
                                  '{"thesis_tau_std_nm": {"a": 1}}', "\udcff{}",
                                  '{"tau_sigma_nm": [NaN, 1, 1, 1, 1, 1, 1]}',
                                  '{"tau_sigma_nm": [-1, 1, 1, 1, 1, 1, 1]}',
                                  '{"tau_sigma_nm": [[1], 1, 1, 1, 1, 1, 1]}'])
def test_augmentation_noise_file_of_the_wrong_shape_is_one_line(tmp_path, text) -> None:
    """``classify experiment augmentation --noise-file``: the baseline it reads is 7
    finite non-negative torques [Nm], or the file is refused naming itself."""
    from contactkit.classify.experiments.augmentation import noise_baseline

    path = tmp_path / "noise.json"
    path.write_bytes(text.encode(errors="surrogateescape"))
    with pytest.raises(InputError) as caught:
        noise_baseline(tmp_path, path)
    assert caught.value.path == str(path) and "\n" not in str(caught.value)
    (tmp_path / "dir.json").mkdir()
    with pytest.raises(InputError):
        noise_baseline(tmp_path, tmp_path / "dir.json")


# -- ONNX model files ----------------------------------------------------------------------

@pytest.mark.parametrize("doc", ["{", "[1, 2]", '"x"', "{}", '{"classes": "abc"}'],
                         ids=["not-json", "list", "string", "no-classes", "classes-str"])
def test_onnx_model_with_metadata_of_the_wrong_shape_is_one_line(tmp_path, good, capsys,
                                                                  doc) -> None:
    """The ``contactkit`` metadata of an ONNX file that is not JSON, not an object or
    lacks its classes: one line naming the file, not a JSONDecodeError/AttributeError/
    KeyError traceback (the digest matches: it is a checksum anyone can recompute)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    from contactkit.classify.modelfile.onnx_model import _graph_digest

    x = helper.make_tensor_value_info("grid", TensorProto.FLOAT, [1, 3])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3])
    model = helper.make_model(helper.make_graph([helper.make_node("Identity", ["grid"],
                                                                  ["y"])], "g", [x], [y]))
    if doc.startswith("{") and doc.endswith("}"):
        doc = json.dumps(json.loads(doc) | {"graph_sha256": _graph_digest(model)})
    entry = model.metadata_props.add()
    entry.key, entry.value = "contactkit", doc
    path = tmp_path / "net.onnx"
    onnx.save(model, str(path))
    code, _, err = _run(classify_app, "classify", capsys, "predict", path, good)
    _one_line(code, err, "net.onnx", "not a contactkit model")
