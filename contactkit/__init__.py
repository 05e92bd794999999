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

import importlib.metadata

try:
    __version__ = importlib.metadata.version("contactkit")
except importlib.metadata.PackageNotFoundError:  # running from a source tree
    __version__ = "0+unknown"

# The version and the subpackages (names only: importing contactkit stays light).
__all__ = ["__version__", "classify", "cli", "errors", "features", "recorder", "replay",
           "robots", "schemas", "util", "viewer"]
