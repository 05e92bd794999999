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
named below), before anything is constructed; (3) builds the model. Feature
tables or sessions prepared with other features are refused by
:meth:`ModelFile.check_features`.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import io
import json
import platform
import zipfile
from dataclasses import dataclass
from pathlib import Path

import skops.io as sio

from contactkit.features.extract import SessionFeatures
from contactkit.schemas import InputError

META_MEMBER = "contactkit.json"
EVENTS_MEMBER = "events.skops"
FORMAT = "contactkit-model/1"
TRUSTED_TYPES = [
    "aeon.classification.convolution_based._minirocket.MiniRocketClassifier",
    "aeon.transformations.collection.convolution_based._minirocket.MiniRocket",
    "contactkit.classify.models.CalibratedSVC",
    "contactkit.classify.models.JointEnsemble",
    "contactkit.classify.nn.MiniRocketClassifier",
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


def _members_digest(archive: zipfile.ZipFile) -> str:
    return _digest({name: archive.read(name) for name in archive.namelist()})


def _digest(members: dict[str, bytes]) -> str:
    digest = hashlib.sha256()
    for name in sorted(members):
        if name == META_MEMBER:
            continue
        digest.update(name.encode() + b"\0" + members[name] + b"\0")
    return digest.hexdigest()


@dataclass
class ModelFile:
    """A loaded model: the estimator and what the file says about it."""

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
    def classes(self) -> list[str]:
        """Class names in the order of ``predict_proba``'s columns."""
        return list(self.meta["classes"])

    @property
    def feature_names(self) -> list[str]:
        """The feature columns the model expects, in order."""
        return list(self.meta["feature_names"])

    @property
    def input(self) -> str:
        """What the model takes: "features" (scalar features) or "grid" (raw windows)."""
        return self.meta.get("input", "features")

    def extractor(self) -> SessionFeatures:
        """Return the feature extractor configured as at training time."""
        if self.input != "features":
            raise InputError("this model takes timeseries grids, not scalar features")
        return SessionFeatures(**self.meta["features"])

    def grid_spec(self):
        """Return the grid specification of a network model."""
        from contactkit.classify.grids import GridSpec

        doc = dict(self.meta["grid"])
        doc["timeseries"] = tuple(doc["timeseries"])
        doc.setdefault("baseline_s", 0.0)
        return GridSpec(**doc)

    def check_features(self, names: list[str], where: str | Path | None = None) -> None:
        """Raise InputError unless ``names`` are exactly the model's feature columns."""
        if list(names) != self.feature_names:
            extra = sorted(set(names) - set(self.feature_names))[:3]
            missing = sorted(set(self.feature_names) - set(names))[:3]
            raise InputError(f"model was trained on other features (missing {missing}, "
                             f"unexpected {extra})", where)


def model_meta(*, kind: str, scheme: str, classes: list[str], fingerprint: str,
               training: dict, extractor: SessionFeatures | None = None,
               feature_names: list[str] | None = None, grid: dict | None = None) -> dict:
    """Return the metadata document every model file carries."""
    meta = {"format": FORMAT, "kind": kind, "scheme": scheme, "classes": list(classes),
            "training_fingerprint": fingerprint, "training": training, "versions": _versions()}
    if grid is not None:
        meta.update({"input": "grid", "grid": grid})
    else:
        meta.update({"input": "features", "features": extractor.config(),
                     "feature_names": list(feature_names)})
    return meta


def save_model(path: str | Path, estimator: object, *, extractor: SessionFeatures | None = None,
               feature_names: list[str] | None = None, classes: list[str], kind: str,
               scheme: str, fingerprint: str, training: dict, overwrite: bool = False,
               grid: dict | None = None, detector: dict | None = None,
               events: tuple[object, dict] | None = None) -> Path:
    """Write a skops model file atomically; return its path. ``detector`` is the
    contact detector's settings document, ``events`` the event classifier and its
    settings document."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise InputError("output file already exists (pass --overwrite to replace it)", path)
    payload = sio.dumps(estimator)
    with zipfile.ZipFile(io.BytesIO(payload)) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    meta = model_meta(kind=kind, scheme=scheme, classes=classes, fingerprint=fingerprint,
                      training=training, extractor=extractor, feature_names=feature_names,
                      grid=grid)
    if detector is not None:
        meta["detector"] = detector
    if events is not None:
        members[EVENTS_MEMBER] = sio.dumps(events[0])
        meta["events"] = events[1]
    meta["members_sha256"] = _digest(members)
    tmp = path.with_name(f".{path.name}.tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as out:
        for name, data in members.items():
            out.writestr(name, data)
        out.writestr(META_MEMBER, json.dumps(meta, indent=2))
    tmp.replace(path)
    return path


def load_model(path: str | Path) -> ModelFile:
    """Load a model file safely (see the module docstring); raise InputError if refused."""
    path = Path(path)
    if not path.is_file():
        raise InputError("no such model file", path)
    if path.suffix.lower() == ".onnx":
        from contactkit.classify.onnx_model import load_onnx_model

        estimator, meta = load_onnx_model(path)
        return ModelFile(estimator=estimator, meta=meta)
    data = path.read_bytes()
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            if META_MEMBER not in archive.namelist():
                raise InputError("not a contactkit model file (no contactkit.json)", path)
            meta = json.loads(archive.read(META_MEMBER))
            digest = _members_digest(archive)
    except (zipfile.BadZipFile, json.JSONDecodeError) as err:
        raise InputError(f"not a contactkit model file ({err})", path) from err
    if meta.get("format") != FORMAT:
        raise InputError(f"unknown model format {meta.get('format')!r}", path)
    if digest != meta.get("members_sha256"):
        raise InputError("model file was modified after it was written (digest mismatch); "
                         "refusing to load it", path)
    estimator = _load_trusted(data, path)
    event_estimator = None
    if "events" in meta:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            if EVENTS_MEMBER not in archive.namelist():
                raise InputError(f"model file lacks its event classifier ({EVENTS_MEMBER})",
                                 path)
            event_estimator = _load_trusted(archive.read(EVENTS_MEMBER), path)
    model = ModelFile(estimator=estimator, meta=meta, event_estimator=event_estimator)
    try:
        model.detector_config()
    except InputError as err:
        raise InputError(f"model file carries invalid detector settings ({err})", path) from err
    return model


def _load_trusted(data: bytes, path: Path) -> object:
    """Build a skops archive's object after refusing any type outside TRUSTED_TYPES."""
    try:
        untrusted = [t for t in sio.get_untrusted_types(data=data) if t not in TRUSTED_TYPES]
    except Exception as err:  # skops raises many kinds on a malformed archive
        raise InputError(f"unreadable model archive ({type(err).__name__})", path) from err
    if untrusted:
        raise InputError(f"model file would build untrusted types {untrusted}; refusing", path)
    return sio.loads(data, trusted=TRUSTED_TYPES)
