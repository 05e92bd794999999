"""The skops model file format: a skops archive (a zip of JSON and .npy members, never
pickle) with one extra member, ``contactkit.json``, and a SHA-256 over every member.

Reading (1) checks the archive's sizes from its directory and the digest, so a file
changed after it was written is refused; (2) asks skops which types the file would build
and refuses any outside :data:`TRUSTED_TYPES` and the ones the model's kind trusts,
before anything is constructed; (3) builds the model. This module sits below the kind
registry: the caller says which types a kind trusts. skops (and with it scikit-learn)
is imported when a file is written or read, not with this module.
"""

from __future__ import annotations

import hashlib
import io
import json
import platform
import zipfile
from collections.abc import Callable, Sequence
from contextlib import suppress
from pathlib import Path

from contactkit.classify.kinds.kind import ModelFormat
from contactkit.classify.modelfile.skops_import import skops_io
from contactkit.errors import ContactkitError, InputError
from contactkit.util.atomic import atomic_write
from contactkit.util.safe_open import check_regular, parse_json, read_input_bytes

META_MEMBER = "contactkit.json"
EVENTS_MEMBER = "events.skops"
FORMAT = "contactkit-model/3"
"""Version 3: a model of an SVM kind also carries its compiled arrays
(:mod:`contactkit.classify.kinds.online_arrays`). Version 2 files, without them, still load.
Since version 2 the digest covers every member, contactkit.json included (version 1
left it out, so its classes could be swapped unnoticed); version 1 files are refused."""
READABLE_FORMATS = ("contactkit-model/2", FORMAT)
MAX_MEMBER_BYTES = 256 << 20
"""The largest member [bytes, uncompressed] a model file may hold; checked from the
archive's directory before anything is decompressed (a zip bomb is refused unread)."""
MAX_MODEL_BYTES = 512 << 20
"""The largest model file, and the most its members may add up to uncompressed [bytes]."""
MAX_MEMBERS = 10_000
TRUSTED_TYPES = [
    "sklearn.model_selection._split.StratifiedKFold",
    "sklearn.calibration._CalibratedClassifier",
    "sklearn.calibration._SigmoidCalibration",
]


def versions() -> dict[str, str]:
    """Return the versions of Python and the packages a model file depends on."""
    names = ("contactkit", "scikit-learn", "numpy", "scipy", "skops", "pin")
    out = {"python": platform.python_version()}
    import importlib.metadata  # some 35 ms, paid only when a model file is written

    for name in names:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "missing"
    return out


def members_digest(archive: zipfile.ZipFile, meta: dict) -> str:
    return digest_of({name: archive.read(name) for name in archive.namelist()}, meta)


def digest_of(members: dict[str, bytes], meta: dict) -> str:
    """Return the SHA-256 over every member (name and bytes, in name order) and over the
    metadata document itself (canonical JSON, without the digest)."""
    digest = hashlib.sha256()
    for name in sorted(members):
        if name == META_MEMBER:
            continue
        digest.update(name.encode() + b"\0" + members[name] + b"\0")
    doc = {k: v for k, v in meta.items() if k != "members_sha256"}
    digest.update(META_MEMBER.encode() + b"\0"
                  + json.dumps(doc, sort_keys=True).encode() + b"\0")
    return digest.hexdigest()


def check_archive_sizes(archive: zipfile.ZipFile, path: Path) -> None:
    """Refuse an archive whose members would decompress beyond the bounds
    (:data:`MAX_MEMBER_BYTES` each, :data:`MAX_MODEL_BYTES` in all, :data:`MAX_MEMBERS`),
    from its directory alone, before any member is decompressed."""
    infos = archive.infolist()
    if len(infos) > MAX_MEMBERS:
        raise InputError(f"model file has {len(infos)} members (at most {MAX_MEMBERS})", path)
    total = 0
    for info in infos:
        if info.file_size > MAX_MEMBER_BYTES:
            raise InputError(f"model file member {info.filename[:80]!r} would decompress to "
                             f"{info.file_size} bytes (at most {MAX_MEMBER_BYTES}); "
                             "refusing it", path)
        total += info.file_size
    if total > MAX_MODEL_BYTES:
        raise InputError(f"model file members would decompress to {total} bytes (at most "
                         f"{MAX_MODEL_BYTES}); refusing it", path)


def write_skops(path: Path, estimator: object, meta: dict, sample_shape: tuple[int, ...] = (),
                overwrite: bool = False, extra: dict[str, bytes] | None = None) -> Path:
    """Write ``estimator`` and ``meta`` (and ``extra`` members, covered by the digest) as a
    skops model file atomically; return the path."""
    payload = skops_io().dumps(estimator)
    with zipfile.ZipFile(io.BytesIO(payload)) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    members |= extra or {}
    meta = meta | {"members_sha256": digest_of(members, meta)}
    with atomic_write(path, overwrite=overwrite) as tmp, \
            zipfile.ZipFile(tmp.file, "w", compression=zipfile.ZIP_DEFLATED) as out:
        for name, data in members.items():
            out.writestr(name, data)
        out.writestr(META_MEMBER, json.dumps(meta, indent=2))
    return path


