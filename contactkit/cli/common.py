"""Command-line apps: one factory, and running them so that an error the user can act on
is one line on stderr and exit code 2."""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, ClassVar

import typer
from typer.core import TyperCommand, TyperGroup

from contactkit.errors import ContactkitError
from contactkit.util.parallel import SCHEDULER_ENV, resolve_scheduler
from contactkit.util.text import console_text, printable

if TYPE_CHECKING:
    from contactkit.features.detector import DetectorConfig
    from contactkit.robots.dynamics import ArmDynamics

SchedulerOpt = Annotated[str | None, typer.Option(
    "--scheduler", envvar=SCHEDULER_ENV, show_envvar=True,
    help="Where parallel jobs run: local (processes on this machine, --workers of them), "
         "local:N (a Dask LocalCluster of N workers on 127.0.0.1) or tcp://host:8786 (a "
         "running Dask scheduler whose workers see the sessions under the same paths). "
         "Dask needs the dask extra. Results are the same wherever the jobs run.")]
"""The ``--scheduler`` option of every app whose commands run parallel jobs, on the app's
callback; its commands read it with :func:`scheduler_of` and pass it down."""


def scheduler_of(ctx: typer.Context) -> str | None:
    """Return the ``--scheduler`` given to the command line's root (before the
    subcommand, or from ``$CONTACTKIT_SCHEDULER``); None for the local pool."""
    return ctx.find_root().params.get("scheduler")

RobotOpt = Annotated[str | None, typer.Option(
    help="The arm's model to use instead of the one each session names: panda, fr3, a "
         "plugin's name or urdf:PATH (`recorder robots` lists them). For sessions "
         "recorded before sessions named their arm; `recorder set-robot` corrects a file "
         "for good.")]
"""The ``--robot`` override of the commands that run the feature chain on sessions."""

DynamicsOpt = Annotated[Path | None, typer.Option(
    "--dynamics", metavar="FILE",
    help="The arm's identified dynamics (`recorder identify`): link inertias, friction and "
         "the detector's thresholds calibrated with them, used instead of those a session "
         "carries (`recorder set-robot --dynamics`) or the robot's nominal model. Refused "
         "for another arm or hand (and with a failing check).")]
"""The ``--dynamics`` option, beside ``--robot``: read with :func:`load_dynamics_option`."""


def beyond_range_text(detector: DetectorConfig) -> str:
    """Return the end of a detector summary line: the dynamic torque [Nm] per joint beyond
    which its thresholds grow further (``dynamic_range``), or nothing without one."""
    if detector.dynamic_range is None:
        return ""
    return (f"; beyond a dynamic torque of {[round(v, 1) for v in detector.dynamic_range]} "
            "Nm they grow further")


def load_dynamics_option(path: Path | None) -> ArmDynamics | None:
    """Return the dynamics of a ``--dynamics`` file, or None: every check of
    :func:`~contactkit.robots.dynamics.load_dynamics`, and of the detector settings
    stored in it. InputError (one line, naming the file) for a file that fails one."""
    if path is None:
        return None
    from contactkit.features.detector import dynamics_detector
    from contactkit.robots.dynamics import load_dynamics

    dynamics = load_dynamics(path)
    dynamics_detector(dynamics)
    return dynamics


VerboseOpt = Annotated[int, typer.Option(
    "--verbose", "-v", count=True, show_default=False,
    help="Say more: -v adds what the tools do (info), -vv debugging detail.")]
"""The ``-v`` option of every command line (before the subcommand where there is one)."""
QuietOpt = Annotated[bool, typer.Option(
    "--quiet", "-q", help="Say less: only errors (no warnings) on stderr.")]
"""The ``-q`` option of every command line; it wins over ``-v``."""

LOGGER = "contactkit"
"""The logger every library module logs under (``logging.getLogger(__name__)``)."""


class _StderrHandler(logging.StreamHandler):
    """Write each record as ``prog: message`` to whatever ``sys.stderr`` is when it is
    emitted: a progress bar's redirection (so the bar is not torn), a test's capture."""

    def __init__(self, prog: str) -> None:
        super().__init__()
        self.setFormatter(logging.Formatter(f"{prog}: %(message)s"))

    def format(self, record: logging.LogRecord) -> str:
        """Return the record as one line with control characters escaped (messages
        quote file names and file contents)."""
        return printable(super().format(record))

    @property
    def stream(self):
        """The current ``sys.stderr``."""
        return sys.stderr

    @stream.setter
    def stream(self, _value) -> None:
        """Ignore the stream the base class sets: the current one is used."""


def set_verbosity(verbose: int = 0, quiet: bool = False) -> None:
    """Set how much contactkit's logger lets through: warnings (default), info with one
    ``-v``, debugging with two, only errors with ``quiet``."""
    levels = {0: logging.WARNING, 1: logging.INFO}
    level = logging.ERROR if quiet else levels.get(verbose, logging.DEBUG)
    logging.getLogger(LOGGER).setLevel(level)


SOME_FAILED = 2
"""Exit code of a command over many sessions (or bags, logs) when some of them failed:
each failure is listed on stderr, and the output of the others is written."""


def print_problems(problems: Sequence[Any], verb: str = "skipped") -> None:
    """Print each problem of a command over many sessions on stderr: ``verb name:
    problem``, from ``(name, problem)`` pairs or errors with ``path`` and ``problem``,
    with control characters and console markup in them escaped."""
    from contactkit.util.progress import err_console

    for problem in problems:
        name, text = problem if isinstance(problem, tuple) else (problem.path, problem.problem)
        err_console.print(f"[yellow]{verb}[/] {console_text(name)}: {console_text(text)}",
                          soft_wrap=True)


