"""Classifiers and their honest evaluation."""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
# fast (the online predict path), online_arrays (that path in model files), networks,
# onnx_model and skops_format sit behind the kinds and model files.
__all__ = ["augmentation", "calibrate", "data", "evaluate", "event_listener",
           "event_metrics", "event_training", "events", "experiments", "grids", "gridsearch",
           "kind", "modelfile", "models", "nn", "prediction", "registry", "schemes",
           "svm_kinds", "training"]
