"""Capturing one session: the loop over a source, the crash-safe journal it writes, and the
live Rerun view."""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
__all__ = ["journal", "live_view", "record"]
