"""Safe output paths: every file name contactkit writes is built from checked parts.

Values that end up in a file name often come from outside (metadata of imported
files, CAN logs, command-line options). :func:`safe_name` accepts a file-name
component only when it cannot name another directory, a hidden file or a device;
:func:`inside` resolves a name against the output directory and refuses anything
that lands outside it (``..``, absolute paths, symbolic links pointing away).
Writing itself goes through :mod:`contactkit.util.atomic`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from contactkit.errors import InputError

MAX_NAME_CHARS = 200
_SAFE = re.compile(r"[A-Za-z0-9_+][A-Za-z0-9._+-]*")


def safe_name(part: str, what: str = "file name") -> str:
    """Return ``part`` unchanged when it is a safe file-name component.

    Safe: 1 to 200 characters out of letters, digits, ``. _ + -``, not starting with a
    dot or a dash (no hidden files, no options, no ``..``). Raises :class:`InputError`
    naming ``what`` otherwise.
    """
    if not isinstance(part, str) or not _SAFE.fullmatch(part) or len(part) > MAX_NAME_CHARS:
        raise InputError(f"unsafe {what} {str(part)[:80]!r} (use 1-{MAX_NAME_CHARS} letters, "
                         "digits, '.', '_', '+' or '-', not starting with '.' or '-')")
    return part


def inside(out_dir: str | Path, name: str | Path) -> Path:
    """Return ``out_dir / name`` resolved, after checking that it lies inside ``out_dir``.

    Raises :class:`InputError` when the name is empty, absolute, climbs out with
    ``..`` or resolves outside through a symbolic link.
    """
    base = Path(out_dir).resolve()
    if str(name) in ("", ".") or Path(name).is_absolute():
        raise InputError(f"output name {str(name)!r} is not a file name inside the output "
                         "directory", out_dir)
    target = (base / name).resolve()
    if target == base or not target.is_relative_to(base):
        raise InputError(f"output name {str(name)!r} leads outside the output directory",
                         out_dir)
    return target


def catalog_beside(dataset: str | Path) -> Path:
    """Return the default Rerun catalog folder of a dataset: ``<dataset name>-catalog``
    beside it (``recorder browse DATASET`` builds it there; ``recorder stats`` links each
    session to its recording there)."""
    dataset = Path(os.path.abspath(dataset))
    return dataset.parent / f"{dataset.name}-catalog"
