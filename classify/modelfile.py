"""Model files that load without executing code from the file.

A model file is a skops archive (a zip of JSON and .npy members, never pickle)
with one extra member, ``contactkit.json``: the feature configuration and feature
names, the class names and scheme, the model kind, a SHA-256 fingerprint of the
training data, package versions, and a SHA-256 over every other member. A model
that also decides per contact event carries the contact detector's settings and
the event classifier's settings there, and the event classifier itself as a
nested skops archive ``events.skops`` (checked the same way).

Loading (1) checks the digest, so a file changed after it was written is refused;
(2) asks skops which types the file would build and refuses any outside
``TRUSTED_TYPES`` (skops' own defaults for numpy and scikit-learn, plus the few
named below) and the model kind's own ``trusted_types``, before anything is
constructed; (3) builds the model. Feature tables or sessions prepared with other
features are refused by :meth:`ModelFile.check_features`.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import io
import json
import platform
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import skops.io as sio
from sklearn.pipeline import Pipeline

from contactkit.classify.kind import ModelFormat, ModelKind
from contactkit.schemas import InputError
from contactkit.util.atomic import atomic_write, check_target

META_MEMBER = "contactkit.json"
EVENTS_MEMBER = "events.skops"
FORMAT = "contactkit-model/2"
"""Version 2: the digest covers every member, contactkit.json included (version 1 left
it out, so its classes could be swapped unnoticed); version 1 files are refused."""
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


def _versions() -> dict[str, str]:
    names = ("contactkit", "scikit-learn", "numpy", "scipy", "skops", "pin")
    out = {"python": platform.python_version()}
    for name in names:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "missing"
    return out


def _members_digest(archive: zipfile.ZipFile, meta: dict) -> str:
    return _digest({name: archive.read(name) for name in archive.namelist()}, meta)


def _digest(members: dict[str, bytes], meta: dict) -> str:
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


@dataclass
class ModelFile:
    """A loaded model: the fitted estimator and what the file says about it."""

    estimator: object
    meta: dict
    event_estimator: object | None = None

    def detector_config(self):
        """Return the contact detector's settings the model carries, or None."""
        from contactkit.features.detector import DetectorConfig

        doc = self.meta.get("detector")
        return None if doc is None else DetectorConfig.from_dict(doc)

    def event_model(self):
        """Return the per-event intent classifier the model carries, or None."""
        from contactkit.classify.events import EventModel

        if self.event_estimator is None:
            return None
        return EventModel.from_meta(self.event_estimator, self.meta["events"])

    @property
    def kind(self) -> ModelKind:
        """The registered kind of this model (raises InputError if it is not installed)."""
        from contactkit.classify.registry import get_kind

        return get_kind(self.meta["kind"])

    @property
    def classes(self) -> list[str]:
        """Class names in the order of ``predict_proba``'s columns."""
        return list(self.meta["classes"])

    @property
    def feature_names(self) -> list[str]:
        """The input columns the model expects, in order (grid channels for a network)."""
        if "feature_names" in self.meta:
            return list(self.meta["feature_names"])
        return list(self.transformer().get_feature_names_out())

    def transformer(self):
        """Return the input transformer (sessions to features or grids) configured as at
        training time."""
        input_kind = self.kind.input
        return input_kind.from_config(dict(self.meta[input_kind.meta_key]))

    def pipeline(self) -> Pipeline:
        """Return the model as a scikit-learn Pipeline over sessions: its first step turns
        sessions (paths or :class:`contactkit.schemas.Session`) into the model's input."""
        return Pipeline([("input", self.transformer()), ("model", self.estimator)])

    def online_predictor(self) -> Callable[[np.ndarray], np.ndarray]:
        """Return the kind's fast function from a batch of inputs to class probabilities."""
        return self.kind.online(self.estimator)

    def check_features(self, names: list[str], where: str | Path | None = None) -> None:
        """Raise InputError unless ``names`` are exactly the model's feature columns."""
        if list(names) != self.feature_names:
            extra = sorted(set(names) - set(self.feature_names))[:3]
            missing = sorted(set(self.feature_names) - set(names))[:3]
            raise InputError(f"model was trained on other features (missing {missing}, "
                             f"unexpected {extra})", where)


