"""The model file: one file per trained model, skops (:mod:`.skops_format`, read without
importing its heavy libraries: :mod:`.skops_import`) or ONNX (:mod:`.onnx_model`),
with its metadata checked on load (:mod:`.model_file`).

The names of :mod:`contactkit.classify.modelfile.model_file` can also be imported from here (``from
contactkit.classify.modelfile import load_model``), as they were before this package had
modules of its own; nothing is imported until one is asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["model_file"]
"""The public modules, for the API reference."""
_MAIN = "contactkit.classify.modelfile.model_file"


def __getattr__(name: str) -> Any:
    """Return ``name`` from
    :mod:`contactkit.classify.modelfile.model_file` (imported on first use)."""
    if name.startswith("__"):
        raise AttributeError(name)
    try:
        return getattr(importlib.import_module(_MAIN), name)
    except AttributeError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
