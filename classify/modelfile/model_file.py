"""Model files: what a fitted model is saved as and loaded from, above the kind registry.

A model file carries the fitted estimator in its kind's file format (skops by default,
:mod:`contactkit.classify.modelfile.skops_format`; ONNX for exported networks) and a metadata
document: the feature configuration and feature names, the class names and scheme, the
model kind, a SHA-256 fingerprint of the training data and package versions. A model
that also decides per contact event carries the contact detector's settings and the
event classifier's settings there, and the event classifier itself as a nested skops
archive ``events.skops`` (checked the same way). A model of an SVM kind also carries
both classifiers compiled to arrays (:mod:`contactkit.classify.kinds.online_arrays`): loaded
with ``lazy=True``, a model classifies online (a replay, ``recorder capture
--events``) from those, and builds its estimator through skops only when something asks for it.

Loading refuses a file changed after it was written and any type outside what the
file's kind trusts, before anything is constructed, and checks the metadata document as
any other input (:func:`check_meta`): its digest only tells that the file is whole, as
anyone can rewrite the document and compute the digest again. Feature tables or sessions prepared
with other features are refused by :meth:`ModelFile.check_features`.
"""

from __future__ import annotations

import io
import logging
import math
import zipfile
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from contactkit.classify.kinds.fast import Compiled, compile_estimator
from contactkit.classify.kinds.kind import ModelKind
from contactkit.classify.kinds.online_arrays import online_members, read_online
from contactkit.classify.kinds.registry import get_kind, kind_names
from contactkit.classify.kinds.svm import SVM_TRUSTED_TYPES as EVENT_TRUSTED_TYPES
from contactkit.classify.modelfile.skops_format import (
    EVENTS_MEMBER,
    FORMAT,
    SKOPS,
    TRUSTED_TYPES,
    build_skops,
    check_archive_sizes,
    read_verified,
    stored_classes,
    versions,
    write_skops,
)
from contactkit.classify.modelfile.skops_import import skops_io
from contactkit.classify.schemes import check_scheme
from contactkit.errors import ContactkitError
from contactkit.schemas import InputError
from contactkit.util.atomic import check_target
from contactkit.util.params import Interval

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from sklearn.pipeline import Pipeline

ONLINE_PREFIX = "online/"
"""Where a model file keeps its classifier's compiled arrays."""
EVENTS_ONLINE_PREFIX = "events-online/"
"""Where a model file keeps its event classifier's compiled arrays."""


