"""Where a network trains: the device names and their checks, without importing PyTorch
until a check runs (see :mod:`contactkit.classify.kinds.networks` for what is repeatable where).
"""

from __future__ import annotations

from contactkit.errors import DependencyMissing, InputError
from contactkit.util.parallel import dask_worker_rank

DEVICES = ("auto", "cpu", "cuda")
"""auto (CUDA when PyTorch sees a GPU), cpu or cuda."""


def require_torch():
    """Return the torch module, or raise a one-line DependencyMissing naming the extra."""
    try:
        import torch
    except ImportError as err:
        raise DependencyMissing("neural networks need PyTorch: pip install 'contactkit[nn]' "
                                "(torch==2.13.0, CPU)") from err
    return torch


def resolve_device(torch, device: str):
    """Return the ``torch.device`` to train on for ``auto``, ``cpu`` or ``cuda``: a
    Dask worker of rank k gets GPU k modulo the number of GPUs, any other process the
    first one.

    Raises InputError for ``cuda`` when PyTorch sees no GPU, or for an unknown name.
    """
    if device not in DEVICES:
        raise InputError(f"unknown device {device!r} (expected one of {', '.join(DEVICES)})")
    if device == "cpu" or (device == "auto" and not torch.cuda.is_available()):
        return torch.device("cpu")
    if not torch.cuda.is_available():
        raise InputError("device cuda asked for, but PyTorch sees no CUDA GPU")
    return torch.device("cuda", (dask_worker_rank() or 0) % torch.cuda.device_count())


def check_device(device: str) -> None:
    """Raise InputError now for an unknown device, or for ``cuda`` where PyTorch (or
    the ``nn`` extra) is missing or sees no GPU; return None otherwise."""
    resolve_device(require_torch(), device)
