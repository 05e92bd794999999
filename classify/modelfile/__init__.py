"""The model file: one file per trained model, skops (:mod:`.skops_format`, read without
importing its heavy libraries: :mod:`.skops_import`) or ONNX (:mod:`.onnx_model`),
with its metadata checked on load (:mod:`.model_file`).

The names of :mod:`contactkit.classify.modelfile.model_file` can also be imported from here (``from
contactkit.classify.modelfile import load_model``), as they were before this package had
modules of its own; nothing is imported until one is asked for.
"""

from __future__ import annotations

from contactkit.classify import names_of

__all__ = ["model_file"]
"""The public modules, for the API reference."""
__getattr__ = names_of(__name__, "contactkit.classify.modelfile.model_file")