class ModelFile:
    """A loaded model: the fitted estimator and what the file says about it.

    ``meta`` is the file's metadata document, ``event_estimator`` the per-event
    classifier (None where the model has none). ``online`` is the classifier compiled
    to arrays, where the file carries it; with it, ``estimator`` may be left to
    ``build_estimator``, called the first time the estimator is asked for.
    """

    def __init__(self, estimator: object | None, meta: dict,
                 event_estimator: object | None = None, *, online: Compiled | None = None,
                 build_estimator: Callable[[], object] | None = None) -> None:
        if estimator is None and build_estimator is None:
            raise ValueError("a model file needs its estimator or a way to build it")
        self._estimator = estimator
        self._build_estimator = build_estimator
        self.meta = meta
        self.event_estimator = event_estimator
        self.online = online

    @property
    def estimator(self) -> Any:
        """The fitted estimator (built on first use where the file was loaded lazily)."""
        if self._estimator is None:
            assert self._build_estimator is not None  # one of the two is given
            self._estimator = self._build_estimator()
        return self._estimator

    @property
    def trained_robots(self) -> list[str] | None:
        """The arms (registry names) of the sessions the model was trained on, None where
        the file does not say (trained on feature tables, or by an older version)."""
        training = self.meta.get("training")
        robots = training.get("robots") if isinstance(training, dict) else None
        return None if robots is None else list(robots)

    def check_robot(self, robot: str, path: str | Path | None = None) -> bool:
        """Return whether the model was trained on sessions of the arm ``robot`` (a
        registry name), or cannot tell; warn once per arm (a logging warning naming the
        session ``path``) when it was not: the features come from that arm's own model,
        but the classifier has not seen its sessions."""
        trained = self.trained_robots
        if trained is None or robot in trained:
            return True
        warned = self.__dict__.setdefault("_warned_robots", set())
        if robot not in warned:
            warned.add(robot)
            where = f"{Path(path).name}: " if path is not None else ""
            log.warning("%sthe model was trained on %s sessions only, this session's arm is "
                        "%s (its features come from that arm's model; the classifier has "
                        "not seen it)", where, " and ".join(trained), robot)
        return False

    def detector_config(self):
        """Return the contact detector's settings the model carries, or None."""
        from contactkit.features.detector import DetectorConfig

        doc = self.meta.get("detector")
        return None if doc is None else DetectorConfig.from_dict(doc)

    def event_model(self):
        """Return the per-event intent classifier the model carries, or None."""
        from contactkit.classify.events.contact_events import EventModel

        if self.event_estimator is None:
            return None
        return EventModel.from_meta(self.event_estimator, self.meta["events"])

    @property
    def kind(self) -> ModelKind:
        """The registered kind of this model (raises InputError if it is not installed)."""
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
        from sklearn.pipeline import Pipeline

        return Pipeline([("input", self.transformer()), ("model", self.estimator)])

    def online_transformer(self):
        """Return the input transformer for online use (a replay, live events): the input
        kind's light one where it has one (without scikit-learn), else
        :meth:`transformer`'s."""
        input_kind = self.kind.input
        return input_kind.online_from_config(dict(self.meta[input_kind.meta_key]))

    def online_predictor(self) -> Callable[[np.ndarray], np.ndarray]:
        """Return a fast function from a batch of inputs to class probabilities: the
        file's compiled arrays where it carries them, else the kind's online predictor."""
        if self.online is not None:
            return self.online.predict_proba
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
            "versions": versions(), "input": kind.input.name,
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
    if kind.file_format is not SKOPS:
        if events is not None:
            raise InputError(f"an event classifier can only travel in a skops model file, "
                             f"not {kind.file_format.name}", path)
        return kind.file_format.save(path, estimator, meta, sample_shape, overwrite)
    extra = _online_extra(meta, estimator, ONLINE_PREFIX)
    if events is not None:
        meta["events"] = dict(events[1])
        extra[EVENTS_MEMBER] = skops_io().dumps(events[0])
        extra |= _online_extra(meta["events"], events[0], EVENTS_ONLINE_PREFIX)
    return write_skops(path, estimator, meta, sample_shape, overwrite, extra=extra)


def _online_extra(doc: dict, estimator: object, prefix: str) -> dict[str, bytes]:
    """Return the members holding ``estimator`` compiled to arrays under ``prefix`` and
    add their description to ``doc`` (as ``online``); none for an estimator that does
    not compile."""
    compiled = compile_estimator(estimator)
    if compiled is None:
        return {}
    doc["online"], members = online_members(compiled, prefix)
    return members


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
    except ContactkitError:
        raise
    except Exception as err:  # the file changed since it was checked, or is damaged
        raise InputError(f"damaged model file ({type(err).__name__})", path) from err
    trusted = TRUSTED_TYPES + list(EVENT_TRUSTED_TYPES)
    try:
        untrusted = [t for t in skops_io().get_untrusted_types(data=data) if t not in trusted]
    except Exception as err:  # skops raises many kinds on a malformed archive
        raise InputError(f"unreadable event classifier ({type(err).__name__})", path) from err
    if untrusted:
        raise InputError(f"event classifier would build untrusted types {untrusted}; "
                         "refusing", path)
    try:
        return skops_io().loads(data, trusted=trusted)
    except Exception as err:  # skops raises many kinds on a malformed archive
        raise InputError(f"unreadable event classifier ({type(err).__name__})", path) from err


def _kind_of(meta: dict, path: Path) -> ModelKind:
    from contactkit.classify.kinds.registry import get_kind

    try:
        return get_kind(str(meta.get("kind")))
    except InputError as err:
        raise InputError(f"{err.problem}; is the package that provides it installed?",
                         path) from err


