"""The ``replay`` command (the replay engine arrives with its issue)."""

from __future__ import annotations

import sys

import typer

from schemas.cli import run_app

app = typer.Typer(name="replay", no_args_is_help=True, add_completion=False,
                  pretty_exceptions_enable=False,
                  help="Replay sessions through the feature chain and classifier into Rerun.")


@app.callback()
def _root() -> None:
    """Replay sessions through the feature chain and classifier into Rerun."""


def main() -> None:
    """Entry point of the ``replay`` console script."""
    sys.exit(run_app(app, "replay"))
