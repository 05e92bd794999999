"""Model files carry their SVMs compiled to arrays; a lazy load classifies from those.

The arrays give the same probabilities as the fitted estimator, for every SVM kind and
the event classifier; the estimator is built (through skops, with its checks) only
when asked for; a file without arrays (format 2) still loads; and arrays that do not
fit are refused in one line, also when the file's digest was recomputed to match.
"""

from __future__ import annotations

import io
import json
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from contactkit.classify.events.contact_events import EVENT_FEATURES, EventModel
from contactkit.classify.kinds.online_arrays import npy_bytes, read_npy
from contactkit.classify.kinds.registry import get_kind, make_estimator
from contactkit.classify.modelfile.model_file import load_model, save_model
from contactkit.classify.modelfile.skops_format import META_MEMBER, digest_of
from contactkit.classify.schemes import relabel
from contactkit.features.extract import SessionFeatures
from contactkit.features.window_features import WindowFeatures
from contactkit.schemas import InputError
from tests.fuzz_support import refused_or


@dataclass
class Rows:
    """Feature rows with the default features' names and the actions they were drawn for."""

    X: np.ndarray
    actions: np.ndarray
    names: list[str]

    def labels(self, scheme: str) -> np.ndarray:
        """Return the classes of the rows in ``scheme``."""
        return relabel(self.actions, scheme)


@pytest.fixture(scope="module")
def features() -> Rows:
    """Random rows, shifted per action (what matters is equality, not accuracy)."""
    names = list(SessionFeatures().get_feature_names_out())
    rng = np.random.default_rng(0)
    actions = np.array(["none", "bump", "adjust", "shove"] * 10)
    shift = np.searchsorted(["adjust", "bump", "none", "shove"], actions)[:, None]
    return Rows(rng.normal(size=(len(actions), len(names))) + shift, actions, names)


def _event_model() -> EventModel:
    rng = np.random.default_rng(3)
    X = rng.normal(size=(40, len(EVENT_FEATURES)))
    y = np.array(["bump", "shove"] * 20)
    estimator = make_estimator("svm", []).fit(X + (y == "shove")[:, None], y)
    return EventModel(estimator, list(estimator.classes_), 0.15, X.min(axis=0), X.max(axis=0))


def _save(features, tmp_path: Path, kind: str = "svm", scheme: str = "full",
          events: EventModel | None = None) -> tuple[Path, object]:
    y = features.labels(scheme)
    estimator = make_estimator(kind, features.names, c=10.0).fit(features.X, y)
    path = save_model(tmp_path / f"{kind}-{scheme}.skops", estimator,
                      transformer=SessionFeatures(), feature_names=features.names,
                      classes=list(estimator.classes_), kind=get_kind(kind), scheme=scheme,
                      fingerprint="", training={},
                      events=None if events is None else (events.estimator, events.meta()))
    return path, estimator


def _rows(features) -> np.ndarray:
    rng = np.random.default_rng(1)
    return features.X + rng.normal(size=features.X.shape) * features.X.std(axis=0)


def _rewrite(path: Path, target: Path, change) -> Path:
    """Copy a model file through ``change(members, meta)`` and sign it with a fresh digest
    (as anyone can: the digest tells a damaged file, not a forged one)."""
    with zipfile.ZipFile(path) as src:
        members = {n: src.read(n) for n in src.namelist()}
    meta = json.loads(members.pop(META_MEMBER))
    change(members, meta)
    meta["members_sha256"] = digest_of(members, meta)
    with zipfile.ZipFile(target, "w") as dst:
        for name, data in members.items():
            dst.writestr(name, data)
        dst.writestr(META_MEMBER, json.dumps(meta))
    return target


@pytest.mark.parametrize("kind", ["svm", "per-joint", "three-joint"])
@pytest.mark.parametrize("scheme", ["full", "reaction"])
def test_lazy_model_predicts_as_the_estimator(features, tmp_path: Path, kind: str,
                                              scheme: str) -> None:
    path, estimator = _save(features, tmp_path, kind, scheme)
    model = load_model(path, lazy=True)
    assert model.online is not None and model._estimator is None  # nothing built yet
    X = _rows(features)
    assert np.abs(model.online_predictor()(X) - estimator.predict_proba(X)).max() <= 1e-9
    assert isinstance(model.online_transformer(), WindowFeatures)
    assert model.online_transformer().config() == SessionFeatures().config()
    assert np.array_equal(model.estimator.predict(X), estimator.predict(X))  # built now


def test_lazy_event_model_decides_as_the_estimator(features, tmp_path: Path) -> None:
    events = _event_model()
    path, _ = _save(features, tmp_path, events=events)
    lazy, full = load_model(path, lazy=True).event_model(), load_model(path).event_model()
    X = np.random.default_rng(2).normal(size=(50, len(EVENT_FEATURES)))
    expected = events.estimator.predict_proba(X)
    assert np.abs(lazy.estimator.predict_proba(X) - expected).max() <= 1e-9
    assert np.abs(full.estimator.predict_proba(X) - expected).max() <= 1e-9
    assert lazy.classes == full.classes and np.array_equal(lazy.low, full.low)


