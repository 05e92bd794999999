"""Small dense linear algebra vectorised over many samples."""

from __future__ import annotations

import numpy as np


def solve_spd(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve a_k x_k = b_k for symmetric positive-definite a_k, vectorised over k.

    ``a`` is (N, n, n), ``b`` is (N, n); returns x, shape (N, n). A Cholesky
    factorisation written column by column over all N at once: for small n (6 for
    a wrench) this is far cheaper than one LAPACK call per sample.
    """
    n = a.shape[-1]
    low = np.zeros_like(a)
    for j in range(n):
        diag = a[:, j, j] - np.einsum("ki,ki->k", low[:, j, :j], low[:, j, :j])
        low[:, j, j] = np.sqrt(diag)
        if j + 1 < n:
            rest = a[:, j + 1:, j] - np.einsum("kri,ki->kr", low[:, j + 1:, :j], low[:, j, :j])
            low[:, j + 1:, j] = rest / low[:, j, j, None]
    y = np.empty_like(b)
    for i in range(n):
        y[:, i] = (b[:, i] - np.einsum("ki,ki->k", low[:, i, :i], y[:, :i])) / low[:, i, i]
    x = np.empty_like(b)
    for i in reversed(range(n)):
        x[:, i] = (y[:, i] - np.einsum("ki,ki->k", low[:, i + 1:, i], x[:, i + 1:])) / low[:, i, i]
    return x
