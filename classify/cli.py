"""The ``classify`` command (features, training and evaluation arrive with their issues)."""

from __future__ import annotations

import sys

import typer

from schemas.cli import run_app

app = typer.Typer(name="classify", no_args_is_help=True, add_completion=False,
                  pretty_exceptions_enable=False,
                  help="Turn sessions into features and contact predictions.")


@app.callback()
def _root() -> None:
    """Turn sessions into features and contact predictions."""


def main() -> None:
    """Entry point of the ``classify`` console script."""
    sys.exit(run_app(app, "classify"))
