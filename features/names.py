"""The names of the timeseries features and their groups, importable without the chain
(pinocchio): the command line lists them in its options and help.
:mod:`contactkit.features.timeseries` computes them."""

SENSOR = ("q", "dq", "tau", "ddq", "p_int")
"""Features from the sensors alone."""
MODEL = ("r", "g", "tau_inv", "p_ext")
"""Features that need the robot's dynamic model."""
WORKSPACE = ("f", "m", "fm_norm")
"""The external wrench in the base frame."""
GROUPS = {"sensor": SENSOR, "model": MODEL, "workspace": WORKSPACE}
ALL_TIMESERIES = SENSOR + MODEL + WORKSPACE
"""The features of the thesis, a chain's default."""
DETECTOR = ("tau_dyn",)
"""Features the contact detector reads besides the residual, computed on request only."""
KNOWN = ALL_TIMESERIES + DETECTOR
"""Every timeseries feature a chain computes."""
