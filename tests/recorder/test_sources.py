"""The source registry: built-in sources, options from Config dataclasses, plugins."""

from __future__ import annotations

import os
import subprocess
import textwrap
from pathlib import Path

import pytest

from contactkit.recorder.sources import (
    ProtocolChoices,
    load_sources,
    open_source,
    registered_sources,
    source_options,
)
from contactkit.recorder.sources.can import CanSource
from contactkit.recorder.sources.sim import SimSource
from contactkit.schemas import InputError, validate_session
from tests.conftest import BIN

PLUGIN = '''
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from contactkit.recorder.protocol import pose_q
from contactkit.recorder.sources import Source
from contactkit.schemas import joint_columns
from contactkit.util.params import Interval


class StillArm(Source):
    """An arm that holds its pose (a lab's plugin)."""

    name = "stillarm"
    columns = ["t", *joint_columns("q"), *joint_columns("dq"), *joint_columns("tau")]
    live = False

    @dataclass(frozen=True)
    class Config:
        samples: int = field(default=100, metadata={"help": "How many samples.",
                                                    "constraints": (Interval(2, None),)})
        period: float = field(default=0.002, metadata={"help": "Sample period.", "unit": "s"})
        motion: Literal["still", "drift"] = field(default="still", metadata={
            "help": "What the arm does."})
        torque: bool = field(default=False, metadata={"help": "Report a torque of 1 Nm."})

    def __init__(self, config, choices):
        self.config, self.choices = config, choices
        self.planned_at_s, self.duration_s = choices.timing()
        self.nominal_rate_hz = 1.0 / config.period

    @classmethod
    def from_config(cls, config, choices):
        return cls(config, choices)

    def stream(self):
        n = self.config.samples
        columns = {"t": np.arange(n) * self.config.period}
        for col, value in zip(joint_columns("q"), pose_q(self.choices.pose), strict=True):
            columns[col] = np.full(n, value)
        for col in joint_columns("dq"):
            columns[col] = np.zeros(n)
        for col in joint_columns("tau"):
            columns[col] = np.full(n, float(self.config.torque))
        if self.config.motion == "drift":
            columns["q_1"] = columns["q_1"] + 1e-4 * np.arange(n)
        yield columns

    def metadata(self):
        return {"source": self.name, "source_info": {"samples": self.config.samples}}
'''


def test_builtin_sources_and_their_options() -> None:
    assert {"sim", "can"} <= set(registered_sources())
    classes, problems = load_sources()
    assert classes["sim"] is SimSource and classes["can"] is CanSource and not problems
    sim = {o.option[2:]: o for o in source_options(SimSource.Config)}
    assert sim["rate"].unit == "Hz" and sim["rate"].default == 1000.0
    assert sim["jitter-ms"].describe().startswith("Time-stamp jitter, uniform +- [ms].")
    can = {o.option[2:]: o for o in source_options(CanSource.Config)}
    assert can["channel"].required and "map" in can and can["timeout"].unit == "s"


def test_open_source_checks_options_and_protocol() -> None:
    choices = ProtocolChoices(action="bump", pose="B", duration_s=2.0, planned_at_s=1.0)
    with pytest.raises(InputError, match="source 'can' needs the option"):
        open_source("can", {}, choices)
    with pytest.raises(InputError, match="unknown source 'ros'"):
        open_source("ros", {}, choices)
    source = open_source("sim", {"rate": 200.0, "seed": 4}, choices)
    meta = source.session_meta()
    assert (meta.source, meta.pose, meta.nominal_rate_hz, meta.planned_at_s) == \
        ("sim", "B", 200.0, 1.0)
    assert meta.session_id == open_source("sim", {"rate": 200.0, "seed": 4},
                                          choices).session_meta().session_id
    with pytest.raises(InputError, match=r"planned interaction time 3\.0 s must lie within"):
        ProtocolChoices(action="none", planned_at_s=3.0, duration_s=2.0).timing()


def test_plugin_source_from_an_entry_point(tmp_path: Path) -> None:
    plugins = tmp_path / "site"
    dist = plugins / "stillarm-0.1.dist-info"
    dist.mkdir(parents=True)
    (plugins / "stillarm.py").write_text(textwrap.dedent(PLUGIN))
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: stillarm\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[contactkit.sources]\nstillarm = stillarm:StillArm\nbroken = no_such_module:Arm\n")
    env = dict(os.environ, PYTHONPATH=str(plugins), COLUMNS="200")

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([str(BIN / "recorder"), *args], capture_output=True, text=True,
                              env=env, timeout=300)

    listing = run("sources")
    assert listing.returncode == 0, listing.stderr
    assert "stillarm: An arm that holds its pose" in listing.stdout
    assert "--period  Sample period [s]. Default: 0.002." in listing.stdout
    assert "broken: unusable" in listing.stdout
    assert "--period" in run("capture", "--help").stdout
    helptext = " ".join(run("capture", "--help").stdout.split())
    assert "--motion <still|drift>" in helptext and "--torque / --no-torque" in helptext
    result = run("capture", "--source", "stillarm", "--samples", "50", "--period", "0.004",
                 "--motion", "drift", "--torque",
                 "--pose", "C", "--action", "none", "--duration", "0.2", "--planned-at", "0.1",
                 "--out", str(tmp_path / "out"))
    assert result.returncode == 0, result.stderr
    session = validate_session(result.stdout.strip())
    assert session.n_samples == 50 and session.meta.source == "stillarm"
    assert session.tau[0, 0] == 1.0 and session.q[-1, 0] > session.q[0, 0]
    assert session.meta.nominal_rate_hz == 250.0 and session.meta.source_info == {"samples": 50}
    wrong = run("capture", "--source", "stillarm", "--rate", "100", "--pose", "C", "--action",
                "none", "--out", str(tmp_path / "out"))
    assert wrong.returncode == 2
    assert "--rate is not an option of source 'stillarm'" in wrong.stderr
    refused = run("capture", "--source", "stillarm", "--samples", "1", "--pose", "C",
                  "--action", "none", "--out", str(tmp_path / "out"))
    assert refused.returncode == 2
    assert "source 'stillarm': samples must be at least 2, got 1" in refused.stderr
