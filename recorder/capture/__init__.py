"""Capturing one session: the loop over a source, the crash-safe journal it writes, and the
live Rerun view."""
