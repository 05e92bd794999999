"""Dataset statistics: the index summary, the streamed per-session pass (``--deep``) and the
report (JSON, Markdown and figures)."""
