"""The choices of the ``classify`` options, importable without scikit-learn, torch,
matplotlib or the chain: the command line builds its options from them at start-up.
The modules that use them (data, evaluate, experiments, gridsearch, training) import
them from here."""

PROTOCOLS = ("thesis", "group")
"""Evaluation protocols (:mod:`contactkit.classify.evaluate`)."""
GROUP_KEYS = ("pose", "session", "operator", "condition")
"""Metadata keys the group protocol can group sessions by."""
EXPERIMENTS = ("features", "rfe", "speed", "window")
"""The thesis experiments of :mod:`contactkit.classify.experiments.thesis`."""
