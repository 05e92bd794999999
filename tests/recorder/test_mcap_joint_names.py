"""export-mcap names the joints of every /joint_states message as the session's robot
names them, also for a session with wrench columns (the exporter's lambdas once read a
loop variable that the wrench topics rebound to their column names; found by mypy)."""

from __future__ import annotations

from pathlib import Path

from conftest import make_session

from contactkit.recorder.importers.mcap_export import export_mcap
from contactkit.schemas import read_session


def test_joint_states_name_the_robots_joints(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    session = make_session(tmp_path, duration_s=0.5, planned_at_s=0.2)
    assert read_session(session).has("f_ext_x")  # the wrench topics are written too
    mcap = export_mcap(session, tmp_path / "s.mcap")
    with AnyReader([mcap], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        connections = [c for c in reader.connections if c.topic == "/joint_states"]
        names = {tuple(reader.deserialize(raw, c.msgtype).name)
                 for c, _, raw in reader.messages(connections=connections)}
    assert names == {tuple(f"panda_joint{j}" for j in range(1, 8))}