def load_model(path: str | Path, *, lazy: bool = False) -> ModelFile:
    """Load a model file safely in the format its suffix names (skops unless another
    installed kind's format claims the suffix); raise InputError if refused.

    With ``lazy``, a file that carries its classifiers compiled to arrays loads those
    (checked, and covered by the file's digest) and builds its estimator through skops,
    with the same refusal of untrusted types, only when ``estimator`` is first asked
    for: a replay then imports neither scikit-learn nor skops."""
    path = Path(path)
    if not path.is_file():
        raise InputError("no such model file", path)
    formats = {get_kind(n).file_format.suffix: get_kind(n).file_format for n in kind_names()}
    file_format = formats.get(path.suffix.lower(), SKOPS)
    if lazy and file_format is SKOPS:
        model = _load_lazily(path)
    else:
        estimator, meta = file_format.load(path, lambda meta: _kind_of(meta, path).trusted_types)
        check_meta(meta, path)
        if file_format is SKOPS:
            check_compiled(read_verified(path)[0], meta, path)
        model = ModelFile(_check_classes(estimator, meta["classes"], path), meta,
                          _check_classes(_load_event_estimator(path, meta),
                                         meta.get("events", {}).get("classes"), path,
                                         "event classifier"))
    try:
        model.event_model()
    except InputError as err:
        raise InputError(f"model file carries invalid event settings ({err.problem})",
                         path) from err
    return model


def check_meta(meta: dict, path: Path) -> None:
    """Raise a one-line InputError naming the model file ``path`` unless its metadata
    document is well formed and consistent: a known kind and its input; classes a
    non-empty list of distinct strings; the input's settings (``features``, ``grid``)
    an object its input kind accepts (the kind's own checks: feature names, window,
    robot); ``feature_names``, where given, the list of names those settings produce;
    a known class scheme; valid detector settings; event settings of the right shape.

    The digest only tells that a file is whole: anyone can rewrite a document and
    recompute it, so the document is checked as any other input."""
    kind = _kind_of(meta, path)
    if meta.get("input", "features") != kind.input.name:
        raise InputError(f"a {kind.name} model takes {kind.input.name} input, the file says "
                         f"{str(meta.get('input'))[:80]!r}", path)
    _check_labels(meta.get("classes"), "classes", path)
    if "scheme" in meta:
        try:
            check_scheme(meta["scheme"])
        except (InputError, TypeError) as err:
            raise InputError(f"model file names an unknown class scheme "
                             f"{str(meta['scheme'])[:80]!r}", path) from err
    key = kind.input.meta_key
    if meta.get(key) is None:
        raise InputError(f"model file lacks its {key} settings", path)
    if not isinstance(meta[key], dict):
        raise InputError(f"model file's {key} settings are not an object (a "
                         f"{type(meta[key]).__name__})", path)
    try:
        transformer = kind.input.online_from_config(dict(meta[key]))
        produced = [str(name) for name in transformer.get_feature_names_out()]
    except InputError as err:
        problem = err.problem if err.problem.startswith(f"{key} settings") else \
            f"{key} settings: {err.problem}"
        raise InputError(f"model file's {problem}", path) from err
    except (TypeError, KeyError, ValueError, AttributeError) as err:  # a plugin's input kind
        raise InputError(f"model file's {key} settings are not what a {kind.input.name} input "
                         f"takes ({type(err).__name__}: {' '.join(str(err).split())[:80]})",
                         path) from err
    robot = meta[key].get("robot")
    if isinstance(robot, str):  # read as predict reads it: a special file is refused here
        from contactkit.robots import get_robot

        try:
            get_robot(robot)
        except InputError as err:
            raise InputError(f"model file's {key} settings name a robot that cannot be used "
                             f"({err})", path) from err
    names = meta.get("feature_names", produced)
    if not (isinstance(names, list) and all(isinstance(name, str) for name in names)):
        raise InputError("model file's feature_names are not a list of names", path)
    if names != produced:
        at = next((i for i, (a, b) in enumerate(zip(names, produced, strict=False)) if a != b),
                  min(len(names), len(produced)))
        raise InputError(f"model file's feature_names ({len(names)}) are not the "
                         f"{len(produced)} its {key} settings produce (at {at}: "
                         f"{names[at] if at < len(names) else 'none'!r:.60} vs "
                         f"{produced[at] if at < len(produced) else 'none'!r:.60})", path)
    from contactkit.features.detector import DetectorConfig

    try:
        if meta.get("detector") is not None:
            DetectorConfig.from_dict(meta["detector"])
    except InputError as err:
        raise InputError(f"model file carries invalid detector settings ({err.problem})",
                         path) from err
    if "events" in meta:
        _check_event_meta(meta["events"], path)
    training = meta.get("training", {})
    robots = training.get("robots") if isinstance(training, dict) else None
    if robots is not None and not (isinstance(robots, list)
                                   and all(isinstance(r, str) for r in robots)):
        raise InputError(f"model file's training robots are not a list of names "
                         f"({str(robots)[:80]})", path)


