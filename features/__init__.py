"""Physics feature chain: Panda dynamics, momentum observer, timeseries and scalar features."""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
__all__ = ["agreement", "chain_cache", "detector", "extract", "identification", "isolation",
           "kinematics", "limits", "observer", "per_sample", "scalars", "sliding", "timeseries",
           "timing", "window_features", "window_stream", "windows"]
