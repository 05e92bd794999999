"""A lab's own model kind, as one module: the estimator, its parameter and the kind.

Registered in-process by ``tests/classify/test_model_kinds.py`` (``registry.register``) and, for
the command line, through an entry point of the group ``contactkit.models``.
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin

from contactkit.classify.kinds.inputs import FEATURES
from contactkit.classify.kinds.kind import ModelKind, ModelOptions
from contactkit.classify.modelfile.skops_format import SKOPS
from contactkit.util.params import Interval, Param

SHRINK = Param("shrink", float, 0.0, "Nearest mean: pull each class mean this far towards "
               "the mean of all classes.", constraints=(Interval(0, 1),))


class NearestMean(ClassifierMixin, BaseEstimator):
    """Class probabilities from the softmax of minus the distance to each class mean
    (features scaled to unit variance; means shrunk by ``shrink`` towards their mean)."""

    def __init__(self, shrink: float = 0.0) -> None:
        self.shrink = shrink

    def fit(self, X: np.ndarray, y: np.ndarray) -> NearestMean:
        """Store the scaled class means; return self."""
        self.classes_ = np.unique(y)
        self.scale_ = X.std(axis=0) + 1e-9
        means = np.stack([X[y == c].mean(axis=0) for c in self.classes_]) / self.scale_
        self.means_ = means + self.shrink * (means.mean(axis=0) - means)
        return self

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Return the softmax of minus the distances to the class means."""
        d = np.linalg.norm(X[:, None, :] / self.scale_ - self.means_[None], axis=2)
        e = np.exp(-(d - d.min(axis=1, keepdims=True)))
        return e / e.sum(axis=1, keepdims=True)

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Return the nearest class."""
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]


def _nearest_mean(options: ModelOptions, feature_names: list[str]) -> NearestMean:
    return NearestMean(**options.params)


TINY = ModelKind("nearest-mean", "distance to class means", FEATURES, _nearest_mean, SKOPS,
                 params=(SHRINK,), default_window="planned",
                 trusted_types=(f"{NearestMean.__module__}.{NearestMean.__qualname__}",))
