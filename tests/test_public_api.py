"""Every package says what is public in ``__all__`` (the API reference is built from it),
every name there exists, and importing a package imports none of the heavy libraries."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

HEAVY = ("torch", "sklearn", "rerun", "pinocchio", "distributed", "polars", "matplotlib")


def _packages() -> list[str]:
    """Return every package pyproject ships."""
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    return tomllib.loads(pyproject.read_text())["tool"]["setuptools"]["packages"]


@pytest.mark.parametrize("name", _packages())
def test_all_names_exist(name: str) -> None:
    package = importlib.import_module(name)
    assert isinstance(getattr(package, "__all__", None), list), f"{name} has no __all__"
    for public in package.__all__:
        assert hasattr(package, public) or importlib.util.find_spec(f"{name}.{public}"), \
            f"{name}.__all__ names {public!r}, which does not exist"


def test_importing_the_packages_stays_light() -> None:
    code = ("import importlib, json, sys\n"
            f"for name in {_packages()!r}:\n"
            "    importlib.import_module(name)\n"
            f"print(json.dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    assert json.loads(done.stdout) == []


def test_moved_modules_keep_their_earlier_names() -> None:
    """classify/'s modules moved into subpackages; their earlier names (in plugins,
    notebooks and model files written before) give the same module objects, and the
    earlier modules that became packages hand out their main module's names."""
    from contactkit.classify import MOVED

    for old, new in MOVED.items():
        earlier = importlib.import_module(f"contactkit.classify.{old}")
        assert earlier is importlib.import_module(f"contactkit.classify.{new}"), old
    from contactkit.classify.events import EventPipeline
    from contactkit.classify.events.contact_events import EventPipeline as at_its_place
    from contactkit.classify.modelfile import load_model
    from contactkit.classify.modelfile.model_file import load_model as loader

    assert EventPipeline is at_its_place and load_model is loader
    with pytest.raises(ImportError):
        from contactkit.classify.events import no_such_name  # noqa: F401
