"""MkDocs hooks: pages generated from the code at build time, so they cannot drift.

* ``reference/cli.md``: the ``--help`` of ``recorder``, ``replay`` and ``classify`` and of
  every (sub)command, rendered by the Typer apps themselves;
* ``reference/session-format.md``: the session columns (``COLUMN_ORDER`` and their
  Arrow types) and the metadata fields of ``SessionMeta``, with the schema's docstring;
* ``build/api-src/contactkit``: the package as it installs, one symbolic link per part
  (from ``[tool.setuptools.package-dir]``), so that mkdocstrings finds
  ``contactkit.schemas`` and the other subpackages, whose folders sit at the repository
  root, by reading the source (``paths`` in ``mkdocs.yml``);
* ``viewer.png`` and ``viewer-annotated.png``: the browser check's screenshot of the demo
  replay that `make docs` has just taken (``docs/screenshots.py``), numbered for the
  "Read the Rerun view" tutorial; without one (no browser here) the committed copies.

Registered in ``mkdocs.yml`` under ``hooks:``; nothing is written into ``docs/``.
"""

from __future__ import annotations

import dataclasses
import inspect
import itertools
import os
import sys
import textwrap
import tomllib
from pathlib import Path

from mkdocs.structure.files import File
from typer.main import get_command
from typer.testing import CliRunner

TOOLS = (("recorder", "contactkit.cli.recorder"), ("classify", "contactkit.cli.classify"),
         ("replay", "contactkit.cli.replay"))
HELP_WIDTH = "100"
ROOT = Path(__file__).resolve().parents[1]
API_SRC = ROOT / "build" / "api-src"
SHOTS = ROOT / "build" / "screenshots"


def stage_package() -> Path:
    """Link the package's folders into ``build/api-src/contactkit`` as they install, and
    return ``build/api-src``."""
    mapping = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-dir"]
    top = API_SRC / "contactkit"
    top.mkdir(parents=True, exist_ok=True)
    links = {entry.name: entry for entry in (ROOT / mapping["contactkit"]).iterdir()
             if entry.name != "__pycache__"}
    for package, folder in mapping.items():
        if package != "contactkit":
            links[package.split(".", 1)[1]] = ROOT / folder
    for stale in top.iterdir():
        if stale.name not in links or stale.resolve() != links[stale.name].resolve():
            stale.unlink()
    for name, target in links.items():
        if not (top / name).is_symlink():
            (top / name).symlink_to(target)
    return API_SRC


def _help(app: object, prog: str, args: list[str]) -> str:
    """Return the plain-text ``--help`` of ``prog args`` as the tool prints it."""
    env = {"COLUMNS": HELP_WIDTH, "NO_COLOR": "1", "TERM": "dumb"}
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # rich reads the width from the environment, not the runner's
    try:
        result = CliRunner().invoke(app, [*args, "--help"], prog_name=prog, env=env)
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
    if result.exit_code != 0:
        raise RuntimeError(f"{prog} {' '.join(args)} --help failed: {result.output}")
    return "\n".join(line.rstrip() for line in result.output.strip().splitlines())


def _walk(command: object, path: list[str]) -> list[list[str]]:
    """Return the argument paths of a command and all its subcommands, in help order."""
    paths = [path]
    if hasattr(command, "list_commands"):  # a group (Typer may bring its own click)
        ctx = command.context_class(command)
        for name in command.list_commands(ctx):
            sub = command.get_command(ctx, name)
            if sub is not None and not getattr(sub, "hidden", False):
                paths += _walk(sub, [*path, name])
    return paths


def cli_reference() -> str:
    """Return the Markdown page with every command's ``--help``."""
    import importlib

    out = ["# Command reference", "",
           "Generated at build time from the command-line tools themselves "
           "(`docs/hooks.py` runs each `--help`), so it always matches the installed "
           "version. Units are in brackets, choices in braces.", ""]
    for prog, module in TOOLS:
        app = importlib.import_module(module).app
        command = get_command(app)
        single = not hasattr(command, "list_commands")
        out += [f"## `{prog}`", ""]
        for path in _walk(command, []):
            if path:
                out += [f"### `{prog} {' '.join(path)}`", ""]
            elif not single:
                out += [f"Run `{prog} COMMAND --help` for a command's options.", ""]
            out += ["```text", _help(app, prog, path), "```", ""]
    return "\n".join(out)


