"""The network kinds (``cnn``, ``lstm``, ``minirocket``): the estimators of
:mod:`contactkit.classify.kinds.networks` and :mod:`contactkit.classify.kinds.minirocket`
declared with
their parameters, input grids and file formats.

The CNN and LSTM share their parameters: ``epochs``, ``depth``, ``width``, ``dropout``,
``patience`` and ``device`` (see :mod:`contactkit.classify.kinds.minirocket` for what they size);
depth, width and dropout carry the thesis's grid, which ``classify gridsearch``
searches. MiniRocket takes its number of kernels. This module imports neither
scikit-learn nor PyTorch: estimators, the ONNX format and the device check import them
when called.
"""

from __future__ import annotations

from typing import Any

from contactkit.classify.kinds.devices import DEVICES, check_device, require_torch
from contactkit.classify.kinds.inputs import CNN_INPUT, GRIDS, LSTM_INPUT
from contactkit.classify.kinds.kind import ModelFormat, ModelKind, ModelOptions, lazy
from contactkit.classify.modelfile.skops_format import SKOPS
from contactkit.util.params import Choice, Interval, Param

NETWORK_PARAMS = (
    Param("epochs", int, 100, "Most training epochs (early stopping on a validation split).",
          constraints=(Interval(1, None),)),
    Param("depth", int, None, "Layer multiplier (thesis grid 1, 2, 4; default CNN 4, LSTM 2).",
          constraints=(Interval(1, None),), optional=True, grid=(1, 2, 4)),
    Param("width", float, 2.0, "Kernel and neuron multiplier (thesis grid 0.5, 1, 2).",
          constraints=(Interval(0, None, "neither"),), grid=(0.5, 1.0, 2.0)),
    Param("dropout", float, 0.02, "Dropout after each pooling and dense layer (thesis grid "
          "0, 0.1, 0.25).", constraints=(Interval(0, 1, "left"),), grid=(0.0, 0.1, 0.25)),
    Param("patience", int, 20, "Early stopping: epochs without a better validation loss "
          "before a training stops.", constraints=(Interval(1, None),)),
    Param("device", str, "cpu", "Where to train (auto: CUDA when PyTorch sees a GPU; a Dask "
          "worker uses its own GPU). Repeatable under --seed on the CPU.",
          constraints=(Choice(DEVICES),)),
)
"""The parameters of the CNN and the LSTM (the keywords of their estimators)."""
ONNX = ModelFormat("onnx", ".onnx",
                   lazy("contactkit.classify.modelfile.onnx_model:save_onnx_model"),
                   lazy("contactkit.classify.modelfile.onnx_model:load_onnx_model"))
"""Networks exported as ONNX graphs (:mod:`contactkit.classify.modelfile.onnx_model`)."""


def _require_torch() -> None:
    """Raise InputError when PyTorch (the nn extra) is missing."""
    require_torch()


def _require_aeon() -> None:
    """Raise InputError when aeon (the nn extra) is missing."""
    from contactkit.classify.kinds.minirocket import require_aeon

    require_aeon()


def _check_device(params: dict[str, Any]) -> None:
    """Raise InputError for a device this process cannot train on (the grid search
    checks a cluster's trials as on the CPU: its GPUs are the workers' business)."""
    check_device(params["device"])


def _cnn(options: ModelOptions, channels: list[str]) -> Any:
    """Return the thesis's CNN classifier."""
    from contactkit.classify.kinds.networks import CNNClassifier

    return CNNClassifier(seed=options.seed, **options.params)


def _lstm(options: ModelOptions, channels: list[str]) -> Any:
    """Return the thesis's LSTM classifier."""
    from contactkit.classify.kinds.networks import LSTMClassifier

    return LSTMClassifier(seed=options.seed, **options.params)


def _minirocket(options: ModelOptions, channels: list[str]) -> Any:
    """Return aeon's MiniRocket behind contactkit's estimator interface."""
    from contactkit.classify.kinds.minirocket import MiniRocketClassifier

    return MiniRocketClassifier(seed=options.seed, **options.params)


CNN = ModelKind("cnn", "the thesis's CNN on window grids (nn extra; .onnx)", GRIDS, _cnn,
                ONNX, params=NETWORK_PARAMS, default_timeseries=CNN_INPUT,
                default_window="planned", check=_check_device, requires=_require_torch,
                parallel_fits=True)
LSTM = ModelKind("lstm", "the thesis's LSTM on window grids (nn extra; .onnx)", GRIDS, _lstm,
                 ONNX, params=NETWORK_PARAMS, default_timeseries=LSTM_INPUT,
                 default_window="planned", check=_check_device, requires=_require_torch,
                 parallel_fits=True)
MINIROCKET = ModelKind(
    "minirocket", "MiniRocket on window grids (nn extra)", GRIDS, _minirocket, SKOPS,
    params=(Param("n_kernels", int, 10_000, "MiniRocket: random convolutional kernels.",
                  constraints=(Interval(84, None),)),),
    default_timeseries=CNN_INPUT, default_window="planned", requires=_require_aeon,
    parallel_fits=True,
    trusted_types=("aeon.classification.convolution_based._minirocket.MiniRocketClassifier",
                   "aeon.transformations.collection.convolution_based._minirocket.MiniRocket",
                   "contactkit.classify.kinds.minirocket.MiniRocketClassifier",
                   # its name in model files written before classify/ had subpackages
                   "contactkit.classify.nn.MiniRocketClassifier"))
