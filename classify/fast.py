"""A fast predict path for one window at a time (the online classifier).

scikit-learn spends about a millisecond checking its input on every call, far more
than an RBF SVM needs to classify one feature vector. :func:`fast_predictor` reads
the fitted parameters of our SVM pipeline (StandardScaler, SVC, sigmoid
calibration) once and evaluates the same formulas with numpy:

* the RBF kernel exp(-gamma |x - sv|^2) against the support vectors;
* libsvm's one-vs-one decision values, turned into scikit-learn's one-vs-rest
  decision function (votes plus bounded confidences, ``_ovr_decision_function``);
* per class the sigmoid 1 / (1 + exp(a f + b)), normalised over the classes
  (binary: p and 1 - p).

The support vectors' dual coefficients, intercepts and the resolved gamma are
read from SVC's private ``_dual_coef_``, ``_intercept_``, ``_gamma`` and
``_n_support`` (libsvm's own order and signs; the public ones are flipped for two
classes, and ``gamma="scale"`` is resolved only privately), so pyproject.toml bounds
scikit-learn to the versions tested. A test holds the output equal to scikit-learn's
``predict_proba`` to 1e-9 for every SVM kind and class scheme; models it does not
know (networks, ONNX) keep their own ``predict_proba``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from sklearn.pipeline import Pipeline

from contactkit.classify.models import CalibratedSVC, JointEnsemble


class _CompiledSVM:
    def __init__(self, pipeline: Pipeline) -> None:
        scaler = pipeline.named_steps["scale"]
        calibrated = pipeline.named_steps["svc"].model_.calibrated_classifiers_[0]
        svc = calibrated.estimator
        self.mean, self.scale = scaler.mean_, scaler.scale_
        self.sv = svc.support_vectors_
        self.sv_sq = np.einsum("ij,ij->i", self.sv, self.sv)
        self.gamma = float(svc._gamma)
        self.dual = svc._dual_coef_
        self.intercept = svc._intercept_
        counts = svc._n_support
        self.starts = np.concatenate([[0], np.cumsum(counts)])
        self.n = len(svc.classes_)
        self.a = np.array([c.a_ for c in calibrated.calibrators])
        self.b = np.array([c.b_ for c in calibrated.calibrators])
        # One-vs-one as matrices: decision values = kernel @ pair_weights + intercept, and
        # each pair's value goes to its two classes' confidence with signs +1 / -1.
        pairs = [(i, j) for i in range(self.n) for j in range(i + 1, self.n)]
        self.pair_weights = np.zeros((len(self.sv), len(pairs)))
        self.signs = np.zeros((len(pairs), self.n))
        for p, (i, j) in enumerate(pairs):
            si = slice(self.starts[i], self.starts[i + 1])
            sj = slice(self.starts[j], self.starts[j + 1])
            self.pair_weights[si, p] = self.dual[j - 1, si]
            self.pair_weights[sj, p] = self.dual[i, sj]
            self.signs[p, i], self.signs[p, j] = 1.0, -1.0
        self.winners = np.maximum(self.signs, 0.0)  # the class a pair's vote goes to if >= 0
        self.losers = np.maximum(-self.signs, 0.0)  # ... and if < 0

    def __call__(self, X: np.ndarray) -> np.ndarray:
        z = (np.asarray(X, dtype=float) - self.mean) / self.scale
        d2 = self.sv_sq[None, :] - 2.0 * z @ self.sv.T + np.einsum("ij,ij->i", z, z)[:, None]
        kernel = np.exp(-self.gamma * np.maximum(d2, 0.0))
        dec = kernel @ self.pair_weights + self.intercept
        if self.n == 2:
            f = -dec
            proba1 = 1.0 / (1.0 + np.exp(self.a[0] * f[:, 0] + self.b[0]))
            return np.column_stack([1.0 - proba1, proba1])
        confidence = dec @ self.signs
        positive = dec >= 0
        votes = positive @ self.winners + ~positive @ self.losers
        f = votes + confidence / (3.0 * (np.abs(confidence) + 1.0))
        proba = 1.0 / (1.0 + np.exp(self.a * f + self.b))
        total = proba.sum(axis=1, keepdims=True)
        return np.where(total > 0, proba / np.where(total > 0, total, 1.0), 1.0 / self.n)


def _is_our_svm(estimator) -> bool:
    return isinstance(estimator, Pipeline) and isinstance(estimator.named_steps.get("svc"),
                                                          CalibratedSVC)


def fast_predictor(estimator) -> Callable[[np.ndarray], np.ndarray]:
    """Return a function X -> class probabilities equal to ``estimator.predict_proba``."""
    if _is_our_svm(estimator):
        return _CompiledSVM(estimator)
    if isinstance(estimator, JointEnsemble) and all(_is_our_svm(m) for _, m in
                                                    estimator.members_):
        members = [(cols, _CompiledSVM(m)) for cols, m in estimator.members_]
        return lambda X: np.mean([f(np.asarray(X)[:, cols]) for cols, f in members], axis=0)
    return estimator.predict_proba
