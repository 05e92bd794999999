"""The Rerun view shared by the recorder's live view and replay: entity paths, blueprints
and colours (:mod:`~contactkit.viewer.layout`) and the web viewer
(:mod:`~contactkit.viewer.web`)."""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
__all__ = ["layout", "palette", "web"]
