"""One safe writer: every file the library writes goes through contactkit.util.atomic
(a temporary named with the writer's pid, renamed into place), so no other module
renames files or makes temporaries of its own that remove_stale_temporaries would miss."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LIBRARY = ("contactkit", "schemas", "features", "classify", "recorder", "replay")
WRITER = ROOT / "contactkit" / "util" / "atomic.py"
OWN_WRITES = re.compile(r"os\.replace\(|os\.rename\(|\.rename\((?!\s*$|\{)|shutil\.move\(|"
                        r"mkstemp\(|mkdtemp\(|NamedTemporaryFile\(|\.tmp[\"']")
"""Renaming or making named temporaries (a polars ``.rename({...})`` is not one)."""


def test_no_writer_beside_atomic() -> None:
    found = []
    for folder in LIBRARY:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path == WRITER:
                continue
            for number, line in enumerate(path.read_text().splitlines(), 1):
                code = line.split("#", 1)[0]
                if OWN_WRITES.search(code):
                    found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not found, "write through contactkit.util.atomic instead:\n" + "\n".join(found)
