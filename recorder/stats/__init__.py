"""Dataset statistics: the index summary, the streamed per-session pass (``--deep``) and the
report (JSON, Markdown and figures)."""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
__all__ = ["deep", "report", "summary"]
