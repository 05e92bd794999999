"""Which existing files a writer may replace: its own, recognised by a mark.

Every writer of :mod:`contactkit.util.atomic` refuses to replace a file unless asked
(``--overwrite``) or unless an :data:`~contactkit.util.atomic.Owned` test says the file is
the tool's own. This module holds those tests and the marks they look for: a marker in a
file's first bytes (:func:`owned_by_marker`: a stats report, a Rerun recording), and the
``contactkit result`` mark of the fixed-name result files that experiments write
(:func:`result_markdown`, :func:`result_json`, :func:`write_figure`, checked by
:func:`owned_result` and, before any work, :func:`check_results`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from contactkit.errors import InputError
from contactkit.util.atomic import Owned, atomic_write, check_target

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def owned_by_marker(marker: bytes, within: int = 4096) -> Owned:
    """Return an :data:`Owned` test: the file's first ``within`` bytes hold ``marker``."""
    def test(path: Path) -> bool:
        with open(path, "rb") as fh:
            return marker in fh.read(within)
    return test


RESULT_MARK = "contactkit result"
"""Written into every fixed-name result file (:func:`result_markdown`,
:func:`result_json`, the PNG's ``Software`` of :func:`write_figure`), so that a re-run
recognises its own results, and no other file of that name, as replaceable."""
RESULT_MARKERS = {".md": b"<!-- ", ".json": b"{", ".png": b"\x89PNG"}


def result_markdown(text: str) -> str:
    """Return a result file's Markdown ``text`` with :data:`RESULT_MARK` on its first
    line (an HTML comment, which Markdown does not show)."""
    return f"<!-- {RESULT_MARK} -->\n{text}"


def result_json(doc: dict[str, Any]) -> dict[str, Any]:
    """Return a result file's JSON object ``doc`` with :data:`RESULT_MARK` first."""
    return {"generator": RESULT_MARK} | doc


def owned_result(path: Path) -> bool:
    """:data:`Owned` for the fixed-name result files a command writes into its output
    directory (``gridsearch.md``, ``augmentation.png``, ...): a regular file of the kind
    its suffix names (Markdown, JSON object, PNG) that holds :data:`RESULT_MARK` near its
    start. A user's own notes, JSON or picture of that name are not replaced."""
    marker = RESULT_MARKERS.get(path.suffix.lower())
    if marker is None or not path.is_file() or path.is_symlink():
        return False
    with open(path, "rb") as fh:
        head = fh.read(4096)
    return head.startswith(marker) and RESULT_MARK.encode() in head


def check_results(out_dir: str | Path, names: Sequence[str]) -> list[Path]:
    """Check, before any work, that the fixed-name result files ``names`` may be written
    into ``out_dir``: each is missing or contactkit's own (:func:`owned_result`); return
    their paths. A directory that does not exist yet holds nothing to refuse; a file or
    a link to nothing at its name is refused. Raises the one-line :class:`InputError` of
    :func:`check_target` otherwise, so that a command that runs for hours does not find
    out at its end."""
    out_dir = Path(out_dir)
    paths = [out_dir / name for name in names]
    if os.path.lexists(out_dir) and not out_dir.is_dir():
        raise InputError("is not a directory: results go into one", out_dir)
    if out_dir.is_dir():
        for path in paths:
            check_target(path, owned=owned_result)
    return paths


def write_figure(path: str | Path, fig: Figure, *, overwrite: bool = False,
                 owned: Owned | None = None, **savefig: Any) -> Path:
    """Save a Matplotlib figure as PNG to ``path`` with :func:`atomic_write`; return it.
    The PNG's ``Software`` is :data:`RESULT_MARK` unless ``metadata`` says otherwise."""
    savefig.setdefault("metadata", {"Software": RESULT_MARK})
    with atomic_write(path, overwrite=overwrite, owned=owned) as tmp:
        fig.savefig(tmp.file, format="png", **savefig)
    return Path(path)