def read_verified(path: Path) -> tuple[bytes, dict]:
    """Read a skops model file's bytes and metadata, checking its sizes, format and
    digest (see the module docstring) but building nothing; raise InputError if refused."""
    if check_regular(path, "model file", "model").st_size > MAX_MODEL_BYTES:
        raise InputError(f"model file is larger than {MAX_MODEL_BYTES} bytes", path)
    data = read_input_bytes(path, "model file", "model")
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            check_archive_sizes(archive, path)
            if META_MEMBER not in archive.namelist():
                raise InputError("not a contactkit model file (no contactkit.json)", path)
            meta = parse_json(archive.read(META_MEMBER), "model metadata", path)
            if not isinstance(meta, dict):
                raise InputError("not a contactkit model file (contactkit.json is not an "
                                 "object)", path)
            digest = members_digest(archive, meta)
    except ContactkitError:
        raise
    except Exception as err:  # zipfile, zlib, json and struct all raise on corrupt bytes
        raise InputError(f"not a contactkit model file, or a damaged one "
                         f"({type(err).__name__}: {' '.join(str(err).split())[:80]})",
                         path) from err
    if meta.get("format") not in READABLE_FORMATS:
        old = meta.get("format") == "contactkit-model/1"
        raise InputError("model file of an older contactkit whose digest leaves out its "
                         "metadata; train it again" if old else
                         f"unknown model format {str(meta.get('format'))[:80]!r}", path)
    if digest != meta.get("members_sha256"):
        raise InputError("model file was modified after it was written (digest mismatch); "
                         "refusing to load it", path)
    return data, meta


def stored_classes(data: bytes, path: Path) -> list[list[str]]:
    """Return the class lists (``classes_`` arrays of names) stored in a verified skops
    archive's schema, read as JSON and plain ``.npy`` text arrays without building
    anything: what a loader that uses the compiled arrays instead of the estimator
    checks the file's classes against, as the loader that builds the estimator does (a
    document whose classes were reordered and re-sealed is refused by both)."""
    import numpy as np

    found = []
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        schema = parse_json(archive.read("schema.json"), "model schema", path,
                            limit=MAX_MODEL_BYTES, max_depth=400)
        stack = [schema]
        while stack:
            node = stack.pop()
            if isinstance(node, list):
                stack += node
                continue
            if not isinstance(node, dict):
                continue
            stack += node.values()
            classes = node.get("classes_")
            if not isinstance(classes, dict):
                continue
            names = classes.get("content")
            with suppress(InputError, ValueError, KeyError, OSError, TypeError):
                if isinstance(names, list):  # an object array: JSON nodes
                    found.append([str(parse_json(n["content"], "model schema", path))
                                  for n in names if n.get("__class__") == "str"])
                elif isinstance(classes.get("file"), str):  # a text array: .npy
                    array = np.load(io.BytesIO(archive.read(classes["file"])),
                                    allow_pickle=False)
                    if array.dtype.kind == "U" and array.ndim == 1:
                        found.append([str(name) for name in array])
    return found


def build_skops(data: bytes, trusted: Sequence[str], path: Path) -> object:
    """Return the estimator of a verified skops archive's bytes (:func:`read_verified`),
    refusing, before anything is constructed, any type outside :data:`TRUSTED_TYPES`
    and ``trusted``; raise InputError naming ``path`` if refused."""
    trusted = TRUSTED_TYPES + list(trusted)
    try:
        untrusted = [t for t in skops_io().get_untrusted_types(data=data) if t not in trusted]
    except Exception as err:  # skops raises many kinds on a malformed archive
        raise InputError(f"unreadable model archive ({type(err).__name__})", path) from err
    if untrusted:
        raise InputError(f"model file would build untrusted types {untrusted}; refusing", path)
    try:
        return skops_io().loads(data, trusted=trusted)
    except Exception as err:  # skops raises many kinds on a malformed archive
        raise InputError(f"unreadable model ({type(err).__name__})", path) from err


def read_skops(path: Path, trusted_types: Callable[[dict], Sequence[str]] = lambda meta: ()
               ) -> tuple[object, dict]:
    """Read a skops model file safely (see the module docstring); return the estimator
    and its metadata, or raise InputError. ``trusted_types(meta)`` names the types the
    file's model kind may build beyond :data:`TRUSTED_TYPES`."""
    data, meta = read_verified(path)
    return build_skops(data, trusted_types(meta), path), meta


SKOPS = ModelFormat("skops", ".skops", write_skops, read_skops)
