"""contactkit's cache directory (default model, viewer assets)."""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir() -> Path:
    """Return contactkit's cache directory ($CONTACTKIT_CACHE, else the XDG cache), created."""
    root = os.environ.get("CONTACTKIT_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "contactkit")
    path = Path(root)
    path.mkdir(parents=True, exist_ok=True)
    return path
