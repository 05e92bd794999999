"""The thesis's CNN and LSTM (section 5.2) as scikit-learn classifiers, and where
they train: ``fit(X, y)``, ``predict``, ``predict_proba`` with X of shape
(sessions, channels, steps).

This module needs only numpy, scikit-learn and PyTorch (not the feature chain), so a
GPU machine can train and time the networks without the rest of contactkit's
dependencies (``benchmarks/bench_gpu.py``). The kinds are declared in
:mod:`contactkit.classify.kinds.neural`.

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

Training (section 5.2.1, improved): the given data are split 70/15 into training
and validation (stratified; the remaining 15 % is the caller's test set, or the
held-out groups of the group protocol), Adam at 3e-3 halved when the validation
loss stalls for a quarter of the patience, early stopping on the validation loss
(patience 20 epochs), the best checkpoint restored. (The thesis's 1e-3 with
patience 10 stopped before the networks had fitted their training data.) Channels
are standardised with training statistics. Seeds fix initialisation, shuffling and
splits: same seed, same model on CPU. PyTorch is the ``nn``
extra: ``pip install 'contactkit[nn]'``.

Devices (:mod:`contactkit.classify.kinds.devices`): ``device="auto"`` trains on CUDA when
PyTorch sees a GPU, else on the CPU; ``"cuda"`` insists on a GPU (a one-line InputError
without one), ``"cpu"`` (the default) never uses one. On a machine with several GPUs, a
Dask worker of rank k trains on GPU k modulo their number
(:func:`contactkit.util.parallel.dask_worker_rank`); any other process on the first
visible GPU, so on a cluster start one single-threaded worker per GPU with
``CUDA_VISIBLE_DEVICES`` set. A trained network is moved back to
the CPU, so predictions, pickled models and ONNX export do not depend on where it was
trained.

What is repeatable: on the CPU the same seed gives the same weights, bit for bit, on
any number of workers. On a GPU the same seed gives the same initialisation,
shuffling and validation split, cuBLAS and cuDNN run in their deterministic modes
where they have one, but some CUDA kernels (the LSTM's among them) may still sum in
another order from run to run, so weights and the epoch early stopping picks can
differ slightly between runs and from the CPU: scores agree within their confidence
intervals, not to the last digit.
"""

from __future__ import annotations

import copy
import math
import os

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.model_selection import train_test_split

from contactkit.classify.kinds.devices import require_torch, resolve_device


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

    class CNN(nn.Module):  # type: ignore[name-defined]  # torch is imported lazily
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

    class LSTM(nn.Module):  # type: ignore[name-defined]  # torch is imported lazily
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
                 learning_rate: float = 3e-3, seed: int = 0, device: str = "cpu") -> None:
        self.depth = depth
        self.width = width
        self.dropout = dropout
        self.epochs = epochs
        self.patience = patience
        self.batch_size = batch_size
        self.learning_rate = learning_rate
        self.seed = seed
        self.device = device

    def _depth(self) -> int:
        return self.default_depth if self.depth is None else self.depth

    def _module(self, torch, channels: int, steps: int, classes: int):
        raise NotImplementedError

    def fit(self, X: np.ndarray, y: np.ndarray) -> _TorchClassifier:
        """Train with early stopping on a stratified 15/85 validation split, on
        ``device``; return self, with the trained network on the CPU."""
        torch = require_torch()
        device = resolve_device(torch, self.device)
        if device.type == "cuda":
            os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
            torch.backends.cudnn.deterministic = True
            torch.backends.cudnn.benchmark = False
        torch.manual_seed(self.seed)
        torch.use_deterministic_algorithms(True, warn_only=device.type == "cuda")
        torch.set_num_threads(1)
        rng = np.random.default_rng(self.seed)
        self.classes_, codes = np.unique(y, return_inverse=True)
        X = np.asarray(X, dtype=np.float32)
        self.mean_ = X.mean(axis=(0, 2), keepdims=True)
        self.std_ = X.std(axis=(0, 2), keepdims=True) + 1e-6
        Xn = (X - self.mean_) / self.std_
        validation = math.ceil(len(codes) * 15 / 85)  # as train_test_split rounds it
        stratify = codes if np.bincount(codes).min() >= 2 and \
            validation >= len(self.classes_) else None
        tr, va = train_test_split(np.arange(len(codes)), test_size=15 / 85,
                                  random_state=self.seed, stratify=stratify)
        self.model_ = self._module(torch, X.shape[1], X.shape[2],
                                   len(self.classes_)).to(device)
        optimiser = torch.optim.Adam(self.model_.parameters(), lr=self.learning_rate)
        scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(
            optimiser, factor=0.5, patience=max(1, self.patience // 4))
        loss_fn = torch.nn.CrossEntropyLoss()
        xt = torch.from_numpy(Xn).to(device)
        yt = torch.from_numpy(codes.astype(np.int64)).to(device)
        va = torch.from_numpy(va).to(device)
        best, best_state, waited = np.inf, None, 0
        self.history_ = []
        for _ in range(self.epochs):
            self.model_.train()
            order = rng.permutation(tr)
            for start in range(0, len(order), self.batch_size):
                batch = order[start:start + self.batch_size]
                if len(batch) < 2:
                    continue
                batch = torch.from_numpy(batch).to(device)
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
        self.model_.to("cpu").eval()
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

        class WithScaling(torch.nn.Module):  # type: ignore[name-defined]  # lazy torch
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
    """The thesis's CNN (see the module's docstring); ``depth`` None is its choice, 4."""

    default_depth = 4

    def _module(self, torch, channels: int, steps: int, classes: int):
        return _cnn_module(torch, channels, steps, classes, self._depth(), self.width,
                           self.dropout)


class LSTMClassifier(_TorchClassifier):
    """The thesis's LSTM (see the module's docstring); ``depth`` None is its choice, 2."""

    default_depth = 2

    def _module(self, torch, channels: int, steps: int, classes: int):
        return _lstm_module(torch, channels, classes, self._depth(), self.width, self.dropout)
