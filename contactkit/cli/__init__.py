"""The commands (``recorder``, ``replay``, ``classify``): the composition roots.

Each module here parses a command line and calls the library below it. This is the only
layer that joins the recorder and classify (the live events of ``capture --events``, the
default model's recipe). No library module imports from here."""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
# The commands, and :mod:`~contactkit.cli.common` for apps built like them (the other modules are
# parts of the commands).
__all__ = ["classify", "common", "recorder", "replay"]
