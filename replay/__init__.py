"""Replay of sessions through the feature chain and classifier, logged to Rerun."""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
__all__ = ["browse", "catalog", "contacts", "engine", "query", "recording", "session_replay"]