def test_a_file_without_arrays_loads_its_estimator(features, tmp_path: Path) -> None:
    """Format 2 files have no arrays: a lazy load builds the estimator at once."""
    path, estimator = _save(features, tmp_path)

    def version_2(members: dict, meta: dict) -> None:
        for name in [n for n in members if n.startswith("online/")]:
            del members[name]
        del meta["online"]
        meta["format"] = "contactkit-model/2"

    old = _rewrite(path, tmp_path / "old.skops", version_2)
    model = load_model(old, lazy=True)
    assert model.online is None and model._estimator is not None
    X = _rows(features)
    assert np.abs(model.online_predictor()(X) - estimator.predict_proba(X)).max() <= 1e-9


def test_online_transformer_without_scikit_learn(tmp_path: Path) -> None:
    """The window features a replay uses import neither scikit-learn nor skops."""
    import subprocess

    probe = ("import sys\n"
             "from contactkit.features.window_features import window_features_from_config\n"
             "from contactkit.classify.modelfile.model_file import load_model\n"
             "print(sorted({m.split('.')[0] for m in sys.modules} & {'sklearn', 'skops', "
             "'scipy', 'pandas'}))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          check=True, timeout=300)
    assert proc.stdout.strip() == "[]"


def _array(name: str):
    def change(members: dict, meta: dict) -> None:
        members[f"online/0/{name}.npy"] = npy_bytes(np.zeros((2, 2)))
    return change


@pytest.mark.parametrize(("change", "problem"), [
    (_array("mean"), "'mean' has shape"),
    (_array("gamma"), "'gamma' has shape"),
    (lambda m, meta: m.__setitem__("online/0/a.npy", npy_bytes(np.array([np.nan] * 4))),
     "not finite"),
    (lambda m, meta: m.__setitem__("online/0/scale.npy", npy_bytes(np.zeros(21))),
     "'scale' holds a zero"),
    (lambda m, meta: m.pop("online/0/signs.npy"), "no item named"),
    (lambda m, meta: m.__setitem__("online/0/b.npy", b"\x93NUMPY junk"), "invalid compiled"),
    (lambda m, meta: meta["online"].__setitem__("form", "pickle"), "unknown form"),
    (lambda m, meta: meta["online"]["parts"][0].__setitem__("columns", [0, 99]),
     "columns outside"),
    (lambda m, meta: meta.__setitem__("classes", meta["classes"][:3]),
     "tells 4 classes apart, the model file names 3"),
])
def test_arrays_that_do_not_fit_are_refused(features, tmp_path: Path, change,
                                            problem: str) -> None:
    path, _ = _save(features, tmp_path)
    bad = _rewrite(path, tmp_path / "bad.skops", change)
    with pytest.raises(InputError, match=r"compiled classifier|fitted on other classes") as err:
        load_model(bad, lazy=True)
    # refused by the arrays' own checks, or, first, by their comparison with the estimator
    # the file also holds (check_compiled: arrays changed apart from the model)
    message = str(err.value)
    assert (problem in message or "is not the estimator's" in message
            or "fitted on other classes" in message) and "\n" not in message
    assert str(bad) in str(err.value)


def test_npy_reader_refuses_what_is_not_one_float_array() -> None:
    out = io.BytesIO()
    np.save(out, np.arange(3, dtype=np.int64))
    for data, problem in [(out.getvalue(), "expected float64"),
                          (npy_bytes(np.zeros(3))[:-8], "does not match"),
                          (npy_bytes(np.zeros(3)) + b"\0" * 8, "does not match")]:
        with pytest.raises(ValueError, match=problem):
            read_npy(data)
    huge = io.BytesIO()
    np.lib.format.write_array_header_1_0(huge, {"descr": "<f8", "fortran_order": False,
                                                "shape": (10**15,)})
    with pytest.raises(ValueError, match="does not match"):  # nothing allocated for it
        read_npy(huge.getvalue() + b"\0" * 24)


@pytest.fixture(scope="module")
def saved(features, tmp_path_factory) -> Path:
    return _save(features, tmp_path_factory.mktemp("saved"), events=_event_model())[0]


@given(name=st.sampled_from(["online/0/mean.npy", "online/0/support_vectors.npy",
                             "online/0/signs.npy", "events-online/0/a.npy"]),
       data=st.binary(max_size=200))
def test_fuzz_online_members(saved: Path, tmp_path_factory, name: str, data: bytes) -> None:
    target = tmp_path_factory.mktemp("fuzz") / "m.skops"
    bad = _rewrite(saved, target, lambda members, meta: members.__setitem__(name, data))
    model = refused_or(load_model, bad, lazy=True)
    if model is not None:  # accepted: it classifies rows of its width
        model.online_predictor()(np.zeros((1, len(model.feature_names))))


JSON = st.recursive(st.none() | st.booleans() | st.integers(-3, 30) | st.text(max_size=8),
                    lambda inner: st.lists(inner, max_size=3)
                    | st.dictionaries(st.text(max_size=8), inner, max_size=3), max_leaves=8)


@given(doc=JSON | st.fixed_dictionaries({"form": st.just("svm-mean/1"), "parts": JSON}))
def test_fuzz_online_document(saved: Path, tmp_path_factory, doc) -> None:
    target = tmp_path_factory.mktemp("fuzz") / "m.skops"
    bad = _rewrite(saved, target, lambda members, meta: meta.__setitem__("online", doc))
    refused_or(load_model, bad, lazy=True)
