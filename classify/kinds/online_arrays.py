"""A compiled classifier (:mod:`contactkit.classify.kinds.fast`) as members of a model file.

A model file of an SVM kind carries, beside its skops estimator, the arrays of the
same model compiled (:class:`contactkit.classify.kinds.fast.CompiledSVM`, or a
:class:`~contactkit.classify.kinds.fast.CompiledEnsemble` of them): one ``.npy`` member per
array (little-endian float64, no pickle) under a prefix such as ``online/0/``, and a
document in ``contactkit.json`` that lists the parts and their feature columns. The
file's digest covers them like every other member. A replay, ``recorder events`` and
other online users load these and classify without importing scikit-learn or skops;
the arrays are checked (dtype, shapes, finiteness, the model's feature count) as they
are read, and a file that lacks them loads its estimator instead.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import numpy as np

from contactkit.classify.kinds.fast import SVM_ARRAYS, Compiled, CompiledEnsemble, CompiledSVM
from contactkit.errors import InputError

FORM = "svm-mean/1"
"""The document's form: the mean of compiled SVMs' probabilities, each on its columns
(all columns where ``columns`` is null)."""
DTYPE = np.dtype("<f8")


def npy_bytes(array: np.ndarray) -> bytes:
    """Return ``array`` as the bytes of a .npy file (little-endian float64, C order)."""
    out = io.BytesIO()
    np.lib.format.write_array(out, np.asarray(array, dtype=DTYPE, order="C"),
                              allow_pickle=False)
    return out.getvalue()


def read_npy(data: bytes) -> np.ndarray:
    """Return the float64 array of .npy bytes; ValueError unless they hold exactly one
    array of that type (its header's shape matches the data, nothing is allocated
    beyond the bytes given)."""
    fp = io.BytesIO(data)
    version = np.lib.format.read_magic(fp)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(fp)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(fp)
    else:
        raise ValueError(f".npy version {version} is not supported")
    if dtype != DTYPE or fortran:
        raise ValueError(f"array is {dtype}{' (Fortran order)' if fortran else ''}, "
                         f"expected {DTYPE} in C order")
    count = int(np.prod(shape, dtype=np.int64)) if shape else 1
    if count * DTYPE.itemsize != len(data) - fp.tell():
        raise ValueError(f"array of shape {shape} does not match its "
                         f"{len(data) - fp.tell()} bytes")
    return np.frombuffer(data, DTYPE, count, fp.tell()).reshape(shape).copy()


def online_members(compiled: Compiled, prefix: str) -> tuple[dict, dict[str, bytes]]:
    """Return the document (for ``contactkit.json``) and the members (name -> .npy bytes)
    that store ``compiled`` under ``prefix``."""
    parts = ([(None, compiled)] if isinstance(compiled, CompiledSVM) else
             [(cols.tolist(), svm) for cols, svm in compiled.members])
    doc: dict[str, Any] = {"form": FORM, "parts": []}
    members: dict[str, bytes] = {}
    for i, (columns, svm) in enumerate(parts):
        doc["parts"].append({"columns": columns, "prefix": f"{prefix}{i}/"})
        members |= {f"{prefix}{i}/{name}.npy": npy_bytes(value)
                    for name, value in svm.arrays().items()}
    return doc, members


def read_online(doc: object, member: Callable[[str], bytes], n_features: int,
                n_classes: int, path: str | Path) -> Compiled:
    """Return the compiled classifier ``doc`` describes, reading its arrays with
    ``member(name)``; ``n_features`` is the width of the rows it classifies and
    ``n_classes`` the number of classes it must tell apart. Raises InputError naming
    ``path`` for a document or array that does not fit."""
    try:
        parts = _parts(doc, n_features)
        members = []
        for columns, prefix in parts:
            svm = CompiledSVM({name: read_npy(member(f"{prefix}{name}.npy"))
                               for name in SVM_ARRAYS})
            width = n_features if columns is None else len(columns)
            if svm.n_features != width:
                raise ValueError(f"part {prefix!r} takes {svm.n_features} features, "
                                 f"expected {width}")
            if svm.n != n_classes:
                raise ValueError(f"part {prefix!r} tells {svm.n} classes apart, the model "
                                 f"file names {n_classes}")
            members.append((columns, svm))
    except (ValueError, KeyError) as err:
        raise InputError(f"invalid compiled classifier in the model file ({err})",
                         path) from err
    if len(members) == 1 and members[0][0] is None:
        return members[0][1]
    if any(columns is None for columns, _ in members):
        raise InputError("invalid compiled classifier in the model file (a part of an "
                         "ensemble without its columns)", path)
    # every part has its columns (checked above)
    return CompiledEnsemble(cast("list[tuple[np.ndarray, CompiledSVM]]", members))


def _parts(doc: object, n_features: int) -> list[tuple[list[int] | None, str]]:
    """Return (columns or None, member prefix) of each part of an online document, or
    raise ValueError."""
    if not isinstance(doc, dict) or doc.get("form") != FORM:
        raise ValueError(f"unknown form, expected {FORM!r}")
    parts = doc.get("parts")
    if not isinstance(parts, list) or not parts:
        raise ValueError("no parts")
    out = []
    for part in parts:
        if not isinstance(part, dict) or not isinstance(part.get("prefix"), str):
            raise ValueError("a part without a member prefix")
        columns = part.get("columns")
        if columns is not None and not (
                isinstance(columns, list) and columns
                and all(type(c) is int and 0 <= c < n_features for c in columns)):
            raise ValueError(f"part {part['prefix'][:40]!r} has columns outside "
                             f"0..{n_features - 1}")
        out.append((columns, part["prefix"]))
    return out
