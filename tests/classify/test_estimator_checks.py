"""The project's scikit-learn estimators meet scikit-learn's own estimator checks
(``parametrize_with_checks``), and each check an estimator does not pass is listed with
the reason it does not apply.

Two reasons cover most of them:

* The classifiers validate no input of their own: they sit behind the model kinds'
  pipelines (``svm_pipeline`` puts a ``StandardScaler``, which validates X, before the
  SVC) and the training code, which gives them finite float arrays and labels of the
  class scheme with at least two sessions per class; a model file holds only fitted
  estimators. So sparse, complex, NaN, empty, 1-D or object inputs, continuous or 2-D
  labels and unfitted use are not refused with scikit-learn's messages.
* Several take other inputs than the checks' 2-D arrays: the window-feature and grid
  transformers take sessions (paths or :class:`Session`), the networks and MiniRocket
  grids (sessions, channels, steps), and :class:`JointEnsemble` the columns its
  ``feature_names`` name. Every check that fits on the checks' data fails for them at
  that data's shape; the API checks (parameters, cloning, ``__init__`` that only
  stores, repr, tags, pickling unfitted) still run and pass.

Changing these estimators' validation would change what they raise on bad input, which
this step of the work (issue 36) leaves alone. The fast classifier and the
transformers run by default; JointEnsemble (seven calibrated SVMs per fit) and the nn
extra's estimators are marked slow (and nn).
"""

from __future__ import annotations

import inspect
from importlib.util import find_spec

import pytest
from sklearn.utils.estimator_checks import parametrize_with_checks

from contactkit.classify.grids import SessionGrids
from contactkit.classify.kinds.minirocket import MiniRocketClassifier
from contactkit.classify.kinds.networks import CNNClassifier, LSTMClassifier
from contactkit.classify.kinds.svm_estimators import CalibratedSVC, JointEnsemble
from contactkit.features.extract import SessionFeatures

if "expected_failed_checks" not in inspect.signature(parametrize_with_checks).parameters:
    pytest.skip("scikit-learn >= 1.6 lists expected failed checks", allow_module_level=True)

NO_VALIDATION = {
    "check_estimators_unfitted": "predict before fit raises AttributeError, not "
                                 "NotFittedError: a model file holds fitted estimators only",
    "check_transformers_unfitted": "transform needs no fitting (the features are computed "
                                   "from each session alone)",
    "check_n_features_in_after_fitting": "n_features_in_ is not recorded: the pipeline's "
                                         "StandardScaler checks the width",
    "check_n_features_in": "n_features_in_ is not recorded: the pipeline's StandardScaler "
                           "checks the width",
    "check_estimator_sparse_tag": "sparse input is not refused: features are dense arrays",
    "check_estimator_sparse_array": "sparse input is not refused with scikit-learn's "
                                    "message: features are dense arrays",
    "check_estimator_sparse_matrix": "sparse input is not refused with scikit-learn's "
                                     "message: features are dense arrays",
    "check_classifier_data_not_an_array": "array-likes are not converted: the training "
                                          "code gives arrays",
    "check_classifiers_regression_target": "continuous labels are not refused: labels come "
                                           "from the class scheme",
    "check_supervised_y_2d": "a column-vector y is not raveled: labels come as 1-D arrays",
    "check_fit2d_1sample": "too few sessions are refused with the project's own message "
                           "(every class needs 2 sessions for calibration)",
    "check_fit2d_1feature": "too few values are refused with another message than "
                            "scikit-learn's",
    "check_requires_y_none": "fit without labels fails with another message than "
                             "scikit-learn's",
    "check_classifiers_one_label": "one class is refused before training "
                                   "(check_two_classes), not by the estimator",
    "check_complex_data": "complex values are not refused: the feature chain gives floats",
    "check_dtype_object": "object arrays are not refused: the feature chain gives floats",
    "check_estimators_empty_data_messages": "empty input is not refused with "
                                            "scikit-learn's message",
    "check_estimators_nan_inf": "NaN and inf are not refused: the feature chain gives "
                                "finite values",
    "check_fit1d": "1-D X is not refused with scikit-learn's message",
}

SESSIONS = "X is a list of sessions (paths or Session objects), not the check's array"
GRIDS = "X is a grid array (sessions, channels, steps), not the check's 2-D array"
COLUMNS = ("X's columns must be the ones feature_names names (per-joint features such "
           "as range(tau_3)); the check's data have other widths")

