"""Classifiers, protocols, schemes and model files on a small simulated dataset."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from sklearn.metrics import balanced_accuracy_score, f1_score, recall_score

from contactkit.classify.data import load_features
from contactkit.classify.evaluate import confusion, evaluate, metrics_from_confusion, splits
from contactkit.classify.kinds.registry import get_kind, make_estimator
from contactkit.classify.kinds.svm_estimators import JointEnsemble, feature_joint
from contactkit.classify.modelfile.model_file import load_model, save_model
from contactkit.classify.modelfile.skops_format import META_MEMBER
from contactkit.classify.schemes import limited_mask, relabel, scheme_classes
from contactkit.features.extract import SessionFeatures
from contactkit.schemas import InputError
from tests.conftest import make_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("static"))


@pytest.fixture(scope="module")
def features(dataset):
    return load_features([dataset], SessionFeatures(), workers=1)


def test_feature_set_and_cache(dataset, features) -> None:
    assert features.X.shape == (32, 21)
    assert sorted(set(features.groups("pose"))) == ["A", "B", "C", "D"]
    cached = load_features([dataset], SessionFeatures(), workers=1)
    assert np.array_equal(cached.X, features.X)
    assert not [p for p in dataset.iterdir() if not p.name.endswith(".parquet")]


def test_the_feature_cache_never_writes_into_a_dataset(tmp_path, monkeypatch) -> None:
    """The cache lived in DATASET/.cache: a read-only dataset failed with a traceback,
    and a .cache link planted in a dataset sent the cache file outside."""
    from tests.conftest import make_session

    monkeypatch.setenv("CONTACTKIT_CACHE", str(tmp_path / "cache"))
    data, outside = tmp_path / "data", tmp_path / "outside"
    data.mkdir()
    outside.mkdir()
    for seed, action in ((3, "none"), (4, "shove")):
        make_session(data, seed=seed, action=action, duration_s=3.0)
    (data / ".cache").symlink_to(outside)
    before = sorted(p.name for p in data.iterdir())
    first = load_features([data], SessionFeatures(), workers=1)
    again = load_features([data], SessionFeatures(), workers=1)
    assert np.array_equal(first.X, again.X)
    assert list(outside.iterdir()) == [] and sorted(p.name for p in data.iterdir()) == before
    assert len(list((tmp_path / "cache" / "features").glob("*.parquet"))) == 1


def test_per_joint_ensemble_sums_member_probabilities(features) -> None:
    y = features.labels()
    model = JointEnsemble(features.names, span=1).fit(features.X, y)
    members = model.member_probabilities(features.X)
    assert members.shape == (7, 32, 4)
    expected = model.classes_[np.argmax(members.sum(axis=0), axis=1)]
    assert np.array_equal(model.predict(features.X), expected)
    assert np.allclose(model.predict_proba(features.X).sum(axis=1), 1.0)
    three = JointEnsemble(features.names, span=3)
    assert three.member_joints() == [(1, 2, 3), (2, 3, 4), (3, 4, 5), (4, 5, 6), (5, 6, 7)]
    assert feature_joint("range(tau_3)") == 3 and feature_joint("range(f_x)") is None


def test_group_splits_never_share_a_group(features) -> None:
    y, groups = features.labels(), features.groups("pose")
    folds = splits("group", y, groups, 0)
    assert len(folds) == 4
    for train, test in folds:
        assert not set(groups[train]) & set(groups[test])
    sessions = features.groups("session")
    for train, test in splits("group", y, sessions, 0):
        assert not set(sessions[train]) & set(sessions[test])
    thesis = splits("thesis", y, None, 0)
    assert len(thesis) == 25 and all(len(test) == 7 for _, test in thesis)


def test_metrics_match_scikit_learn() -> None:
    rng = np.random.default_rng(3)
    classes = ["none", "bump", "adjust", "shove"]
    y = rng.choice(classes, 200)
    p = np.where(rng.random(200) < 0.7, y, rng.choice(classes, 200))
    m = metrics_from_confusion(confusion(y, p, classes))
    assert m["balanced_accuracy"] == pytest.approx(balanced_accuracy_score(y, p))
    assert m["macro_f1"] == pytest.approx(f1_score(y, p, average="macro", labels=classes))
    assert m["recall"] == pytest.approx(list(recall_score(y, p, average=None, labels=classes)))


@pytest.mark.parametrize("kind", ["svm", "per-joint", "three-joint"])
def test_evaluate_reports_everything(features, kind) -> None:
    y = features.labels()
    report = evaluate(features.X, y, lambda: make_estimator(kind, features.names), protocol="group",
                      groups=features.groups("pose"), group_by="pose", model=kind,
                      classes=scheme_classes("full"))
    assert report.n_splits == 4 and report.n_sessions == 32
    for interval in (report.accuracy, report.balanced_accuracy, report.macro_f1):
        assert interval.low <= interval.value <= interval.high
    # every figure is the pooled out-of-fold predictions' own, as scikit-learn computes it
    predicted = report.out_of_fold
    classes = scheme_classes("full")
    assert report.accuracy.value == pytest.approx(np.mean(predicted == y))
    assert report.balanced_accuracy.value == pytest.approx(
        balanced_accuracy_score(y, predicted))
    assert report.macro_f1.value == pytest.approx(
        f1_score(y, predicted, average="macro", labels=classes))
    recall = recall_score(y, predicted, average=None, labels=classes)
    assert [report.recall[c].value for c in classes] == pytest.approx(list(recall))
    assert report.confusion_counts == confusion(y, predicted, classes).tolist()
    groups = features.groups("pose")
    per_split = [np.mean(predicted[groups == g] == y[groups == g]) for g in "ABCD"]
    assert report.split_accuracies == pytest.approx(per_split)
    assert report.split_accuracy_mean == pytest.approx(np.mean(per_split))
    assert np.allclose(np.sum(report.confusion_normalised, axis=1), 1.0)
    again = evaluate(features.X, y, lambda: make_estimator(kind, features.names),
                     protocol="group", groups=groups, group_by="pose", model=kind,
                     classes=classes)
    assert again.as_dict() == report.as_dict()


def test_schemes_and_limited_context() -> None:
    actions = np.array(["none", "bump", "adjust", "shove"])
    assert list(relabel(actions, "reaction")) == ["none", "none", "adjust", "shove"]
    assert list(relabel(actions, "contact")) == ["none", "contact", "contact", "contact"]
    assert list(relabel(actions, "intentional")) == ["none", "none", "intentional",
                                                     "intentional"]
    conditions = np.array(["static", "dynamic", "dynamic", "static"])
    assert list(limited_mask(actions, conditions)) == [True, True, False, False]
    with pytest.raises(InputError, match="unknown class scheme"):
        relabel(actions, "vibes")


def test_model_file_round_trip_and_refusals(features, tmp_path: Path) -> None:
    y = features.labels()
    model = make_estimator("per-joint", features.names).fit(features.X, y)
    path = save_model(tmp_path / "m.skops", model, transformer=SessionFeatures(),
                      feature_names=features.names, classes=list(model.classes_),
                      kind=get_kind("per-joint"), scheme="full", fingerprint=features.fingerprint(),
                      training={})
    loaded = load_model(path)
    assert np.array_equal(loaded.estimator.predict(features.X), model.predict(features.X))
    assert loaded.meta["versions"]["scikit-learn"]
    with pytest.raises(InputError, match="other features"):
        loaded.check_features(features.names[::-1])
    with pytest.raises(InputError, match="already exists"):
        save_model(path, model, transformer=SessionFeatures(), feature_names=features.names,
                   classes=[], kind=get_kind("svm"), scheme="full", fingerprint="", training={})

    def rewrite(target: Path, change) -> Path:
        with zipfile.ZipFile(path) as src, zipfile.ZipFile(target, "w") as dst:
            for name in src.namelist():
                data = change(name, src.read(name))
                if data is not None:
                    dst.writestr(name, data)
        return target

    npy = next(n for n in zipfile.ZipFile(path).namelist() if n.endswith(".npy"))
    tampered = rewrite(tmp_path / "t.skops",
                       lambda n, d: d[:-8] + b"\x00" * 8 if n == npy else d)
    with pytest.raises(InputError, match="modified after it was written"):
        load_model(tampered)
    stripped = rewrite(tmp_path / "s.skops", lambda n, d: None if n == META_MEMBER else d)
    with pytest.raises(InputError, match="not a contactkit model file"):
        load_model(stripped)
    junk = tmp_path / "junk.skops"
    junk.write_bytes(b"PK not really")
    with pytest.raises(InputError, match="not a contactkit model file"):
        load_model(junk)


def test_model_file_as_untrusted_input(features, tmp_path: Path) -> None:
    """A relabelled contactkit.json, a zip bomb and flipped bytes: each one line."""
    from contactkit.classify.modelfile import skops_format

    model = make_estimator("svm", features.names).fit(features.X, features.labels())
    path = save_model(tmp_path / "m.skops", model, transformer=SessionFeatures(),
                      feature_names=features.names, classes=list(model.classes_),
                      kind=get_kind("svm"), scheme="full", fingerprint="", training={})
    with zipfile.ZipFile(path) as src:
        members = {n: src.read(n) for n in src.namelist()}
    meta = json.loads(members[META_MEMBER])
    meta["classes"] = meta["classes"][::-1]
    relabelled = tmp_path / "relabelled.skops"
    with zipfile.ZipFile(relabelled, "w") as dst:
        for name, data in members.items():
            dst.writestr(name, json.dumps(meta) if name == META_MEMBER else data)
    with pytest.raises(InputError, match="modified after it was written"):
        load_model(relabelled)
    bomb = tmp_path / "bomb.skops"
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as dst:
        for name, data in members.items():
            dst.writestr(name, data)
        dst.writestr("big.npy", b"\0" * (skops_format.MAX_MEMBER_BYTES + 1))
    assert bomb.stat().st_size < 2_000_000
    with pytest.raises(InputError, match="would decompress"):
        load_model(bomb)
    data = path.read_bytes()
    for offset in range(0, len(data), max(1, len(data) // 97)):
        flipped = tmp_path / "flipped.skops"
        flipped.write_bytes(data[:offset] + bytes([data[offset] ^ 0xFF]) + data[offset + 1:])
        try:
            load_model(flipped)
        except InputError as err:
            assert "\n" not in str(err)


def test_model_file_refuses_untrusted_types(features, tmp_path: Path) -> None:
    import skops.io as sio
    from sklearn.base import BaseEstimator

    from contactkit.classify.modelfile.skops_format import FORMAT
    from contactkit.classify.modelfile.skops_format import members_digest as _members_digest

    class Smuggled(BaseEstimator):
        pass

    payload = sio.dumps(Smuggled())
    meta = {"format": FORMAT, "kind": "svm"}
    with zipfile.ZipFile(io.BytesIO(payload)) as archive:
        members = {n: archive.read(n) for n in archive.namelist()}
        digest = _members_digest(archive, meta)
    evil = tmp_path / "evil.skops"
    with zipfile.ZipFile(evil, "w") as out:
        for name, data in members.items():
            out.writestr(name, data)
        out.writestr(META_MEMBER, json.dumps(meta | {"members_sha256": digest}))
    with pytest.raises(InputError, match="untrusted types"):
        load_model(evil)


@pytest.mark.parametrize("kind", ["svm", "per-joint", "three-joint"])
@pytest.mark.parametrize("scheme", ["full", "contact", "reaction"])
def test_fast_online_predictor_equals_scikit_learn(features, kind, scheme) -> None:
    from contactkit.classify.kinds.fast import fast_predictor

    y = features.labels(scheme)
    model = make_estimator(kind, features.names, c=10.0).fit(features.X, y)
    rng = np.random.default_rng(1)
    X = features.X + rng.normal(size=features.X.shape) * features.X.std(axis=0)
    assert np.abs(fast_predictor(model)(X) - model.predict_proba(X)).max() <= 1e-9
