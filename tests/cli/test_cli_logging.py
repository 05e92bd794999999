"""Library code logs; the command line shows the records as ``prog: message`` on stderr,
warnings by default, more with -v, only errors with -q."""

from __future__ import annotations

import logging

import pytest

from contactkit.cli.common import QuietOpt, VerboseOpt, new_app, run_app, set_verbosity

log = logging.getLogger("contactkit.recorder.sources.test")


def _app():
    app = new_app("tool")

    @app.callback()
    def root(verbose: VerboseOpt = 0, quiet: QuietOpt = False) -> None:
        """A tool."""
        set_verbosity(verbose, quiet)

    @app.command()
    def go() -> None:
        """Log at every level."""
        log.debug("detail")
        log.info("step")
        log.warning("bus silent for 1.0 s: capture ended")
        log.error("failed")

    @app.command()
    def other() -> None:
        """A second command."""

    return app


@pytest.mark.parametrize(("flags", "shown"), [
    ([], ["bus silent for 1.0 s: capture ended", "failed"]),
    (["-q"], ["failed"]),
    (["-v"], ["step", "bus silent for 1.0 s: capture ended", "failed"]),
    (["-vv"], ["detail", "step", "bus silent for 1.0 s: capture ended", "failed"]),
    (["-v", "-q"], ["failed"]),
])
def test_verbosity(flags, shown, capsys) -> None:
    assert run_app(_app(), "tool", [*flags, "go"]) == 0
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.splitlines() == [f"tool: {line}" for line in shown]


def test_handler_removed_after_the_run() -> None:
    before = list(logging.getLogger("contactkit").handlers)
    run_app(_app(), "tool", ["go"])
    assert logging.getLogger("contactkit").handlers == before
