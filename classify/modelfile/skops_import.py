"""``skops.io``, imported on first use and without torch or Dask.

When skops.io is first imported it lists the estimator types it trusts by walking
scikit-learn's packages (``sklearn.utils.all_estimators``). The walk imports every
module before it filters scikit-learn's vendored externals out, and two of those,
``sklearn.externals.array_api_compat.torch`` and ``.dask``, import torch and dask:
seconds of start-up and hundreds of MB for no trusted type. They are marked missing
while skops.io is imported (the walk skips a module that cannot be imported), so the
trusted list is the same and loading a model file imports neither library.
"""

from __future__ import annotations

import sys
from types import ModuleType

WALK_SKIPS = ("sklearn.externals.array_api_compat.torch",
              "sklearn.externals.array_api_compat.dask")
"""Modules scikit-learn's package walk would import for skops, and which it leaves out of
the estimator list anyway."""


def skops_io() -> ModuleType:
    """Return the ``skops.io`` module, importing it on first use without the modules of
    :data:`WALK_SKIPS` (nor torch or dask through them)."""
    if "skops.io" in sys.modules:
        return sys.modules["skops.io"]
    blocked = [name for name in WALK_SKIPS if name not in sys.modules]
    for name in blocked:
        sys.modules[name] = None  # type: ignore[assignment]  # import raises: the walk skips it
    try:
        import skops.io
    finally:
        for name in blocked:
            if name in sys.modules and sys.modules[name] is None:
                del sys.modules[name]
    return skops.io