def model_meta(*, kind: ModelKind, transformer, feature_names: list[str], scheme: str,
               classes: list[str], fingerprint: str, training: dict) -> dict:
    """Return the metadata document every model file carries."""
    return {"format": FORMAT, "kind": kind.name, "scheme": scheme, "classes": list(classes),
            "training_fingerprint": fingerprint, "training": training,
            "versions": _versions(), "input": kind.input.name,
            kind.input.meta_key: transformer.config(), "feature_names": list(feature_names)}


def save_model(path: str | Path, estimator: object, *, kind: ModelKind, transformer,
               feature_names: list[str], classes: list[str], scheme: str, fingerprint: str,
               training: dict, sample_shape: tuple[int, ...] = (), overwrite: bool = False,
               detector: dict | None = None, events: tuple[object, dict] | None = None
               ) -> Path:
    """Write a fitted model in its kind's file format, atomically; return the path.

    ``sample_shape`` is the shape of one input (for formats that fix it in the file).
    ``detector`` is the contact detector's settings document and ``events`` the event
    classifier with its settings document (skops model files only).
    """
    path = Path(path)
    suffix = kind.file_format.suffix
    if path.suffix.lower() != suffix:
        raise InputError(f"a {kind.name} model is saved as {kind.file_format.name}: the file "
                         f"name must end in {suffix}", path)
    check_target(path, overwrite=overwrite)
    meta = model_meta(kind=kind, transformer=transformer, feature_names=feature_names,
                      scheme=scheme, classes=classes, fingerprint=fingerprint,
                      training=training)
    if detector is not None:
        meta["detector"] = detector
    if events is None:
        return kind.file_format.save(path, estimator, meta, sample_shape, overwrite)
    if kind.file_format is not SKOPS:
        raise InputError(f"an event classifier can only travel in a skops model file, not "
                         f"{kind.file_format.name}", path)
    meta["events"] = events[1]
    return write_skops(path, estimator, meta, sample_shape, overwrite,
                       extra={EVENTS_MEMBER: sio.dumps(events[0])})


def write_skops(path: Path, estimator: object, meta: dict, sample_shape: tuple[int, ...] = (),
                overwrite: bool = False, extra: dict[str, bytes] | None = None) -> Path:
    """Write ``estimator`` and ``meta`` (and ``extra`` members, covered by the digest) as a
    skops model file atomically; return the path."""
    payload = sio.dumps(estimator)
    with zipfile.ZipFile(io.BytesIO(payload)) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    members |= extra or {}
    meta = meta | {"members_sha256": _digest(members, meta)}
    with atomic_write(path, overwrite=overwrite) as tmp, \
            zipfile.ZipFile(tmp.file, "w", compression=zipfile.ZIP_DEFLATED) as out:
        for name, data in members.items():
            out.writestr(name, data)
        out.writestr(META_MEMBER, json.dumps(meta, indent=2))
    return path


