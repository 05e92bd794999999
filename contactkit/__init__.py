"""contactkit: record, replay and classify physical human-robot contact.

One import root. The subpackages live in top-level folders of the repository and
are mapped here by setuptools' ``package-dir``:

* :mod:`contactkit.schemas`: session, index and feature file formats, validation;
* :mod:`contactkit.features`: robot dynamics, observer, feature chain, windows;
* :mod:`contactkit.classify`: classifiers, evaluation, experiments, model files;
* :mod:`contactkit.recorder`: sources, capture, importers, datasets, statistics;
* :mod:`contactkit.replay`: streaming replay and Rerun logging.

Dependencies flow one way (``schemas <- features <- classify <- replay``;
``recorder`` uses ``schemas`` and ``features``), and the shared helpers in this
package itself (:mod:`contactkit.util`) sit below all of them.
"""

from __future__ import annotations


def __getattr__(name: str) -> str:
    """Return ``__version__``, the installed distribution's version ("0+unknown" in a
    source tree that is not installed), found on first use: reading distributions'
    metadata imports :mod:`importlib.metadata` (some 35 ms), which most commands never
    need."""
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib.metadata

    try:
        version = importlib.metadata.version("contactkit")
    except importlib.metadata.PackageNotFoundError:
        version = "0+unknown"
    globals()["__version__"] = version  # found once: later reads are plain attributes
    return version

# The version and the subpackages (names only: importing contactkit stays light).
__all__ = ["__version__", "classify", "cli", "errors", "features", "recorder", "replay",
           "robots", "schemas", "util", "viewer"]
