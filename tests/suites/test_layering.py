"""The layering in README and DESIGN notes, checked on every module's imports, lazy ones too.

The contract is the table ``LAYERS`` below, and nothing is exempt. From the bottom:

* ``contactkit`` (the root and :mod:`contactkit.errors`), ``contactkit.util`` and
  ``contactkit.robots``: the base everything may use;
* ``schemas`` (pyarrow only) <- ``features`` <- ``classify``;
* ``viewer`` (the Rerun layout) on schemas; ``recorder`` on schemas, features and viewer;
  ``replay`` on schemas, features, classify and viewer;
* ``cli``: the commands, the only modules that may join recorder and classify.

Besides the table, no import cycle may exist among contactkit's modules, counting the
imports inside functions. Third-party imports are not checked here.
"""

from __future__ import annotations

import ast
import functools
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BASE = {"contactkit", "contactkit.errors", "contactkit.util", "contactkit.robots"}
# Layer -> the layers its modules may import (besides BASE and itself).
LAYERS = {
    "base": set(),
    "contactkit.schemas": set(),
    "contactkit.features": {"contactkit.schemas"},
    "contactkit.viewer": {"contactkit.schemas"},
    "contactkit.classify": {"contactkit.schemas", "contactkit.features"},
    "contactkit.recorder": {"contactkit.schemas", "contactkit.features", "contactkit.viewer"},
    "contactkit.replay": {"contactkit.schemas", "contactkit.features", "contactkit.classify",
                          "contactkit.viewer"},
    "contactkit.cli": {"contactkit.schemas", "contactkit.features", "contactkit.classify",
                       "contactkit.viewer", "contactkit.recorder", "contactkit.replay"},
}
# Inside the base: util and robots may import errors; robots may import util; util may
# not import robots.
BASE_ORDER = {"contactkit.errors": set(), "contactkit": {"contactkit.errors"},
              "contactkit.util": {"contactkit.errors"},
              "contactkit.robots": {"contactkit.errors", "contactkit.util"}}


def source_folders() -> dict[str, Path]:
    """Return {package name: folder} of contactkit's top-level packages, from pyproject."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    return {name: ROOT / folder for name, folder in config["package-dir"].items()}


def all_modules(folders: dict[str, Path]) -> dict[str, Path]:
    """Return {dotted module name: file} of every module of the project."""
    modules = {}
    for package, folder in folders.items():
        for path in sorted(folder.rglob("*.py")):
            if package == "contactkit" and any(
                    (ROOT / f).resolve() in path.resolve().parents
                    for n, f in folders.items() if n != "contactkit"):
                continue
            rel = path.relative_to(folder).with_suffix("").parts
            if rel[-1] == "__init__":
                rel = rel[:-1]
            modules[".".join([package, *rel])] = path
    return modules


def imported_modules(name: str, path: Path, modules: dict[str, Path]
                     ) -> list[tuple[int, str]]:
    """Return (line, module) of every project module ``path`` imports, anywhere in it.
    ``from package import name`` counts as importing the submodule when ``name`` is one."""
    found = []
    is_package = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_package else name.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                module = ".".join([*base, *([node.module] if node.module else [])])
            else:
                module = node.module or ""
            targets = [f"{module}.{a.name}" if f"{module}.{a.name}" in modules else module
                       for a in node.names]
        else:
            continue
        found += [(node.lineno, t) for t in targets
                  if t.split(".")[0] in {"contactkit", *_bare_tops()}]
    return found


@functools.cache
def _bare_tops() -> frozenset[str]:
    """Return the folder names that install under contactkit (schemas, features, ...)."""
    return frozenset(n.split(".")[1] for n in source_folders() if n != "contactkit")


def layer_of(module: str) -> str:
    """Return the layer a module belongs to (see LAYERS)."""
    parts = module.split(".")
    for depth in (2, 1):
        head = ".".join(parts[:depth])
        if head in LAYERS:
            return head
        if head in BASE:
            return "base"
    return "base"


def _base_part(module: str) -> str:
    parts = module.split(".")
    two = ".".join(parts[:2])
    return two if two in BASE_ORDER else "contactkit"


def violations(modules: dict[str, Path]) -> list[str]:
    """Return one line per import that breaks the layering."""
    problems = []
    for name, path in modules.items():
        layer = layer_of(name)
        for line, target in imported_modules(name, path, modules):
            where = f"{path.name if ROOT not in path.parents else path.relative_to(ROOT)}:{line} " \
                    f"imports {target}"
            if not target.startswith("contactkit"):
                problems.append(f"{where} (not through the contactkit root)")
                continue
            other = layer_of(target)
            if other == "base":
                if layer == "base" and _base_part(target) != _base_part(name) and \
                        _base_part(target) not in BASE_ORDER[_base_part(name)]:
                    problems.append(f"{where} (layering inside the base)")
                continue
            if other != layer and other not in LAYERS[layer]:
                allowed = ", ".join(sorted(LAYERS[layer])) or "only the base"
                problems.append(f"{where} (layering: {layer} may import {allowed})")
    return problems


def import_cycles(modules: dict[str, Path]) -> list[list[str]]:
    """Return the import cycles among the project's modules (strongly connected
    components of more than one module, or a module importing itself)."""
    graph = {name: sorted({t for _, t in imported_modules(name, path, modules)
                           if t in modules and t != name})
             for name, path in modules.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []

    def visit(node: str) -> None:  # Tarjan's algorithm
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in graph[node]:
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return cycles


def _modules_importing_each_other() -> dict[str, Path]:
    return all_modules(source_folders())


def test_every_module_follows_the_layering() -> None:
    assert violations(_modules_importing_each_other()) == []


def test_no_import_cycles_among_contactkit_modules() -> None:
    cycles = import_cycles(_modules_importing_each_other())
    assert cycles == [], "\n".join(" <-> ".join(c) for c in cycles)


def test_every_module_is_checked() -> None:
    modules = _modules_importing_each_other()
    for name in ("contactkit.cli.recorder", "contactkit.cli.replay", "contactkit.cli.classify",
                 "contactkit.recorder.sim.simulator", "contactkit.viewer.layout",
                 "contactkit.robots.model", "contactkit.errors"):
        assert name in modules


def test_the_check_sees_violations_and_cycles(tmp_path: Path) -> None:
    schemas = tmp_path / "schemas"
    schemas.mkdir()
    (schemas / "bad.py").write_text("def f():\n    from contactkit.classify import models\n"
                                    "import schemas\n")
    (schemas / "a.py").write_text("def f():\n    from contactkit.schemas import b\n")
    (schemas / "b.py").write_text("from contactkit.schemas.a import f\n")
    classify = tmp_path / "classify"
    classify.mkdir()
    (classify / "models.py").write_text("")
    (classify / "uses_recorder.py").write_text("import contactkit.recorder.sim\n")
    modules = all_modules({"contactkit.schemas": schemas, "contactkit.classify": classify})
    problems = violations(modules)
    assert len(problems) == 3, problems
    assert sum("contactkit.schemas may import" in p for p in problems) == 1
    assert sum("contactkit root" in p for p in problems) == 1
    assert sum("contactkit.classify may import" in p for p in problems) == 1
    assert import_cycles(modules) == [["contactkit.schemas.a", "contactkit.schemas.b"]]
