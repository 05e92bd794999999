"""Experiments: the thesis's (:mod:`.thesis`), data augmentation (:mod:`.augmentation`)
and the grid search over model settings (:mod:`.gridsearch`).

The names of :mod:`contactkit.classify.experiments.thesis` can also be imported from
here (``from contactkit.classify.experiments import feature_identification``), as they
were before this package had modules of its own; nothing is imported until one is asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["augmentation", "gridsearch", "thesis"]
"""The public modules, for the API reference."""
_MAIN = "contactkit.classify.experiments.thesis"


def __getattr__(name: str) -> Any:
    """Return ``name`` from
    :mod:`contactkit.classify.experiments.thesis` (imported on first use)."""
    if name.startswith("__"):
        raise AttributeError(name)
    try:
        return getattr(importlib.import_module(_MAIN), name)
    except AttributeError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
