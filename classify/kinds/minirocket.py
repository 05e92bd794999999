"""MiniRocket (aeon's), a fast modern baseline on timeseries grids, behind the
scikit-learn estimator interface: ``fit(X, y)``, ``predict``, ``predict_proba`` with X of
shape (sessions, channels, steps) from :mod:`contactkit.classify.grids`. aeon is part of
the ``nn`` extra: ``pip install 'contactkit[nn]'``. The kind is declared in
:mod:`contactkit.classify.kinds.neural`; the CNN and the LSTM are in
:mod:`contactkit.classify.kinds.networks`.
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin

from contactkit.errors import DependencyMissing


class MiniRocketClassifier(ClassifierMixin, BaseEstimator):
    """aeon's MiniRocket (random convolutional kernels + ridge classifier), with
    probabilities from a softmax of the ridge scores."""

    def __init__(self, n_kernels: int = 10_000, seed: int = 0) -> None:
        self.n_kernels = n_kernels
        self.seed = seed

    def fit(self, X: np.ndarray, y: np.ndarray) -> MiniRocketClassifier:
        """Fit MiniRocket on (sessions, channels, steps) grids."""
        try:
            from aeon.classification.convolution_based import MiniRocketClassifier as Rocket
        except ImportError as err:
            raise DependencyMissing("MiniRocket needs aeon: pip install 'contactkit[nn]'"
                                    ) from err
        self.model_ = Rocket(n_kernels=self.n_kernels, random_state=self.seed)
        self.model_.fit(np.asarray(X, dtype=np.float64), y)
        self.classes_ = self.model_.classes_
        return self

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Return class probabilities."""
        return self.model_.predict_proba(np.asarray(X, dtype=np.float64))

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Return the predicted class."""
        return self.model_.predict(np.asarray(X, dtype=np.float64))


def require_aeon() -> None:
    """Raise a one-line DependencyMissing naming the extra when aeon is missing."""
    try:
        import aeon  # noqa: F401
    except ImportError as err:
        raise DependencyMissing("MiniRocket needs aeon: pip install 'contactkit[nn]'") from err
