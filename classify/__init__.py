"""Classifiers and their honest evaluation, in subpackages by job:

* :mod:`~contactkit.classify.kinds`: the model kinds (what a kind is, the registry, the
  SVM kinds and their estimators, the network kinds, MiniRocket, the devices networks
  train on, and the fast online path a replay predicts with);
* :mod:`~contactkit.classify.modelfile`: the model file (skops or ONNX, metadata,
  checks on load);
* :mod:`~contactkit.classify.events`: contact events (the pipeline a replay and a live
  capture run, its listener, metrics, training and detector calibration);
* :mod:`~contactkit.classify.experiments`: the thesis experiments, augmentation and
  the grid search;

and, at the top, what they share: the sessions' features and grids (``data``,
``grids``), training, evaluation, prediction, class schemes and the options' names.

Modules moved into the subpackages keep their earlier names
(``contactkit.classify.registry``, ``...models``, ...): importing one gives the module
at its new place (:data:`MOVED`), so code and model files written before still work.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
from collections.abc import Callable
from types import ModuleType
from typing import Any

MOVED = {
    "kind": "kinds.kind", "registry": "kinds.registry", "inputs": "kinds.inputs",
    "svm_kinds": "kinds.svm", "models": "kinds.svm_estimators", "nn_kinds": "kinds.neural",
    "networks": "kinds.networks", "nn": "kinds.minirocket", "devices": "kinds.devices",
    "fast": "kinds.fast", "online_arrays": "kinds.online_arrays",
    "skops_format": "modelfile.skops_format", "skops_import": "modelfile.skops_import",
    "onnx_model": "modelfile.onnx_model", "event_listener": "events.listener",
    "event_metrics": "events.metrics", "event_training": "events.training",
    "calibrate": "events.calibrate", "augmentation": "experiments.augmentation",
    "gridsearch": "experiments.gridsearch",
}
"""Earlier module names under ``contactkit.classify`` and where each module is now."""


def names_of(package: str, main: str) -> Callable[[str], Any]:
    """Return the module ``__getattr__`` of ``package``, a module that became a package:
    it hands out the names of its main module ``main`` (imported on first use), so that
    ``from package import name`` works as before."""

    def forward(name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        try:
            return getattr(importlib.import_module(main), name)
        except AttributeError:
            raise AttributeError(f"module {package!r} has no attribute {name!r}") from None

    return forward


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports an earlier module name (:data:`MOVED`) as the module at its new place: one
    module object under both names, so its classes and functions are the same objects."""

    def find_spec(self, fullname: str, path: object = None, target: object = None
                  ) -> importlib.machinery.ModuleSpec | None:
        """Return a spec for an earlier name, None for any other module."""
        if fullname.rpartition(".")[0] != __name__ or fullname.rpartition(".")[2] not in MOVED:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        """Return the module at its new place (imported on first use)."""
        return importlib.import_module(f"{__name__}.{MOVED[spec.name.rpartition('.')[2]]}")

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the module ran when it was imported at its new place."""


__all__ = ["data", "evaluate", "events", "experiments", "grids", "kinds", "modelfile",
           "prediction", "schemes", "training"]
"""The public modules and subpackages, for the API reference (names only: importing the
package stays light)."""

if not any(isinstance(finder, _MovedModules) for finder in sys.meta_path):
    sys.meta_path.append(_MovedModules())
