"""Shared helpers below every subpackage: atomic writes, the one opener and bounded JSON
parser for files named by input or metadata, streamed Rerun files, progress bars, pacing,
parallel work, parameter declarations and plugin registries."""

# The public modules, for the API reference (submodule names: importing the package
# stays light). dask_executor and workers sit behind parallel; exact_median, moments and
# pacing serve one caller each. params and plugins are what extensions declare with.
__all__ = ["atomic", "cache", "owned", "parallel", "params", "paths", "plugins", "progress",
           "rrd_file", "safe_open", "text"]
