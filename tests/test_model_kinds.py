"""A new classifier is one module and one registry line: a tiny kind registered here goes
through train, predict and replay without any change to those."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import numpy as np
import pytest
from sklearn.base import BaseEstimator, ClassifierMixin

from contactkit.classify import registry
from contactkit.classify.data import FEATURES
from contactkit.classify.kind import ModelKind, ModelOptions
from contactkit.classify.modelfile import load_model
from contactkit.classify.prediction import predict_sources
from contactkit.classify.skops_format import SKOPS
from contactkit.classify.training import evaluate_kind, train
from contactkit.replay.session_replay import replay_session
from contactkit.schemas import InputError
from tests.conftest import make_dataset


class NearestMean(ClassifierMixin, BaseEstimator):
    """Class probabilities from the softmax of minus the distance to each class mean."""

    def fit(self, X: np.ndarray, y: np.ndarray) -> NearestMean:
        self.classes_ = np.unique(y)
        self.scale_ = X.std(axis=0) + 1e-9
        self.means_ = np.stack([X[y == c].mean(axis=0) for c in self.classes_]) / self.scale_
        return self

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        d = np.linalg.norm(X[:, None, :] / self.scale_ - self.means_[None], axis=2)
        e = np.exp(-(d - d.min(axis=1, keepdims=True)))
        return e / e.sum(axis=1, keepdims=True)

    def predict(self, X: np.ndarray) -> np.ndarray:
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]


def _nearest_mean(options: ModelOptions, feature_names: list[str]) -> NearestMean:
    return NearestMean()


TINY = ModelKind("nearest-mean", "distance to class means", FEATURES, _nearest_mean, SKOPS,
                 default_window="planned",
                 trusted_types=(f"{NearestMean.__module__}.{NearestMean.__qualname__}",))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("tiny"), poses=("A", "B"), repeats=1)


@pytest.fixture
def tiny_kind():
    registry.register(TINY)
    yield TINY
    registry.unregister(TINY.name)


def test_a_registered_kind_trains_predicts_and_replays(dataset, tiny_kind, tmp_path) -> None:
    options = ModelOptions(kind="nearest-mean")
    trained = train([dataset], tmp_path / "tiny.skops", options)
    assert trained.kind == "nearest-mean" and trained.sessions == 8
    assert trained.classes == ["adjust", "bump", "none", "shove"]
    model = load_model(trained.path)
    assert model.kind is TINY and model.transformer().window == "planned"
    sessions = sorted(dataset.glob("*.parquet"))
    predictions, problems = predict_sources(model, sessions)
    assert not problems and len(predictions) == 8
    # the tiny model was fitted on these sessions: it reproduces most of their actions
    hits = sum(p.predicted == p.recorded for p in predictions)
    assert hits >= 6
    for p in predictions:
        assert sum(p.probabilities.values()) == pytest.approx(1.0)
    rrd = tmp_path / "tiny.rrd"
    summary = replay_session(sessions[0], model, save=rrd)
    assert summary.saved == rrd and rrd.stat().st_size > 10_000
    assert summary.offline.label == predictions[0].predicted
    assert len(summary.pred_t) > 10 and set(summary.pred_label) <= set(trained.classes)


def test_evaluate_takes_any_kind(dataset, tiny_kind) -> None:
    report, problems = evaluate_kind([dataset], ModelOptions(kind="nearest-mean"),
                                     protocol="group", group="pose")
    assert not problems and report.model == "nearest-mean"
    assert report.n_splits == 2 and report.n_sessions == 8
    assert 0.0 <= report.balanced_accuracy.value <= 1.0


def test_a_kind_from_an_entry_point(monkeypatch) -> None:
    point = importlib.metadata.EntryPoint(name="nearest-mean", group="contactkit.models",
                                          value=f"{__name__}:TINY")
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group: [point] if group == "contactkit.models" else [])
    monkeypatch.setattr(registry, "_entry_points_loaded", False)
    try:
        assert "nearest-mean" in registry.kind_names()
        assert registry.get_kind("nearest-mean") is TINY
    finally:
        registry.unregister("nearest-mean")


def test_unknown_kind_and_model_file_of_a_missing_kind(dataset, tiny_kind, tmp_path) -> None:
    with pytest.raises(InputError, match="unknown model 'forest'"):
        registry.get_kind("forest")
    with pytest.raises(InputError, match="already registered"):
        registry.register(ModelKind("svm", "", FEATURES, _nearest_mean, SKOPS))
    path = train([dataset], tmp_path / "tiny.skops", ModelOptions(kind="nearest-mean")).path
    registry.unregister(TINY.name)
    with pytest.raises(InputError, match="is the package that provides it installed"):
        load_model(path)
