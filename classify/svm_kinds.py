"""The SVM kinds (``svm``, ``per-joint``, ``three-joint``): the estimators of
:mod:`contactkit.classify.models` registered with their checks, file format and fast
online predictor (:mod:`contactkit.classify.fast`)."""

from __future__ import annotations

from sklearn.pipeline import Pipeline

from contactkit.classify.data import FEATURES
from contactkit.classify.fast import fast_predictor
from contactkit.classify.kind import ModelKind, ModelOptions
from contactkit.classify.models import (
    ENSEMBLE_TRUSTED_TYPES,
    SVM_TRUSTED_TYPES,
    JointEnsemble,
    svm_pipeline,
)
from contactkit.classify.skops_format import SKOPS
from contactkit.schemas import InputError


def _check_c(options: ModelOptions) -> None:
    if not options.c > 0:
        raise InputError(f"the SVM regularisation C must be positive, got {options.c}")


def _svm(options: ModelOptions, feature_names: list[str]) -> Pipeline:
    return svm_pipeline(options.c, seed=options.seed)


def _per_joint(options: ModelOptions, feature_names: list[str]) -> JointEnsemble:
    return JointEnsemble(list(feature_names), span=1, c=options.c, seed=options.seed)


def _three_joint(options: ModelOptions, feature_names: list[str]) -> JointEnsemble:
    return JointEnsemble(list(feature_names), span=3, c=options.c, seed=options.seed)


SVM = ModelKind("svm", "whole-arm SVM on scalar features", FEATURES, _svm, SKOPS,
                check=_check_c, online=fast_predictor, trusted_types=SVM_TRUSTED_TYPES)
PER_JOINT = ModelKind("per-joint", "one SVM per joint, probabilities summed (eq. 4.1)",
                      FEATURES, _per_joint, SKOPS, check=_check_c, online=fast_predictor,
                      trusted_types=ENSEMBLE_TRUSTED_TYPES)
THREE_JOINT = ModelKind("three-joint", "SVMs on joint triples, summed (eq. 4.2)", FEATURES,
                        _three_joint, SKOPS, check=_check_c, online=fast_predictor,
                        trusted_types=PER_JOINT.trusted_types)