def _check_labels(labels: object, what: str, path: Path) -> None:
    """Raise InputError naming ``path`` unless ``labels`` are a non-empty list of distinct
    strings."""
    if not (isinstance(labels, list) and labels and all(isinstance(c, str) for c in labels)
            and len(set(labels)) == len(labels)):
        raise InputError(f"model file's {what} are not a non-empty list of distinct names "
                         f"({str(labels)[:80]})", path)


def _check_event_meta(doc: object, path: Path) -> None:
    """Raise InputError naming ``path`` unless ``doc`` has the shape of
    :meth:`contactkit.classify.events.contact_events.EventModel.meta`'s document."""
    from contactkit.classify.events.contact_events import EVENT_FEATURES

    if not isinstance(doc, dict):
        raise InputError("model file's event settings are not an object", path)
    _check_labels(doc.get("classes"), "event classes", path)
    if doc.get("features") != EVENT_FEATURES:
        raise InputError("the event classifier was trained on other event features", path)
    decide: Any = doc.get("decide_after_s")
    problem = Interval(0, None).problem(decide)
    if problem is None and not math.isfinite(decide):
        problem = f"must be finite, got {decide!r}"
    if problem is not None:
        raise InputError(f"model file's event decide_after_s {problem}", path)
    def numbers(values: object) -> bool:
        return (isinstance(values, list) and len(values) == len(EVENT_FEATURES)
                and all(isinstance(v, int | float) and not isinstance(v, bool)
                        and not math.isnan(v) for v in values))

    for key in ("low", "high"):
        if not numbers(doc.get(key)):
            raise InputError(f"model file's event {key} must be {len(EVENT_FEATURES)} "
                             "numbers", path)
    for key in ("class_low", "class_high"):  # absent in files written before them
        per_class = doc.get(key, {})
        if not (isinstance(per_class, dict) and set(per_class) <= set(doc["classes"])
                and all(numbers(v) for v in per_class.values())):
            raise InputError(f"model file's event {key} must give each of its classes "
                             f"{len(EVENT_FEATURES)} numbers", path)
    if ("class_low" in doc) != ("class_high" in doc):
        raise InputError("model file's event class_low and class_high come together", path)
    if "weak" in doc:  # absent in files written before it
        _check_weak(doc["weak"], path)


def _check_weak(doc: object, path: Path) -> None:
    """Raise InputError naming ``path`` unless ``doc`` is a weak-contact rule's settings
    (:meth:`contactkit.classify.events.contact_events.WeakDecision.to_dict`)."""
    from contactkit.classify.events.contact_events import WeakDecision

    if not (isinstance(doc, dict) and set(doc) == {"score", "decide_after_s"}
            and all(isinstance(v, int | float) and not isinstance(v, bool)
                    for v in doc.values())):
        raise InputError("model file's event weak must be an object of a score and a "
                         "decide_after_s", path)
    try:
        WeakDecision.from_dict(doc)
    except InputError as err:
        raise InputError(f"model file's event weak: {err.problem}", path) from err


def _check_classes(estimator: object | None, classes: list[str] | None, path: Path,
                   what: str = "model") -> object | None:
    """Return ``estimator``; raise InputError naming ``path`` when the classes it was
    fitted on (``classes_``, where it has them) are not the file's ``classes``."""
    fitted = getattr(estimator, "classes_", None)
    if fitted is not None and [str(c) for c in fitted] != classes:
        raise InputError(f"the {what} was fitted on other classes than the file lists "
                         f"({len(fitted)}: {', '.join(map(str, fitted))[:80]})", path)
    return estimator


