"""The choices of the ``classify`` options, importable without scikit-learn, torch,
matplotlib or the chain: the command line builds its options from them at start-up.
The modules that use them (data, evaluate, experiments, networks, gridsearch) import
them from here."""

PROTOCOLS = ("thesis", "group")
"""Evaluation protocols (:mod:`contactkit.classify.evaluate`)."""
GROUP_KEYS = ("pose", "session", "operator", "condition")
"""Metadata keys the group protocol can group sessions by."""
EXPERIMENTS = ("features", "rfe", "speed", "window")
"""The thesis experiments of :mod:`contactkit.classify.experiments`."""
DEVICES = ("auto", "cpu", "cuda")
"""Where a network trains (:mod:`contactkit.classify.networks`)."""
NETWORKS = ("cnn", "lstm")
"""The kinds the grid search tries."""
THESIS_DEPTHS = (1, 2, 4)
"""The thesis grid's layer multipliers."""
THESIS_WIDTHS = (0.5, 1.0, 2.0)
"""The thesis grid's kernel and neuron multipliers."""
THESIS_DROPOUTS = (0.0, 0.1, 0.25)
"""The thesis grid's dropouts."""
