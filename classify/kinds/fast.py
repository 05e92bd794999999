"""A fast predict path for one window at a time (the online classifier), and its arrays.

scikit-learn spends about a millisecond checking its input on every call, far more
than an RBF SVM needs to classify one feature vector. :func:`compile_estimator` reads
the fitted parameters of our SVM pipeline (StandardScaler, SVC, sigmoid
calibration) once into a :class:`CompiledSVM`, which evaluates the same formulas with
numpy:

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

A compiled model is plain arrays (:meth:`CompiledSVM.arrays`), which model files carry
beside the estimator (:mod:`contactkit.classify.kinds.online_arrays`), so a replay classifies
without importing scikit-learn. This module imports scikit-learn only to compile a
fitted estimator.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

SVM_ARRAYS = ("mean", "scale", "support_vectors", "gamma", "pair_weights", "intercept",
              "signs", "a", "b")
"""The arrays of a :class:`CompiledSVM`, by name."""


class CompiledSVM:
    """Scaler + RBF SVC + sigmoid calibration as arrays: ``predict_proba(X)`` returns the
    class probabilities (rows of X, classes in the fitted order).

    ``arrays`` holds :data:`SVM_ARRAYS`: the scaler's ``mean`` and ``scale`` (features,),
    the ``support_vectors`` (m, features), ``gamma`` (a scalar), ``pair_weights``
    (m, pairs) and ``intercept`` (pairs,) of the one-vs-one decision values, ``signs``
    (pairs, classes): +1 for the class a pair's positive value votes for, -1 for the
    other, and the calibration's ``a`` and ``b`` (classes; one for two classes).
    Shapes and values are checked (ValueError naming the array)."""

    def __init__(self, arrays: Mapping[str, np.ndarray]) -> None:
        missing = [name for name in SVM_ARRAYS if name not in arrays]
        if missing:
            raise ValueError(f"compiled SVM lacks array {missing[0]!r}")
        a = {name: np.asarray(arrays[name]) for name in SVM_ARRAYS}
        for name, value in a.items():
            if value.dtype.kind != "f" or not np.isfinite(value).all():
                raise ValueError(f"compiled SVM array {name!r} is not finite floats")
        n = _check_shapes(a)
        self.mean, self.scale, self.sv = a["mean"], a["scale"], a["support_vectors"]
        self.gamma = float(a["gamma"])
        self.pair_weights, self.intercept, self.signs = (a["pair_weights"], a["intercept"],
                                                         a["signs"])
        self.a, self.b = a["a"], a["b"]
        self.n = n
        self.sv_sq = np.einsum("ij,ij->i", self.sv, self.sv)
        self.winners = np.maximum(self.signs, 0.0)  # the class a pair's vote goes to if >= 0
        self.losers = np.maximum(-self.signs, 0.0)  # ... and if < 0

    @property
    def n_features(self) -> int:
        """The number of input features."""
        return len(self.mean)

    def arrays(self) -> dict[str, np.ndarray]:
        """Return the arrays this SVM is made of (:data:`SVM_ARRAYS`)."""
        return {"mean": self.mean, "scale": self.scale, "support_vectors": self.sv,
                "gamma": np.asarray(self.gamma), "pair_weights": self.pair_weights,
                "intercept": self.intercept, "signs": self.signs, "a": self.a, "b": self.b}

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Return the class probabilities (rows, classes) of the feature rows ``X``."""
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

    __call__ = predict_proba


def _check_shapes(a: Mapping[str, np.ndarray]) -> int:
    """Return the number of classes of a compiled SVM's arrays, or raise ValueError
    naming the first array whose shape does not fit the others."""
    sv, signs = a["support_vectors"], a["signs"]
    if sv.ndim != 2 or signs.ndim != 2 or signs.shape[1] < 2:
        raise ValueError("compiled SVM arrays 'support_vectors' and 'signs' must be "
                         "matrices, with at least two classes")
    (m, features), (pairs, n) = sv.shape, signs.shape
    expected = {"mean": (features,), "scale": (features,), "gamma": (),
                "pair_weights": (m, pairs), "intercept": (pairs,),
                "a": (1 if n == 2 else n,), "b": (1 if n == 2 else n,)}
    for name, shape in expected.items():
        if a[name].shape != shape:
            raise ValueError(f"compiled SVM array {name!r} has shape {a[name].shape}, "
                             f"expected {shape}")
    if pairs != n * (n - 1) // 2:
        raise ValueError(f"compiled SVM has {pairs} class pairs for {n} classes")
    if not (a["scale"] != 0).all():
        raise ValueError("compiled SVM array 'scale' holds a zero")
    return n