def exit_if_failed(problems: object) -> None:
    """End the command with :data:`SOME_FAILED` when ``problems`` (listed already) is not
    empty; return otherwise."""
    if problems:
        raise typer.Exit(SOME_FAILED)


CommandsBuilder = Callable[[], dict[str, Any]]
"""Builds a group's deferred commands: returns their click commands by name."""


class DeferredCommands(TyperGroup):
    """A command group some of whose commands are built only when they run or show their
    own help, so that the group's ``--help`` does not import what they need (the capture
    command's flags come from every installed source plugin). ``deferred`` maps each such
    command's name to its one-line help and the builder that makes it (one builder may
    make several commands); subclass it per app with :func:`deferred_commands`."""

    deferred: ClassVar[dict[str, tuple[str, CommandsBuilder]]] = {}

    def build(self, name: str) -> None:
        """Build the deferred command ``name`` (and those its builder makes with it)."""
        if name in self.deferred and name not in self.commands:
            self.commands.update(self.deferred[name][1]())

    def list_commands(self, ctx: Any) -> list[str]:
        """Return the command names, the deferred ones first, built or not."""
        return [*self.deferred, *(n for n in super().list_commands(ctx)
                                 if n not in self.deferred)]

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        """Return a command; a deferred one not yet built is a stand-in with its one-line
        help, which is all that the group's ``--help`` shows."""
        command = super().get_command(ctx, cmd_name)
        if command is None and cmd_name in self.deferred:
            summary = self.deferred[cmd_name][0]
            command = TyperCommand(name=cmd_name, help=summary)
        return command

    def resolve_command(self, ctx: Any, args: list[str]) -> Any:
        """Build the command the arguments name before it runs (or shows its help); an
        unknown name builds them all, so that "did you mean" can suggest them too."""
        if args:
            names = [args[0]] if args[0] in self.deferred or args[0] in self.commands \
                else list(self.deferred)
            for name in names:
                self.build(name)
        return super().resolve_command(ctx, args)


def deferred_commands(commands: dict[str, tuple[str, CommandsBuilder]]
                      ) -> type[DeferredCommands]:
    """Return a :class:`DeferredCommands` class for an app (``new_app(cls=...)``) whose
    commands in ``commands`` (name: (one-line help, builder)) are built on first use."""
    return type("AppCommands", (DeferredCommands,), {"deferred": dict(commands)})


def new_app(name: str | None = None, help: str | None = None, *,
            root_options: bool = False, **settings) -> typer.Typer:
    """Return a Typer app with contactkit's settings: plain help text (rich markup off, so
    units in brackets such as "[s]" or "[rad]" print as written), no shell-completion
    options, no pretty tracebacks, and help when called without arguments.

    ``root_options`` gives an app of subcommands the options that go before the
    subcommand: ``--scheduler`` (read by the commands with :func:`scheduler_of`),
    ``-v/--verbose`` and ``-q/--quiet``.
    """
    defaults = {"rich_markup_mode": None, "add_completion": False,
                "pretty_exceptions_enable": False, "no_args_is_help": True}
    app = typer.Typer(name=name, help=help, **(defaults | settings))
    if root_options:
        app.callback()(_root)
    return app


def _root(scheduler: SchedulerOpt = None, verbose: VerboseOpt = 0,
          quiet: QuietOpt = False) -> None:
    """Apply the options before the subcommand (see :func:`new_app`)."""
    set_verbosity(verbose, quiet)
    resolve_scheduler(scheduler)  # a malformed address fails before any command runs


def run_app(app: typer.Typer, prog: str, argv: list[str] | None = None) -> int:
    """Run a Typer app; return its exit code.

    A :class:`~contactkit.errors.ContactkitError` (bad input, a missing extra, a full
    disk or a dead cluster) and usage errors print ``prog: error: <one line>`` on
    stderr and give exit code 2 (a bare command prints its help); Ctrl-C gives 130. No
    traceback reaches the user for bad input (a bug still shows one). While it runs,
    the library's log records (warnings, unless ``-v`` or ``-q`` says otherwise) go to
    stderr as ``prog: message``.
    """
    logger = logging.getLogger(LOGGER)
    handler = _StderrHandler(prog)
    logger.addHandler(handler)
    set_verbosity()
    try:
        return _run(app, prog, argv)
    finally:
        logger.removeHandler(handler)


def _run(app: typer.Typer, prog: str, argv: list[str] | None) -> int:
    """Run the app as :func:`run_app` says; return its exit code."""
    try:
        result = app(args=argv, prog_name=prog, standalone_mode=False)
    except ContactkitError as err:
        print(f"{prog}: error: {printable(err)}", file=sys.stderr)
        return 2
    except typer.TyperException as err:
        ctx = getattr(err, "ctx", None)
        if type(err).__name__ == "NoArgsIsHelpError":
            print(err.format_message(), file=sys.stderr)
            return 2
        hint = f" (see {ctx.command_path} --help)" if ctx is not None else ""
        message = f"{prog}: error: {err.format_message()}{hint}"
        print(printable(" ".join(message.split())), file=sys.stderr)
        return getattr(err, "exit_code", 2) or 2
    except typer.Exit as err:
        return err.exit_code
    except (typer.Abort, KeyboardInterrupt):
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    return result if isinstance(result, int) else 0
