"""Model kinds: what a kind is (:mod:`.kind`), the registry of kinds by name and entry
point (:mod:`.registry`), the inputs a kind takes (:mod:`.inputs`), the SVM kinds
(:mod:`.svm`) and their scikit-learn estimators (:mod:`.svm_estimators`), the network
kinds (:mod:`.neural`) with the CNN and LSTM (:mod:`.networks`), MiniRocket
(:mod:`.minirocket`) and the devices networks train on (:mod:`.devices`), and the fast
online path a replay predicts with (:mod:`.fast`, stored as :mod:`.online_arrays`).

Importing the package imports none of them.
"""

# fast (the online predict path), online_arrays (that path in model files) and networks
# sit behind the kinds.
__all__ = ["devices", "inputs", "kind", "minirocket", "neural", "registry", "svm",
           "svm_estimators"]
