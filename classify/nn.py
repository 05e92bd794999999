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

The registered kinds are :data:`CNN`, :data:`LSTM` and :data:`MINIROCKET`.

Training (section 5.2.1, improved): the given data are split 70/15 into training
and validation (stratified; the remaining 15 % is the caller's test set, or the
held-out groups of the group protocol), Adam at 3e-3 halved when the validation
loss stalls for a quarter of the patience, early stopping on the validation loss
(patience 20 epochs), the best checkpoint restored. (The thesis's 1e-3 with
patience 10 stopped before the networks had fitted their training data.) Channels
are standardised with training statistics. Seeds fix initialisation, shuffling and
splits: same seed, same model on CPU. PyTorch is the ``nn`` extra: ``pip install 'contactkit[nn]'``.
"""

from __future__ import annotations

import copy

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.model_selection import train_test_split

from contactkit.classify.grids import CNN_INPUT, GRIDS, LSTM_INPUT
from contactkit.classify.kind import ModelKind, ModelOptions
from contactkit.classify.modelfile import SKOPS
from contactkit.classify.onnx_model import ONNX
from contactkit.schemas import InputError


def require_torch():
    """Return the torch module, or raise a one-line InputError naming the extra."""
    try:
        import torch
    except ImportError as err:
        raise InputError("neural networks need PyTorch: pip install 'contactkit[nn]' "
                         "(torch==2.13.0, CPU)") from err
    return torch


def _cnn_module(torch, channels: int, steps: int, classes: int, depth: int, width: float,
                dropout: float):
    nn = torch.nn
    base = [32, 64]
    filters = [max(4, round(f * width)) for f in base for _ in range(depth)]
    layers, in_ch, t = [], 1, steps
    for f in filters:
        pool = 2 if t >= 8 else 1
        layers += [nn.Conv2d(in_ch, f, kernel_size=(3, 5), padding=(1, 2)),
                   nn.MaxPool2d((1, pool)), nn.BatchNorm2d(f), nn.LeakyReLU(0.01),
                   nn.Dropout(dropout)]
        in_ch, t = f, t // pool
    dense = max(4, round(32 * width))
    head = nn.Sequential(nn.Linear(in_ch * channels, dense), nn.BatchNorm1d(dense),
                         nn.LeakyReLU(0.01), nn.Dropout(dropout), nn.Linear(dense, classes))

    class CNN(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.body = nn.Sequential(*layers)
            self.head = head

        def forward(self, x):
            features = self.body(x.unsqueeze(1)).mean(dim=3)
            return self.head(features.flatten(1))

    return CNN()


def _lstm_module(torch, channels: int, classes: int, depth: int, width: float,
                 dropout: float):
    nn = torch.nn
    sizes = [max(4, round(u * width)) for u in (32, 16) for _ in range(depth)]
    dense = max(4, round(16 * width))

    class LSTM(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.lstms = nn.ModuleList()
            self.norms = nn.ModuleList()
            size_in = channels
            for size in sizes:
                self.lstms.append(nn.LSTM(size_in, size, batch_first=True))
                self.norms.append(nn.BatchNorm1d(size))
                size_in = size
            self.drop = nn.Dropout(dropout)
            self.act = nn.LeakyReLU(0.01)
            self.head = nn.Sequential(nn.Linear(size_in, dense), nn.BatchNorm1d(dense),
                                      nn.LeakyReLU(0.01), nn.Dropout(dropout),
                                      nn.Linear(dense, classes))

        def forward(self, x):
            h = x.transpose(1, 2)
            for lstm, norm in zip(self.lstms, self.norms, strict=True):
                h, _ = lstm(h)
                h = self.drop(self.act(norm(h.transpose(1, 2)).transpose(1, 2)))
            return self.head(h[:, -1])

    return LSTM()


class _TorchClassifier(ClassifierMixin, BaseEstimator):
    """Shared parameters and training loop of the CNN and the LSTM."""

    default_depth = 1

    def __init__(self, depth: int | None = None, width: float = 2.0, dropout: float = 0.02,
                 epochs: int = 100, patience: int = 20, batch_size: int = 32,
                 learning_rate: float = 3e-3, seed: int = 0) -> None:
        self.depth = depth
        self.width = width
        self.dropout = dropout
        self.epochs = epochs
        self.patience = patience
        self.batch_size = batch_size
        self.learning_rate = learning_rate
        self.seed = seed

    def _depth(self) -> int:
        return self.default_depth if self.depth is None else self.depth

    def _module(self, torch, channels: int, steps: int, classes: int):
        raise NotImplementedError

    def fit(self, X: np.ndarray, y: np.ndarray) -> _TorchClassifier:
        """Train with early stopping on a stratified 15/85 validation split."""
        torch = require_torch()
        torch.manual_seed(self.seed)
        torch.use_deterministic_algorithms(True)
        torch.set_num_threads(1)
        rng = np.random.default_rng(self.seed)
        self.classes_, codes = np.unique(y, return_inverse=True)
        X = np.asarray(X, dtype=np.float32)
        self.mean_ = X.mean(axis=(0, 2), keepdims=True)
        self.std_ = X.std(axis=(0, 2), keepdims=True) + 1e-6
        Xn = (X - self.mean_) / self.std_
        stratify = codes if np.bincount(codes).min() >= 2 else None
        tr, va = train_test_split(np.arange(len(codes)), test_size=15 / 85,
                                  random_state=self.seed, stratify=stratify)
        self.model_ = self._module(torch, X.shape[1], X.shape[2], len(self.classes_))
        optimiser = torch.optim.Adam(self.model_.parameters(), lr=self.learning_rate)
        scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(
            optimiser, factor=0.5, patience=max(1, self.patience // 4))
        loss_fn = torch.nn.CrossEntropyLoss()
        xt, yt = torch.from_numpy(Xn), torch.from_numpy(codes.astype(np.int64))
        best, best_state, waited = np.inf, None, 0
        self.history_ = []
        for _ in range(self.epochs):
            self.model_.train()
            order = rng.permutation(tr)
            for start in range(0, len(order), self.batch_size):
                batch = order[start:start + self.batch_size]
                if len(batch) < 2:
                    continue
                optimiser.zero_grad()
                loss = loss_fn(self.model_(xt[batch]), yt[batch])
                loss.backward()
                optimiser.step()
            self.model_.eval()
            with torch.no_grad():
                val = float(loss_fn(self.model_(xt[va]), yt[va]))
            self.history_.append(val)
            scheduler.step(val)
            if val < best - 1e-6:
                best, best_state, waited = val, copy.deepcopy(self.model_.state_dict()), 0
            else:
                waited += 1
                if waited >= self.patience:
                    break
        self.model_.load_state_dict(best_state)
        self.model_.eval()
        self.n_epochs_ = len(self.history_)
        return self

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Return class probabilities (softmax of the network's logits)."""
        torch = require_torch()
        Xn = ((np.asarray(X, dtype=np.float32) - self.mean_) / self.std_).astype(np.float32)
        with torch.no_grad():
            return torch.softmax(self.model_(torch.from_numpy(Xn)), dim=1).numpy()

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Return the most probable class."""
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]

    def export_onnx(self, path, channels: int, steps: int) -> None:
        """Write the trained network, standardisation and softmax included, as ONNX
        (input ``grid`` float32 (batch, channels, steps), output ``probabilities``)."""
        torch = require_torch()

        class WithScaling(torch.nn.Module):
            def __init__(self, net, mean, std) -> None:
                super().__init__()
                self.net = net
                self.register_buffer("mean", torch.from_numpy(mean))
                self.register_buffer("std", torch.from_numpy(std))

            def forward(self, x):
                return torch.softmax(self.net((x - self.mean) / self.std), dim=1)

        wrapped = WithScaling(self.model_, self.mean_, self.std_).eval()
        dummy = torch.zeros((1, channels, steps), dtype=torch.float32)
        with torch.no_grad():
            torch.onnx.export(wrapped, (dummy,), str(path), input_names=["grid"],
                              output_names=["probabilities"], opset_version=17,
                              dynamic_axes={"grid": {0: "batch"},
                                            "probabilities": {0: "batch"}}, dynamo=False)


class CNNClassifier(_TorchClassifier):
    """The thesis's CNN (see the module docstring); ``depth`` None is its choice, 4."""

    default_depth = 4

    def _module(self, torch, channels: int, steps: int, classes: int):
        return _cnn_module(torch, channels, steps, classes, self._depth(), self.width,
                           self.dropout)


