"""Classifiers behind one scikit-learn interface: fit / predict / predict_proba.

* ``svm``: the whole-arm SVM, ``StandardScaler`` + ``SVC`` (RBF) in one Pipeline.
* ``per-joint``: the ensemble of Golz et al. as in thesis eq. 4.1: one SVM per joint
  on that joint's features, class probabilities summed over the 7 SVMs, argmax.
* ``three-joint``: thesis eq. 4.2: 5 SVMs on joints (j-1, j, j+1), j = 2..6, summed.

Each is a registered kind (:mod:`contactkit.classify.kinds.svm`).
Features that belong to no joint (for example ``range(f_x)``) are used by the
whole-arm SVM only. The ensembles' ``predict_proba`` returns the summed
probabilities divided by the number of members, so rows sum to 1 and the argmax is
eq. 4.1's.
"""

from __future__ import annotations

import re

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin, clone
from sklearn.calibration import CalibratedClassifierCV
from sklearn.model_selection import StratifiedKFold
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

from contactkit.schemas import InputError

JOINT_OF_FEATURE = re.compile(r"\((?:[a-z_]+)_(\d)\)$")


def svm_pipeline(c: float = 1.0, gamma: str | float = "scale", seed: int = 0,
                 probability: bool = True) -> Pipeline:
    """Return StandardScaler + RBF SVC. With ``probability`` its probabilities come from
    Platt scaling (sigmoid calibration on 5 internal folds, then one SVC on all the
    data: what ``SVC(probability=True)`` did, and what the thesis's predict_log_proba
    used); without, it only predicts labels, six times faster to fit (experiments)."""
    if not probability:
        return Pipeline([("scale", StandardScaler()),
                         ("svc", SVC(C=c, gamma=gamma, random_state=seed))])
    return Pipeline([("scale", StandardScaler()), ("svc", CalibratedSVC(c, gamma, seed))])


class CalibratedSVC(ClassifierMixin, BaseEstimator):
    """RBF SVC with Platt-scaled probabilities, calibrated on up to 5 stratified folds
    (fewer when the smallest class has fewer than 5 sessions, at least 2)."""

    def __init__(self, c: float = 1.0, gamma: str | float = "scale", seed: int = 0) -> None:
        self.c = c
        self.gamma = gamma
        self.seed = seed

    def fit(self, X: np.ndarray, y: np.ndarray) -> CalibratedSVC:
        """Fit the SVC on all of X and the sigmoid calibration on internal folds."""
        _, counts = np.unique(y, return_counts=True)
        folds = int(min(5, counts.min()))
        if folds < 2:
            raise InputError("every class needs at least 2 sessions in each training set "
                             "for probability estimates")
        svc = SVC(C=self.c, gamma=self.gamma, random_state=self.seed)
        cv = StratifiedKFold(folds, shuffle=True, random_state=self.seed)
        self.model_ = CalibratedClassifierCV(svc, method="sigmoid", cv=cv, ensemble=False)
        self.model_.fit(X, y)
        self.classes_ = self.model_.classes_
        return self

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Return calibrated class probabilities, columns in ``classes_`` order."""
        return self.model_.predict_proba(X)

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Return the most probable class."""
        return self.model_.predict(X)


def feature_joint(name: str) -> int | None:
    """Return the joint (1..7) a feature such as ``range(tau_3)`` belongs to, or None."""
    match = JOINT_OF_FEATURE.search(name)
    return int(match.group(1)) if match else None


class JointEnsemble(ClassifierMixin, BaseEstimator):
    """SVMs on subsets of joints whose class probabilities are summed (eqs. 4.1, 4.2).

    ``span`` 1 gives 7 per-joint SVMs; 3 gives 5 SVMs on consecutive joint triples.
    ``feature_names`` names the columns of X (to find each joint's columns).
    """

    def __init__(self, feature_names: list[str] | tuple[str, ...] = (), span: int = 1,
                 c: float = 1.0, seed: int = 0) -> None:
        self.feature_names = feature_names
        self.span = span
        self.c = c
        self.seed = seed

    def member_joints(self) -> list[tuple[int, ...]]:
        """Return the joints each member SVM sees."""
        if self.span == 1:
            return [(j,) for j in range(1, 8)]
        half = self.span // 2
        return [tuple(range(j - half, j + half + 1)) for j in range(1 + half, 8 - half)]

    def _columns(self, joints: tuple[int, ...]) -> np.ndarray:
        cols = [i for i, n in enumerate(self.feature_names) if feature_joint(n) in joints]
        if not cols:
            raise InputError(f"no per-joint features for joints {joints} (features like "
                             "range(tau_3) are needed)")
        return np.array(cols)

    def fit(self, X: np.ndarray, y: np.ndarray) -> JointEnsemble:
        """Fit one SVM per member on its joints' columns."""
        self.classes_ = np.unique(y)
        base = svm_pipeline(self.c, seed=self.seed)
        self.members_ = []
        for joints in self.member_joints():
            cols = self._columns(joints)
            self.members_.append((cols, clone(base).fit(X[:, cols], y)))
        return self

    def member_probabilities(self, X: np.ndarray) -> np.ndarray:
        """Return each member's class probabilities, shape (members, samples, classes)."""
        return np.stack([model.predict_proba(X[:, cols]) for cols, model in self.members_])

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Return the summed member probabilities divided by the number of members."""
        return self.member_probabilities(X).mean(axis=0)

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Return argmax over classes of the summed member probabilities (eq. 4.1)."""
        return self.classes_[np.argmax(self.member_probabilities(X).sum(axis=0), axis=1)]