FAILING = {
    CalibratedSVC: (None, [
        "check_estimators_unfitted", "check_n_features_in_after_fitting",
        "check_estimator_sparse_tag", "check_classifier_data_not_an_array",
        "check_classifiers_regression_target", "check_supervised_y_2d",
        "check_fit2d_1sample", "check_n_features_in", "check_requires_y_none"]),
    JointEnsemble: (COLUMNS, [
        "check_classifier_data_not_an_array", "check_classifiers_classes",
        "check_classifiers_regression_target", "check_classifiers_train",
        "check_dict_unchanged", "check_dont_overwrite_parameters",
        "check_estimator_sparse_array", "check_estimator_sparse_matrix",
        "check_estimators_dtypes", "check_estimators_empty_data_messages",
        "check_estimators_fit_returns_self", "check_estimators_nan_inf",
        "check_estimators_overwrite_params", "check_estimators_pickle",
        "check_estimators_unfitted", "check_f_contiguous_array_estimator", "check_fit1d",
        "check_fit2d_1feature", "check_fit2d_1sample", "check_fit2d_predict1d",
        "check_fit_check_is_fitted", "check_fit_idempotent", "check_fit_score_takes_y",
        "check_methods_sample_order_invariance", "check_methods_subset_invariance",
        "check_n_features_in", "check_n_features_in_after_fitting",
        "check_pipeline_consistency", "check_positive_only_tag_during_fit",
        "check_readonly_memmap_input", "check_requires_y_none", "check_supervised_y_2d"]),
    SessionFeatures: (SESSIONS, [
        "check_complex_data", "check_dict_unchanged", "check_dtype_object",
        "check_estimator_sparse_tag", "check_estimators_dtypes",
        "check_estimators_empty_data_messages", "check_estimators_nan_inf",
        "check_estimators_pickle", "check_f_contiguous_array_estimator", "check_fit1d",
        "check_fit2d_predict1d", "check_fit_idempotent", "check_fit_score_takes_y",
        "check_methods_sample_order_invariance", "check_methods_subset_invariance",
        "check_n_features_in", "check_n_features_in_after_fitting",
        "check_pipeline_consistency", "check_transformer_data_not_an_array",
        "check_transformer_general", "check_transformer_preserve_dtypes",
        "check_transformers_unfitted"]),
}
FAILING[SessionGrids] = (SESSIONS, FAILING[SessionFeatures][1])
_NETWORK = [
    "check_classifier_data_not_an_array", "check_classifiers_classes",
    "check_classifiers_one_label", "check_classifiers_regression_target",
    "check_classifiers_train", "check_complex_data", "check_dict_unchanged",
    "check_dont_overwrite_parameters", "check_dtype_object", "check_estimator_sparse_array",
    "check_estimator_sparse_matrix", "check_estimator_sparse_tag", "check_estimators_dtypes",
    "check_estimators_empty_data_messages", "check_estimators_fit_returns_self",
    "check_estimators_nan_inf", "check_estimators_overwrite_params", "check_estimators_pickle",
    "check_estimators_unfitted", "check_f_contiguous_array_estimator", "check_fit2d_1feature",
    "check_fit2d_1sample", "check_fit2d_predict1d", "check_fit_check_is_fitted",
    "check_fit_idempotent", "check_fit_score_takes_y", "check_methods_sample_order_invariance",
    "check_methods_subset_invariance", "check_n_features_in",
    "check_n_features_in_after_fitting", "check_pipeline_consistency",
    "check_positive_only_tag_during_fit", "check_readonly_memmap_input",
    "check_requires_y_none", "check_supervised_y_2d"]
FAILING[CNNClassifier] = FAILING[LSTMClassifier] = (GRIDS, _NETWORK)
FAILING[MiniRocketClassifier] = (GRIDS, [
    *(c for c in _NETWORK if c not in ("check_classifiers_regression_target",
                                       "check_complex_data")),
    "check_fit1d"])


def expected_failed_checks(estimator) -> dict[str, str]:
    """Return the checks ``estimator`` does not pass, each with why it does not apply."""
    shape, names = FAILING[type(estimator)]
    return {name: NO_VALIDATION[name] if shape is None or name in (
        "check_estimators_unfitted", "check_transformers_unfitted") else shape
            for name in names}


@parametrize_with_checks([CalibratedSVC(), SessionFeatures(), SessionGrids()],
                         expected_failed_checks=expected_failed_checks)
def test_estimator(estimator, check) -> None:
    check(estimator)


@pytest.mark.slow
@parametrize_with_checks([JointEnsemble(feature_names=[f"range(tau_{j})" for j in range(1, 8)])],
                         expected_failed_checks=expected_failed_checks)
def test_joint_ensemble(estimator, check) -> None:
    check(estimator)


# small settings: the checks fit dozens of times
@pytest.mark.slow
@pytest.mark.nn
@pytest.mark.skipif(find_spec("torch") is None, reason="the networks need torch (nn extra)")
@parametrize_with_checks([CNNClassifier(depth=1, width=0.25, epochs=2, patience=1),
                          LSTMClassifier(depth=1, width=0.25, epochs=2, patience=1)],
                         expected_failed_checks=expected_failed_checks)
def test_network(estimator, check) -> None:
    check(estimator)


@pytest.mark.slow
@pytest.mark.nn
@pytest.mark.skipif(find_spec("aeon") is None, reason="MiniRocket needs aeon (nn extra)")
@parametrize_with_checks([MiniRocketClassifier(n_kernels=84)],
                         expected_failed_checks=expected_failed_checks)
def test_minirocket(estimator, check) -> None:
    check(estimator)
