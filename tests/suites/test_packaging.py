"""The built wheel installs one import root, ``contactkit``, and nothing beside it."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_wheel_holds_only_the_contactkit_package(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(tmp_path), str(ROOT)], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    (wheel,) = tmp_path.glob("contactkit-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {name.split("/")[0] for name in names}
    dist_info = {t for t in tops if t.endswith(".dist-info")}
    assert tops - dist_info == {"contactkit"}, sorted(tops)
    for module in ("contactkit/recorder/sources/__init__.py", "contactkit/schemas/session.py",
                   "contactkit/util/parallel.py", "contactkit/cli/replay.py",
                   "contactkit/recorder/data/can_default_map.toml"):
        assert module in names
    assert not any("/tests/" in n or n.startswith("tests/") for n in names)
    (entry_points,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    scripts = zipfile.ZipFile(wheel).read(entry_points).decode()
    for command in ("recorder", "replay", "classify"):
        assert f"{command} = contactkit.cli.{command}:main" in scripts


def test_every_source_package_is_listed_in_pyproject() -> None:
    """A new subpackage (a folder with ``__init__.py``) must be in pyproject's package list,
    or the wheel silently leaves it out."""
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    folders = {package: ROOT / folder for package, folder in config["package-dir"].items()}
    found = set()
    for package, folder in folders.items():
        for init in folder.rglob("__init__.py"):
            rel = init.parent.relative_to(folder).parts
            found.add(".".join([package, *rel]))
    assert found - listed == set(), "add these to [tool.setuptools] packages"
    assert listed - found == set(), "listed but not in the tree"