class CompiledEnsemble:
    """The mean of compiled SVMs, each on its own feature ``columns`` (an ensemble over
    joints, eq. 4.1 and 4.2): ``predict_proba(X)`` returns the class probabilities."""

    def __init__(self, members: Sequence[tuple[np.ndarray, CompiledSVM]]) -> None:
        if not members:
            raise ValueError("a compiled ensemble needs at least one member")
        self.members = [(np.asarray(cols, dtype=np.intp), svm) for cols, svm in members]

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Return the class probabilities (rows, classes) of the feature rows ``X``."""
        X = np.asarray(X)
        return np.mean([svm.predict_proba(X[:, cols]) for cols, svm in self.members], axis=0)

    __call__ = predict_proba


Compiled = CompiledSVM | CompiledEnsemble


def _compile_svm(pipeline) -> CompiledSVM:
    """Return the arrays of our fitted SVM pipeline (scale, svc) as a CompiledSVM."""
    scaler = pipeline.named_steps["scale"]
    calibrated = pipeline.named_steps["svc"].model_.calibrated_classifiers_[0]
    svc = calibrated.estimator
    dual, starts = svc._dual_coef_, np.concatenate([[0], np.cumsum(svc._n_support)])
    n = len(svc.classes_)
    # One-vs-one as matrices: decision values = kernel @ pair_weights + intercept, and
    # each pair's value goes to its two classes' confidence with signs +1 / -1.
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    pair_weights = np.zeros((len(svc.support_vectors_), len(pairs)))
    signs = np.zeros((len(pairs), n))
    for p, (i, j) in enumerate(pairs):
        si = slice(starts[i], starts[i + 1])
        sj = slice(starts[j], starts[j + 1])
        pair_weights[si, p] = dual[j - 1, si]
        pair_weights[sj, p] = dual[i, sj]
        signs[p, i], signs[p, j] = 1.0, -1.0
    return CompiledSVM({
        "mean": scaler.mean_, "scale": scaler.scale_, "support_vectors": svc.support_vectors_,
        "gamma": np.asarray(float(svc._gamma)), "pair_weights": pair_weights,
        "intercept": np.asarray(svc._intercept_, dtype=float), "signs": signs,
        "a": np.array([c.a_ for c in calibrated.calibrators], dtype=float),
        "b": np.array([c.b_ for c in calibrated.calibrators], dtype=float)})


def compile_estimator(estimator) -> Compiled | None:
    """Return the compiled form of our SVM pipeline or of a joint ensemble of them (equal
    to its ``predict_proba`` to 1e-9), or None for an estimator it does not know."""
    if isinstance(estimator, CompiledSVM | CompiledEnsemble):
        return estimator
    from sklearn.pipeline import Pipeline

    from contactkit.classify.kinds.svm_estimators import CalibratedSVC, JointEnsemble

    def ours(model) -> bool:
        return isinstance(model, Pipeline) and isinstance(model.named_steps.get("svc"),
                                                          CalibratedSVC)

    if ours(estimator):
        return _compile_svm(estimator)
    if isinstance(estimator, JointEnsemble) and all(ours(m) for _, m in estimator.members_):
        return CompiledEnsemble([(cols, _compile_svm(m)) for cols, m in estimator.members_])
    return None


def fast_predictor(estimator) -> Callable[[np.ndarray], np.ndarray]:
    """Return a function X -> class probabilities equal to ``estimator.predict_proba``."""
    compiled = compile_estimator(estimator)
    return estimator.predict_proba if compiled is None else compiled.predict_proba
