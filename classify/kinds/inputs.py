"""The inputs a kind may take, declared without importing what computes them.

:data:`FEATURES` are scalar features of each session's interaction window
(:class:`contactkit.features.extract.SessionFeatures`, built in
:mod:`contactkit.classify.data`); :data:`GRIDS` are timeseries grids of the window
(:class:`contactkit.classify.grids.SessionGrids`). Their functions import scikit-learn
and the feature chain when called, so declaring a kind stays light.
"""

from __future__ import annotations

from contactkit.classify.kinds.kind import InputKind, lazy

CNN_INPUT = ("q", "dq", "tau")
"""Default timeseries of a grid (and of the CNN): joint positions, velocities, torques."""
LSTM_INPUT = ("dq", "tau", "r")
"""Default timeseries of the LSTM: joint velocities, torques and observer residuals."""

FEATURES = InputKind(name="features", meta_key="features",
                     build=lazy("contactkit.classify.data:features_for"),
                     from_config=lazy("contactkit.classify.data:features_from_config"),
                     load=lazy("contactkit.classify.data:load_features"),
                     online_config=lazy("contactkit.features.window_features:"
                                        "window_features_from_config"))
GRIDS = InputKind(name="grid", meta_key="grid",
                  build=lazy("contactkit.classify.grids:grids_for"),
                  from_config=lazy("contactkit.classify.grids:grids_from_config"),
                  load=lazy("contactkit.classify.grids:load_grid_set"))
