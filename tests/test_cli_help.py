"""--help of the three command-line tools: units survive, choices are listed."""

from __future__ import annotations

import enum
import importlib
import re
import types
import typing

import pytest
import typer
from typer.main import get_command
from typer.testing import CliRunner

# Options that take one of a fixed set of values, per tool and command ("" for a tool
# with a single command): each must be a choice, so --help lists the values.
CHOICE_OPTIONS = {
    "recorder": {"capture": {"pose", "action", "source", "condition", "target_pose", "viewer"},
                 "stats": {"fmt"}, "simulate": {"preset"}, "browse": {"viewer"},
                 "import-can": {"pose", "action", "condition", "target_pose"}},
    "classify": {"evaluate": {"protocol", "group"}, "train": {"model"}},
    "replay": {"": {"viewer"}},
}
UNIT = re.compile(r"\[[^\]]+\]")


def _app(name: str, monkeypatch: pytest.MonkeyPatch) -> typer.Typer:
    """Return the Typer app that the tool's main() runs."""
    module = importlib.import_module(f"contactkit.cli.{name}")
    captured = {}

    def capture_app(app: typer.Typer, prog: str, argv: list[str] | None = None) -> int:
        captured["app"] = app
        return 0

    monkeypatch.setattr(module, "run_app", capture_app)
    with pytest.raises(SystemExit):
        module.main()
    return captured["app"]


def _choices(param: object) -> list[str]:
    """Return the values a parameter accepts when it is a choice (Literal or Enum), else []."""
    annotation = param.type_descriptor.annotation
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType) and len(args) == 1:
        annotation = args[0]
    if typing.get_origin(annotation) is typing.Literal:
        return [str(v) for v in typing.get_args(annotation)]
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return [str(m.value) for m in annotation]
    return []


def _commands(app: typer.Typer) -> dict[str, object]:
    command = get_command(app)
    return dict(getattr(command, "commands", {"": command}))


@pytest.mark.parametrize("name", ["recorder", "classify", "replay"])
def test_help_keeps_units_and_lists_choices(name: str, monkeypatch: pytest.MonkeyPatch
                                            ) -> None:
    app = _app(name, monkeypatch)
    runner = CliRunner()
    for sub, command in _commands(app).items():
        result = runner.invoke(app, [*([sub] if sub else []), "--help"], terminal_width=240,
                               env={"COLUMNS": "240", "NO_COLOR": "1"})
        assert result.exit_code == 0, result.output
        text = " ".join(result.output.replace("│", " ").split())
        for param in command.params:
            for unit in UNIT.findall(getattr(param, "help", None) or ""):
                assert unit in text, f"{name} {sub} --{param.name}: {unit} lost in --help"
            choices = _choices(param)
            assert all(c in text for c in choices), (name, sub, param.name)
        for wanted in CHOICE_OPTIONS[name].get(sub, ()):
            param = next(p for p in command.params if p.name == wanted)
            assert _choices(param), f"{name} {sub} --{wanted} is not a choice"


def test_recorder_help_shows_units_and_every_source_option() -> None:
    runner = CliRunner()
    module = importlib.import_module("contactkit.cli.recorder")
    text = " ".join(runner.invoke(module.app, ["capture", "--help"], terminal_width=240,
                                  env={"COLUMNS": "240"}).output.split())
    for piece in ("[rad/s]", "[s from start]", "[Hz]", "[ms]", "[s]", "<sim|can|franka>",
                  "<none|bump|adjust|shove>", "--channel", "--map", "--noise-scale"):
        assert piece in text
    arrays = runner.invoke(module.app, ["import-arrays", "--help"], terminal_width=240)
    assert "[rad]" in arrays.output
