"""Scalar features of a windowed timeseries (thesis Table 3.4).

Each function takes an (N, k) array (N samples of k channels) and returns (k,)
values, or (k, n) for the FFT; units follow the input's unit u.

=============  ===================================================  ==========
name           definition                                           unit
=============  ===================================================  ==========
mean           (1/N) sum s_i                                        u
variance       (1/N) sum (s_i - mean)^2                             u^2
range          max s - min s                                        u
delta          s_N - s_1 (last minus first)                         u
skew           (1/N) sum (s_i - mean)^3 / sigma^3 (scipy.stats.skew,  1
               biased). The thesis prints the numerator without the
               cube; we use the standard definition.
energy         sum s_i^2                                            u^2
hjorth_mob     sqrt(var(ds) / var(s)), ds the first difference      1 / sample
hjorth_comp    mobility(ds) / mobility(s)                           1
fft            |FFT(s)[j]| for j = 0..k-1 (scipy.fft), k = 3        u
=============  ===================================================  ==========

Hjorth parameters are three lines of numpy: antropy implements the same formulas
but would add numba to the install for no gain. A constant signal has zero
variance; its skew and Hjorth parameters are defined as 0 rather than NaN, and so are
the Hjorth parameters of a window too short to difference (one or two samples).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

SCALARS = ("mean", "variance", "range", "delta", "skew", "energy", "hjorth_mob",
           "hjorth_comp", "fft")
DEFAULT_FFT_K = 3


def safe_ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """Return num / den elementwise, and 0 where den is not above 1e-300 (a constant
    signal's zero variance)."""
    out = np.zeros_like(num, dtype=float)
    ok = den > 1e-300
    out[ok] = num[ok] / den[ok]
    return out


def mean(x: np.ndarray) -> np.ndarray:
    """Mean of each channel."""
    return x.mean(axis=0)


def variance(x: np.ndarray) -> np.ndarray:
    """Population variance of each channel."""
    return x.var(axis=0)


def value_range(x: np.ndarray) -> np.ndarray:
    """Max minus min of each channel."""
    return x.max(axis=0) - x.min(axis=0)


def delta(x: np.ndarray) -> np.ndarray:
    """Last minus first value of each channel."""
    return x[-1] - x[0]


def skew(x: np.ndarray) -> np.ndarray:
    """Standard (biased) skewness of each channel; 0 for a constant channel."""
    sd = x.std(axis=0)
    centred = x - x.mean(axis=0)
    return safe_ratio((centred**3).mean(axis=0), sd**3)


def energy(x: np.ndarray) -> np.ndarray:
    """Sum of squares of each channel."""
    return np.einsum("ij,ij->j", x, x)


def _mobility(x: np.ndarray) -> np.ndarray:
    if len(x) < 2:  # no difference to take: defined as 0, like a constant signal
        return np.zeros(x.shape[1:])
    return np.sqrt(safe_ratio(np.diff(x, axis=0).var(axis=0), x.var(axis=0)))


def hjorth_mobility(x: np.ndarray) -> np.ndarray:
    """Hjorth mobility sqrt(var(diff x) / var(x)) of each channel."""
    return _mobility(x)


def hjorth_complexity(x: np.ndarray) -> np.ndarray:
    """Hjorth complexity mobility(diff x) / mobility(x) of each channel."""
    return hjorth_parameters(x)[1]


def hjorth_parameters(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return Hjorth mobility and complexity of each channel, from one pass of
    differences and variances (each is 0 where undefined, as above)."""
    zeros = np.zeros(x.shape[1:])
    if len(x) < 2:
        return zeros, zeros
    first = np.diff(x, axis=0)
    var_first = first.var(axis=0)
    mobility = np.sqrt(safe_ratio(var_first, x.var(axis=0)))
    if len(x) < 3:
        return mobility, zeros
    mobility_first = np.sqrt(safe_ratio(np.diff(first, axis=0).var(axis=0), var_first))
    return mobility, safe_ratio(mobility_first, mobility)


def fft_magnitudes(x: np.ndarray, k: int = DEFAULT_FFT_K) -> np.ndarray:
    """First ``k`` FFT magnitudes of each channel, shape (channels, k) (zero-padded when
    the window has fewer than k samples)."""
    import scipy.fft  # here, not at import: the command line lists SCALARS without scipy

    mags = np.abs(scipy.fft.fft(x, axis=0))[:k].T
    if mags.shape[1] < k:
        mags = np.pad(mags, ((0, 0), (0, k - mags.shape[1])))
    return mags


FUNCTIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "mean": mean, "variance": variance, "range": value_range, "delta": delta, "skew": skew,
    "energy": energy, "hjorth_mob": hjorth_mobility, "hjorth_comp": hjorth_complexity,
}


def scalar_blocks(x: np.ndarray, names: tuple[str, ...] | list[str],
                  fft_k: int = DEFAULT_FFT_K) -> list[np.ndarray]:
    """Return the requested scalar features of an (N, k) window as blocks of k values
    (one per channel), in the order of :func:`scalar_feature_names`: one block per
    name, ``fft_k`` for "fft". Channels never mix, so the k columns may as well be
    the channels of many windows of N samples side by side."""
    blocks: list[np.ndarray] = []
    hjorth = hjorth_parameters(x) if "hjorth_comp" in names else None  # shared by both
    for name in names:
        if name == "fft":
            mags = fft_magnitudes(x, fft_k)
            blocks += [mags[:, j] for j in range(fft_k)]
        elif hjorth is not None and name.startswith("hjorth"):
            blocks.append(hjorth[name == "hjorth_comp"])
        else:
            blocks.append(FUNCTIONS[name](x))
    return blocks


def scalar_feature_names(names: tuple[str, ...] | list[str], channel_names: list[str],
                         fft_k: int = DEFAULT_FFT_K) -> list[str]:
    """Return the names of the scalar features ``names`` of channels ``channel_names``,
    like ``range(tau_3)`` or ``fft2(r_1)`` (the third FFT magnitude)."""
    labels: list[str] = []
    for name in names:
        if name == "fft":
            for j in range(fft_k):
                labels += [f"fft{j}({c})" for c in channel_names]
        else:
            labels += [f"{name}({c})" for c in channel_names]
    return labels


def scalar_features(x: np.ndarray, names: tuple[str, ...] | list[str], channel_names: list[str],
                    fft_k: int = DEFAULT_FFT_K) -> tuple[np.ndarray, list[str]]:
    """Return (values, names) of the requested scalar features of an (N, k) window.

    Names read like ``range(tau_3)`` or ``fft2(r_1)`` (the third FFT magnitude).
    """
    return (np.concatenate(scalar_blocks(x, names, fft_k)),
            scalar_feature_names(names, channel_names, fft_k))
