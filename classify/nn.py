"""Neural classifiers on timeseries grids (thesis section 5.2), behind the
scikit-learn estimator interface: ``fit(X, y)``, ``predict``, ``predict_proba`` with
X of shape (sessions, channels, steps) from :mod:`contactkit.classify.grids`.

* :class:`CNNClassifier`: 2-D convolutions over the channels x time grid, max pooling
  in time, batch normalisation, leaky ReLU and dropout after each pooling and dense
  layer. Base network: convolutions of 32 and 64 kernels, one dense layer of 32.
  What is left of the time axis after pooling is averaged, so one network takes
  windows of any length (and exports to ONNX for any length).
  ``depth`` multiplies the number of layers, ``width`` the kernels and neurons (the
  thesis's grid: depth 1/2/4, width 0.5/1/2, dropout 0/0.1/0.25). Default: its
  choice, depth 4, width 2, dropout 0.02.
* :class:`LSTMClassifier`: LSTM layers of 32 and 16 units and a dense layer of 16,
  with the same multipliers; default depth 2, width 2, dropout 0.02.
* :class:`MiniRocketClassifier`: aeon's MiniRocket, a fast modern baseline.

The kinds are declared in :mod:`contactkit.classify.nn_kinds`.

Training (section 5.2.1, improved): the given data are split 70/15 into training
and validation (stratified; the remaining 15 % is the caller's test set, or the
held-out groups of the group protocol), Adam at 3e-3 halved when the validation
loss stalls for a quarter of the patience, early stopping on the validation loss
(patience 20 epochs), the best checkpoint restored. (The thesis's 1e-3 with
patience 10 stopped before the networks had fitted their training data.) Channels
are standardised with training statistics. Seeds fix initialisation, shuffling and
splits: same seed, same model on CPU. PyTorch is the ``nn`` extra: ``pip install 'contactkit[nn]'``.

The CNN and LSTM estimators and their devices (``--device auto|cpu|cuda``, what is
repeatable on a GPU) live in :mod:`contactkit.classify.networks`, which needs neither
the feature chain nor the model files.
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