def read_skops(path: Path) -> tuple[object, dict]:
    """Read a skops model file safely (see the module docstring); return the estimator
    and its metadata, or raise InputError."""
    if path.stat().st_size > MAX_MODEL_BYTES:
        raise InputError(f"model file is larger than {MAX_MODEL_BYTES} bytes", path)
    data = path.read_bytes()
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            check_archive_sizes(archive, path)
            if META_MEMBER not in archive.namelist():
                raise InputError("not a contactkit model file (no contactkit.json)", path)
            meta = json.loads(archive.read(META_MEMBER))
            if not isinstance(meta, dict):
                raise InputError("not a contactkit model file (contactkit.json is not an "
                                 "object)", path)
            digest = _members_digest(archive, meta)
    except InputError:
        raise
    except Exception as err:  # zipfile, zlib, json and struct all raise on corrupt bytes
        raise InputError(f"not a contactkit model file, or a damaged one "
                         f"({type(err).__name__}: {' '.join(str(err).split())[:80]})",
                         path) from err
    if meta.get("format") != FORMAT:
        old = meta.get("format") == "contactkit-model/1"
        raise InputError("model file of an older contactkit whose digest leaves out its "
                         "metadata; train it again" if old else
                         f"unknown model format {str(meta.get('format'))[:80]!r}", path)
    if digest != meta.get("members_sha256"):
        raise InputError("model file was modified after it was written (digest mismatch); "
                         "refusing to load it", path)
    trusted = TRUSTED_TYPES + list(_kind_of(meta, path).trusted_types)
    try:
        untrusted = [t for t in sio.get_untrusted_types(data=data) if t not in trusted]
    except Exception as err:  # skops raises many kinds on a malformed archive
        raise InputError(f"unreadable model archive ({type(err).__name__})", path) from err
    if untrusted:
        raise InputError(f"model file would build untrusted types {untrusted}; refusing", path)
    try:
        return sio.loads(data, trusted=trusted), meta
    except Exception as err:  # skops raises many kinds on a malformed archive
        raise InputError(f"unreadable model ({type(err).__name__})", path) from err


def _load_event_estimator(path: Path, meta: dict) -> object | None:
    """Return the nested event classifier of a skops model file (None where the model has
    none), refusing untrusted types as for the main model."""
    if "events" not in meta:
        return None
    try:
        with zipfile.ZipFile(path) as archive:
            check_archive_sizes(archive, path)
            if EVENTS_MEMBER not in archive.namelist():
                raise InputError(f"model file lacks its event classifier ({EVENTS_MEMBER})",
                                 path)
            data = archive.read(EVENTS_MEMBER)
    except InputError:
        raise
    except Exception as err:  # the file changed since it was checked, or is damaged
        raise InputError(f"damaged model file ({type(err).__name__})", path) from err
    from contactkit.classify.registry import get_kind

    trusted = TRUSTED_TYPES + list(get_kind("svm").trusted_types)
    try:
        untrusted = [t for t in sio.get_untrusted_types(data=data) if t not in trusted]
    except Exception as err:  # skops raises many kinds on a malformed archive
        raise InputError(f"unreadable event classifier ({type(err).__name__})", path) from err
    if untrusted:
        raise InputError(f"event classifier would build untrusted types {untrusted}; "
                         "refusing", path)
    try:
        return sio.loads(data, trusted=trusted)
    except Exception as err:  # skops raises many kinds on a malformed archive
        raise InputError(f"unreadable event classifier ({type(err).__name__})", path) from err


def _kind_of(meta: dict, path: Path) -> ModelKind:
    from contactkit.classify.registry import get_kind

    try:
        return get_kind(str(meta.get("kind")))
    except InputError as err:
        raise InputError(f"{err.problem}; is the package that provides it installed?",
                         path) from err


SKOPS = ModelFormat("skops", ".skops", write_skops, read_skops)


def load_model(path: str | Path) -> ModelFile:
    """Load a model file safely in the format its suffix names (skops unless another
    installed kind's format claims the suffix); raise InputError if refused."""
    from contactkit.classify.registry import get_kind, kind_names

    path = Path(path)
    if not path.is_file():
        raise InputError("no such model file", path)
    formats = {get_kind(n).file_format.suffix: get_kind(n).file_format for n in kind_names()}
    estimator, meta = formats.get(path.suffix.lower(), SKOPS).load(path)
    model = ModelFile(estimator=estimator, meta=meta,
                      event_estimator=_load_event_estimator(path, meta))
    try:
        model.detector_config()
    except InputError as err:
        raise InputError(f"model file carries invalid detector settings ({err})", path) from err
    kind = _kind_of(meta, path)
    if meta.get("input", "features") != kind.input.name:
        raise InputError(f"a {kind.name} model takes {kind.input.name} input, the file says "
                         f"{meta.get('input')!r}", path)
    return model
