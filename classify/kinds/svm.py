"""The SVM kinds (``svm``, ``per-joint``, ``three-joint``): the estimators of
:mod:`contactkit.classify.kinds.svm_estimators` declared with their parameter, file format and fast
online predictor (:mod:`contactkit.classify.kinds.fast`).

This module imports neither scikit-learn nor the feature chain: the estimators are
built, and the online predictor compiled, by functions that import them when called.
"""

from __future__ import annotations

from typing import Any

from contactkit.classify.kinds.inputs import FEATURES
from contactkit.classify.kinds.kind import ModelKind, ModelOptions, lazy
from contactkit.classify.modelfile.skops_format import SKOPS
from contactkit.util.params import Interval, Param

C = Param("c", float, 1.0, "SVM regularisation C.", constraints=(Interval(0, None, "neither"),),
          flag="C")
"""The regularisation every SVM kind takes (``--C``)."""
SVM_TRUSTED_TYPES = ("contactkit.classify.kinds.svm_estimators.CalibratedSVC",
                     # its name in model files written before classify/ had subpackages
                     "contactkit.classify.models.CalibratedSVC")
"""The estimator types an SVM's skops file may build beyond scikit-learn's."""
ENSEMBLE_TRUSTED_TYPES = (*SVM_TRUSTED_TYPES,
                          "contactkit.classify.kinds.svm_estimators.JointEnsemble",
                          "contactkit.classify.models.JointEnsemble")
"""The estimator types an ensemble's skops file may build beyond scikit-learn's."""


def _svm(options: ModelOptions, feature_names: list[str]) -> Any:
    """Return StandardScaler + calibrated RBF SVC (a scikit-learn Pipeline)."""
    from contactkit.classify.kinds.svm_estimators import svm_pipeline

    return svm_pipeline(options.params["c"], seed=options.seed)


def _ensemble(span: int, options: ModelOptions, feature_names: list[str]) -> Any:
    """Return the joint ensemble of SVMs on ``span`` consecutive joints each."""
    from contactkit.classify.kinds.svm_estimators import JointEnsemble

    return JointEnsemble(list(feature_names), span=span, c=options.params["c"],
                         seed=options.seed)


def _per_joint(options: ModelOptions, feature_names: list[str]) -> Any:
    """Return one SVM per joint, probabilities summed (eq. 4.1)."""
    return _ensemble(1, options, feature_names)


def _three_joint(options: ModelOptions, feature_names: list[str]) -> Any:
    """Return SVMs on joint triples, probabilities summed (eq. 4.2)."""
    return _ensemble(3, options, feature_names)


_FAST = lazy("contactkit.classify.kinds.fast:fast_predictor")
SVM = ModelKind("svm", "whole-arm SVM on scalar features", FEATURES, _svm, SKOPS, params=(C,),
                online=_FAST, trusted_types=SVM_TRUSTED_TYPES)
PER_JOINT = ModelKind("per-joint", "one SVM per joint, probabilities summed (eq. 4.1)",
                      FEATURES, _per_joint, SKOPS, params=(C,), online=_FAST,
                      trusted_types=ENSEMBLE_TRUSTED_TYPES)
THREE_JOINT = ModelKind("three-joint", "SVMs on joint triples, summed (eq. 4.2)", FEATURES,
                        _three_joint, SKOPS, params=(C,), online=_FAST,
                        trusted_types=ENSEMBLE_TRUSTED_TYPES)
