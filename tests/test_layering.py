"""The layering README describes, checked on every module's imports.

contactkit.util/errors <- schemas <- features <- classify <- replay, and recorder <-
schemas, features (replay may also import recorder). ``cli.py`` modules are the
composition roots and may import anything. Every import of the project goes through
the one root ``contactkit``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BASE = {"contactkit", "contactkit.errors", "contactkit.util", "contactkit.robots"}
# Subpackage -> the contactkit subpackages its library modules may import. The robot
# models (contactkit.robots) sit beside util at the bottom: everything may use them,
# and they import only util and errors.
ALLOWED = {
    "contactkit": set(),
    "schemas": set(),
    "features": {"schemas"},
    "classify": {"schemas", "features"},
    "recorder": {"schemas", "features"},
    "replay": {"schemas", "features", "classify", "recorder"},
}
FOLDERS = {"contactkit": ROOT / "contactkit", **{p: ROOT / p for p in ALLOWED if p != "contactkit"}}
TOP_LEVEL = set(ALLOWED) - {"contactkit"}


def _imports(path: Path, package: str) -> list[tuple[int, str]]:
    """Return (line, absolute module name) of every import in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = ["contactkit", package] if package != "contactkit" else ["contactkit"]
                rel = path.relative_to(FOLDERS[package]).parent.parts
                base = [*parts, *rel][: len(parts) + len(rel) - (node.level - 1)]
                found.append((node.lineno, ".".join([*base, *([node.module] if node.module
                                                                 else [])])))
            else:
                found.append((node.lineno, node.module or ""))
    return found


def _violations(package: str) -> list[str]:
    problems = []
    for path in sorted(FOLDERS[package].rglob("*.py")):
        for line, module in _imports(path, package):
            where = f"{path.relative_to(FOLDERS[package].parent)}:{line} imports {module}"
            top = module.split(".")[0]
            if top in TOP_LEVEL:
                problems.append(f"{where} (not through the contactkit root)")
                continue
            if top != "contactkit" or path.name == "cli.py":
                continue
            parts = module.split(".")
            target = parts[1] if len(parts) > 1 else ""
            if module in BASE or ".".join(parts[:2]) in BASE or target == package:
                continue
            if target not in ALLOWED[package]:
                problems.append(f"{where} (layering: {package} may import "
                                f"{', '.join(sorted(ALLOWED[package])) or 'only util/errors'})")
    return problems


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_follow_the_layering(package: str) -> None:
    assert _violations(package) == []


def test_the_check_sees_a_violation(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = tmp_path / "features"
    folder.mkdir()
    (folder / "bad.py").write_text("from contactkit.classify import models\nimport schemas\n")
    (folder / "cli.py").write_text("from contactkit.replay import cli\n")
    monkeypatch.setitem(FOLDERS, "features", folder)
    problems = _violations("features")
    assert len(problems) == 2
    assert "layering" in problems[0] and "contactkit root" in problems[1]
