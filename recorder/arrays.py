"""Plain numeric arrays as labs export them: text, CSV or .npy.

Text files hold one number per line (7 consecutive lines per sample for joint
arrays) or 7 numbers per line separated by spaces, tabs or commas. ``.npy`` files
hold an (N,) or (N, 7) array.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from contactkit.schemas import N_JOINTS, InputError


def load_array(path: str | Path, width: int) -> np.ndarray:
    """Load ``path`` as an (N, width) float64 array (``width`` 1 gives shape (N,)).

    Raises InputError naming the file when it cannot be read, holds non-numbers or
    has a length that is not a multiple of ``width``.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    try:
        if path.suffix == ".npy":
            raw = np.load(path, allow_pickle=False)
        else:
            text = path.read_text().replace(",", " ").replace(";", " ")
            rows = [line.split() for line in text.splitlines() if line.strip()
                    and not line.lstrip().startswith("#")]
            lengths = {len(r) for r in rows}
            if len(lengths) > 1:
                raise InputError(f"lines have different numbers of values {sorted(lengths)}",
                                 path)
            raw = np.array(rows, dtype=float)
        raw = np.asarray(raw, dtype=float)
    except (ValueError, TypeError, OSError, EOFError) as err:
        raise InputError(f"not a numeric array ({type(err).__name__}: {str(err)[:80]})",
                         path) from err
    if raw.ndim not in (1, 2):
        raise InputError(f"expected a table of numbers, found {raw.ndim} dimensions", path)
    if raw.ndim == 2 and raw.shape[1] == 1:
        raw = raw[:, 0]
    if width == 1:
        if raw.ndim != 1:
            raise InputError(f"expected one value per line, found {raw.shape[1]}", path)
        return raw
    if raw.ndim == 1:
        if raw.size % width:
            raise InputError(f"{raw.size} values is not a multiple of {width} joints", path)
        return raw.reshape(-1, width)
    if raw.shape[1] != width:
        raise InputError(f"wrong joint count: {raw.shape[1]} values per line, expected "
                         f"{width}", path)
    return raw


def load_joint_arrays(t_path: str | Path, q_path: str | Path, dq_path: str | Path,
                      tau_path: str | Path) -> dict[str, np.ndarray]:
    """Load time [s], q [rad], dq [rad/s] and tau [Nm] files; check their lengths agree.

    Returns a dict with ``t`` (N,) and ``q``, ``dq``, ``tau`` (N, 7).
    """
    arrays = {"t": load_array(t_path, 1), "q": load_array(q_path, N_JOINTS),
              "dq": load_array(dq_path, N_JOINTS), "tau": load_array(tau_path, N_JOINTS)}
    paths = {"t": t_path, "q": q_path, "dq": dq_path, "tau": tau_path}
    n = len(arrays["t"])
    for name, values in arrays.items():
        if len(values) != n:
            raise InputError(f"{len(values)} samples, but the time file has {n}", paths[name])
    return arrays
