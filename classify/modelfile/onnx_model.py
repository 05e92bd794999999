"""Network model files as ONNX: a graph, no code, with contactkit's metadata inside.

``save_onnx_model`` exports a trained CNN or LSTM (standardisation and softmax
included) and stores the same metadata document as a skops model file (grid
specification, classes, kind, training fingerprint, versions) in the ONNX
``metadata_props``, with a SHA-256 of the graph so that a modified file is
refused. ``OnnxClassifier`` runs it with onnxruntime on one CPU thread.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin

from contactkit.errors import DependencyMissing
from contactkit.schemas import InputError
from contactkit.util.atomic import atomic_write
from contactkit.util.safe_open import parse_json

META_KEY = "contactkit"


def _graph_digest(model) -> str:
    return hashlib.sha256(model.graph.SerializeToString()).hexdigest()


def save_onnx_model(path: Path, network, meta: dict, sample_shape: tuple[int, ...],
                    overwrite: bool = False) -> Path:
    """Export ``network`` (inputs of ``sample_shape`` = (channels, steps)) to ONNX with
    ``meta`` embedded, replacing ``path`` atomically; return the path."""
    import onnx

    channels, steps = sample_shape
    with atomic_write(path, overwrite=overwrite, suffix=".onnx") as tmp:
        network.export_onnx(tmp.path, channels, steps)
        model = onnx.load(str(tmp.path))
        doc = {**meta, "graph_sha256": _graph_digest(model)}
        entry = model.metadata_props.add()
        entry.key, entry.value = META_KEY, json.dumps(doc)
        tmp.file.seek(0)
        tmp.file.write(model.SerializeToString())
        tmp.file.truncate()
    return path


class OnnxClassifier(ClassifierMixin, BaseEstimator):
    """predict_proba / predict over (sessions, channels, steps) grids with onnxruntime."""

    def __init__(self, path: Path, classes: list[str]) -> None:
        import onnxruntime as ort

        self.path = path
        self.classes = classes
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        self.session_ = ort.InferenceSession(str(path), options,
                                             providers=["CPUExecutionProvider"])
        self.classes_ = np.array(classes, dtype=object)

    def fit(self, X, y=None) -> OnnxClassifier:
        """Refuse: an exported network is trained already (scikit-learn looks for fit)."""
        raise InputError("an ONNX model file holds a trained network; it cannot be refitted")

    def __sklearn_is_fitted__(self) -> bool:
        """Always fitted, so that it can end a scikit-learn Pipeline."""
        return True

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Return class probabilities."""
        return self.session_.run(None, {"grid": np.asarray(X, dtype=np.float32)})[0]

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Return the most probable class."""
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]


def load_onnx_model(path: Path, trusted_types: object = None) -> tuple[OnnxClassifier, dict]:
    """Load an ONNX model file; check its metadata and graph digest. Return the classifier
    and its metadata. ``trusted_types`` is ignored: an ONNX file builds no Python objects."""
    try:
        import onnx
        import onnxruntime  # noqa: F401 (OnnxClassifier runs the graph with it)
    except ImportError as err:
        raise DependencyMissing("ONNX models need onnx and onnxruntime: pip install "
                                "'contactkit[nn]'", path) from err
    try:
        model = onnx.load(str(path))
    except Exception as err:  # onnx raises DecodeError and others on foreign bytes
        raise InputError(f"not a readable ONNX file ({type(err).__name__})", path) from err
    props = {p.key: p.value for p in model.metadata_props}
    if META_KEY not in props:
        raise InputError("not a contactkit model (no contactkit metadata in the ONNX file)",
                         path)
    try:
        meta = parse_json(props[META_KEY], "model metadata", path)
    except InputError as err:
        raise InputError(f"not a contactkit model (its ONNX metadata is not JSON: "
                         f"{err.problem[:120]})", path) from err
    if not isinstance(meta, dict):
        raise InputError("not a contactkit model (its ONNX metadata is not an object)", path)
    if meta.get("graph_sha256") != _graph_digest(model):
        raise InputError("model file was modified after it was written (digest mismatch); "
                         "refusing to load it", path)
    classes = meta.get("classes")
    if not (isinstance(classes, list) and classes and all(isinstance(c, str) for c in classes)):
        raise InputError("not a contactkit model (its ONNX metadata lists no classes)", path)
    try:
        return OnnxClassifier(path, classes), meta
    except Exception as err:  # onnxruntime raises InvalidGraph, Fail and others
        raise InputError(f"onnxruntime cannot run this ONNX graph ({type(err).__name__}: "
                         f"{' '.join(str(err).split())[:120]})", path) from err