class LSTMClassifier(_TorchClassifier):
    """The thesis's LSTM (see the module docstring); ``depth`` None is its choice, 2."""

    default_depth = 2

    def _module(self, torch, channels: int, steps: int, classes: int):
        return _lstm_module(torch, channels, classes, self._depth(), self.width, self.dropout)


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
            raise InputError("MiniRocket needs aeon: pip install 'contactkit[nn]'") from err
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


def _require_aeon() -> None:
    try:
        import aeon  # noqa: F401
    except ImportError as err:
        raise InputError("MiniRocket needs aeon: pip install 'contactkit[nn]'") from err


def _check_epochs(options: ModelOptions) -> None:
    if options.epochs < 1:
        raise InputError(f"epochs must be at least 1, got {options.epochs}")


def _check_network(options: ModelOptions) -> None:
    _check_epochs(options)
    if options.depth is not None and options.depth < 1:
        raise InputError(f"depth must be at least 1, got {options.depth}")
    if options.width <= 0:
        raise InputError(f"width must be positive, got {options.width}")
    if not 0 <= options.dropout < 1:
        raise InputError(f"dropout must be in [0, 1), got {options.dropout}")


def _torch_params(options: ModelOptions) -> dict:
    return {"seed": options.seed, "epochs": options.epochs, "depth": options.depth,
            "width": options.width, "dropout": options.dropout}


def _cnn(options: ModelOptions, channels: list[str]) -> CNNClassifier:
    return CNNClassifier(**_torch_params(options))


def _lstm(options: ModelOptions, channels: list[str]) -> LSTMClassifier:
    return LSTMClassifier(**_torch_params(options))


def _minirocket(options: ModelOptions, channels: list[str]) -> MiniRocketClassifier:
    return MiniRocketClassifier(seed=options.seed)


def _require_torch() -> None:
    require_torch()


CNN = ModelKind("cnn", "the thesis's CNN on window grids (nn extra; .onnx)", GRIDS, _cnn,
                ONNX, default_timeseries=CNN_INPUT, default_window="planned",
                check=_check_network, requires=_require_torch, parallel_fits=True)
LSTM = ModelKind("lstm", "the thesis's LSTM on window grids (nn extra; .onnx)", GRIDS, _lstm,
                 ONNX, default_timeseries=LSTM_INPUT, default_window="planned",
                 check=_check_network, requires=_require_torch, parallel_fits=True)
MINIROCKET = ModelKind(
    "minirocket", "MiniRocket on window grids (nn extra)", GRIDS, _minirocket, SKOPS,
    default_timeseries=CNN_INPUT, default_window="planned", check=_check_epochs,
    requires=_require_aeon, parallel_fits=True,
    trusted_types=("aeon.classification.convolution_based._minirocket.MiniRocketClassifier",
                   "aeon.transformations.collection.convolution_based._minirocket.MiniRocket",
                   "contactkit.classify.nn.MiniRocketClassifier"))