def _type_name(annotation: object) -> str:
    text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__",
                                                                   str(annotation))
    return text.replace("|", "\\|")


def _field_docs(cls: type) -> dict[str, str]:
    """Return the attribute docstrings (a string literal right after a field) of a dataclass."""
    import ast

    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body
    docs = {}
    for node, nxt in itertools.pairwise(body):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                and isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant)
                and isinstance(nxt.value.value, str)):
            docs[node.target.id] = " ".join(nxt.value.value.split())
    return docs


def session_format() -> str:
    """Return the Markdown page of the session format, from ``contactkit.schemas``'
    ``columns``, ``metadata`` and ``session`` modules."""
    from contactkit.schemas import columns, metadata, session

    out = ["# Session format", "",
           "Generated at build time from `contactkit.schemas` (`columns.COLUMN_ORDER`, "
           "`columns.column_type`, `metadata.SessionMeta`). A session is one Parquet file; "
           f"the schema version is **{metadata.SCHEMA_VERSION}**.", "",
           "## The schema's own description", "",
           "```text", inspect.cleandoc(columns.__doc__ or ""), "```", "",
           "## Columns, in file order", "",
           "| column | Arrow type | required |", "|---|---|---|"]
    required = set(columns.REQUIRED_COLUMNS)
    for name in columns.COLUMN_ORDER:
        out.append(f"| `{name}` | {columns.column_type(name)} | "
                   f"{'yes' if name in required else 'optional'} |")
    out += ["", "## Metadata", "",
            f"The key-value metadata key `{session.METADATA_KEY.decode()}` holds one JSON "
            "document with these fields (`SessionMeta`; "
            f"{inspect.cleandoc(metadata.SessionMeta.__doc__ or '')})", "",
            "| field | type | default | meaning |", "|---|---|---|---|"]
    docs = _field_docs(metadata.SessionMeta)
    for f in dataclasses.fields(metadata.SessionMeta):
        if f.default is not dataclasses.MISSING:
            default = f"`{f.default!r}`"
        elif f.default_factory is not dataclasses.MISSING:
            default = f"`{f.default_factory()!r}`"
        else:
            default = "required"
        meaning = docs.get(f.name, "").replace("|", "\\|").replace("``", "`")
        meaning = meaning.replace(":mod:", "").replace(":class:", "")
        out.append(f"| `{f.name}` | `{_type_name(f.type)}` | {default} | {meaning} |")
    out += ["", f"Actions: {', '.join(f'`{a}`' for a in metadata.ACTIONS)}; conditions: "
            f"{', '.join(f'`{c}`' for c in metadata.CONDITIONS)}.", ""]
    return "\n".join(out)


GENERATED = {"reference/cli.md": cli_reference, "reference/session-format.md": session_format}


def on_startup(command, dirty, **kwargs):
    """Stage the package for mkdocstrings before any page is read."""
    stage_package()


def screenshots(files, config) -> None:
    """Put the demo replay's fresh screenshot and its numbered copy on the site in place
    of the committed ones, when `make docs` has taken one."""
    sys.path.insert(0, str(ROOT / "docs"))
    from screenshots import SHOT, annotate

    if not SHOT.is_file():
        print("docs: no fresh screenshot of the demo replay (the browser check did not run "
              "here): the site keeps the committed docs/viewer*.png", file=sys.stderr)
        return
    fresh = {"viewer.png": SHOT,
             "viewer-annotated.png": annotate(SHOT, SHOTS / "viewer-annotated.png")}
    for uri, path in fresh.items():
        files.remove(files.get_file_from_path(uri))
        files.append(File.generated(config, uri, abs_src_path=str(path)))


def on_files(files, config, **kwargs):
    """Add the generated pages and the fresh screenshots to the site."""
    for uri, render in GENERATED.items():
        files.append(File.generated(config, uri, content=render()))
    screenshots(files, config)
    return files