COPIED_ARRAYS = ("mean", "scale", "support_vectors")
"""The compiled arrays that are copies of the estimator's own (the scaler's mean and
scale, the SVM's support vectors): a loader that classifies with the compiled arrays
checks them against the estimator's, so that it and a loader that builds the estimator
classify alike, or both refuse the file."""


def check_compiled(data: bytes, meta: dict, path: Path) -> None:
    """Check a verified skops file's compiled classifier against its estimator without
    building it: the classes the estimator was fitted on (:func:`stored_classes`) are
    the file's, and the compiled arrays that copy the estimator's are its copies. Both
    loaders run it (the compiled arrays' and the estimator's), so that a file changed
    apart from its model is refused by both, never classified two ways."""
    if "online" not in meta:
        return
    stored = stored_classes(data, path)
    if stored and meta["classes"] not in stored:
        raise InputError(f"the model was fitted on other classes than the file lists "
                         f"({', '.join(stored[-1])[:80]})", path)
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        _check_copies(archive, meta["online"], archive, path)
        events = meta.get("events")
        if isinstance(events, dict) and "online" in events and EVENTS_MEMBER in \
                archive.namelist():
            with zipfile.ZipFile(io.BytesIO(archive.read(EVENTS_MEMBER))) as estimator:
                _check_copies(archive, events["online"], estimator, path)


def _check_copies(archive: zipfile.ZipFile, online: object, estimator: zipfile.ZipFile,
                  path: Path) -> None:
    """Raise InputError naming ``path`` when a compiled array of :data:`COPIED_ARRAYS`
    (members of ``archive`` the ``online`` document names) is not one of the
    estimator's arrays stored in the skops archive ``estimator`` (a compiled classifier
    edited apart from its estimator and re-sealed)."""
    parts = online.get("parts") if isinstance(online, dict) else None
    # a malformed document (parts not a list) is left to read_online's one-line refusal
    prefixes = [part.get("prefix") for part in parts
                if isinstance(part, dict)] if isinstance(parts, list) else []
    stored: dict[str, Any] = {}
    for name in estimator.namelist():
        if name.endswith(".npy") and "/" not in name:
            with suppress(ValueError, OSError, EOFError):
                array = np.load(io.BytesIO(estimator.read(name)), allow_pickle=False)
                stored.setdefault(array.shape, []).append(array)
    for prefix in prefixes:
        for name in COPIED_ARRAYS:
            member = f"{prefix}{name}.npy"
            if not isinstance(prefix, str) or member not in archive.namelist():
                continue
            try:
                array = np.load(io.BytesIO(archive.read(member)), allow_pickle=False)
            except (ValueError, OSError, EOFError) as err:
                raise InputError(f"invalid compiled classifier in the model file ({member})",
                                 path) from err
            if not any(np.array_equal(array, other) for other in stored.get(array.shape, [])):
                raise InputError(f"the compiled classifier's {name} ({member}) is not the "
                                 "estimator's: the file was changed apart from its model",
                                 path)


def _load_lazily(path: Path) -> ModelFile:
    """Return the model of a skops file from its compiled arrays, its estimator left to
    be built on first use; a file that lacks arrays for one of its classifiers is
    loaded whole, from the bytes read once."""
    data, meta = read_verified(path)
    check_meta(meta, path)
    kind = _kind_of(meta, path)
    events = meta.get("events")
    names, classes = meta.get("feature_names"), meta["classes"]

    def build() -> object:
        return _check_classes(build_skops(data, kind.trusted_types, path), classes, path)

    if "online" not in meta or names is None or (events is not None
                                                  and "online" not in events):
        return ModelFile(build(), meta,
                         _check_classes(_load_event_estimator(path, meta),
                                        None if events is None else events["classes"], path,
                                        "event classifier"))
    check_compiled(data, meta, path)
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        online = read_online(meta["online"], archive.read, len(names), len(classes), path)
        event_online = (None if events is None else
                        read_online(events["online"], archive.read, len(events["features"]),
                                    len(events["classes"]), path))
    return ModelFile(None, meta, event_online, online=online, build_estimator=build)
