"""Experiments: the thesis's (:mod:`.thesis`), data augmentation (:mod:`.augmentation`)
and the grid search over model settings (:mod:`.gridsearch`).

The names of :mod:`contactkit.classify.experiments.thesis` can also be imported from
here (``from contactkit.classify.experiments import feature_identification``), as they
were before this package had modules of its own; nothing is imported until one is asked for.
"""

from __future__ import annotations

from contactkit.classify import names_of

__all__ = ["augmentation", "gridsearch", "thesis"]
"""The public modules, for the API reference."""
__getattr__ = names_of(__name__, "contactkit.classify.experiments.thesis")
