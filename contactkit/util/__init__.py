"""Shared helpers below every subpackage: progress bars, pacing, parallel work, CLI runner."""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
# The helpers other code builds on; dask_executor and workers sit behind parallel, and
# exact_median, moments and pacing serve one caller each.
__all__ = ["atomic", "cache", "parallel", "paths", "progress", "text"]
