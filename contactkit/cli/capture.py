"""``recorder capture``: the protocol's options plus every registered source's options.

The command is built when the CLI starts: each source's ``Config`` fields become
options (``--field-name``), listed after the protocol's, source by source, so a
source installed from another package (entry-point group ``contactkit.sources``)
shows up in ``recorder capture --help`` without changes here. An option several
sources declare with the same type is shared; an option that clashes with a
protocol option or with another source's option of another type makes that source
unusable, which ``recorder sources`` reports.

A :class:`CaptureExtension` adds options and a listener that follows the capture
(the live contact-event pipeline, wired in by the ``recorder`` composition root),
without this module knowing what the listener does.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from contactkit.recorder.capture.record import (
    CaptureListener,
    OperatorCue,
    output_directory,
    record_session,
)
from contactkit.recorder.protocol import POSES
from contactkit.recorder.sources import (
    ProtocolChoices,
    Source,
    load_sources,
    open_source,
    source_options,
)
from contactkit.schemas import ACTIONS, InputError, SessionMeta
from contactkit.util.progress import err_console

Viewer = Literal["rerun", "web", "none"]
Condition = Literal["static", "dynamic"]
Action = Literal[ACTIONS]  # type: ignore[valid-type]
Pose = Literal[tuple(POSES)]  # type: ignore[valid-type]


@dataclass
class SharedOption:
    """A source option on the command line and the sources that take it."""

    param: str
    flag: str
    type: Any
    help: str
    fields: dict[str, str] = field(default_factory=dict)
    """Source name -> its ``Config`` field behind this option."""


@dataclass(frozen=True)
class CaptureExtension:
    """Extra ``capture`` options and what to do with them: ``parameters`` become
    options (keyword-only, annotated like the protocol's), and ``start`` is called
    with every option's value and the session metadata before recording; it returns
    a listener that sees every chunk as it is recorded (or None to stay out)."""

    parameters: tuple[inspect.Parameter, ...]
    start: Callable[[dict[str, Any], SessionMeta], CaptureListener | None]


def _protocol_parameters(source_names: list[str]) -> list[inspect.Parameter]:
    source_type = Literal[tuple(source_names)]  # type: ignore[valid-type]
    spec: list[tuple[str, Any, Any, Any]] = [
        ("pose", Pose, ..., typer.Option(help="Start pose (thesis Table 3.1).")),
        ("action", Action, ..., typer.Option(help="What the person does.")),
        ("source", source_type, "sim", typer.Option(
            help="Where the samples come from (recorder sources lists each source's "
                 "options): sim is the simulated Panda.")),
        ("condition", Condition, "static", typer.Option(
            help="static: hold the pose; dynamic: move to the target pose.")),
        ("target_pose", Pose | None, None, typer.Option(
            help="Dynamic condition: pose to move to (default D).")),
        ("speed", float | None, None, typer.Option(
            help="Dynamic condition: average speed of the furthest-moving joint [rad/s] "
                 "(default 0.2).")),
        ("link", int | None, None, typer.Option(
            help="Link 1-7 to touch (default: random for a contact).")),
        ("planned_at", float | None, None, typer.Option(
            help="Planned interaction time [s from start] (default: thesis timing, 5 s "
                 "static, mid-motion dynamic).")),
        ("duration", float | None, None, typer.Option(
            help="Session length [s] (default: 3 s hold + 4 s or the motion + 5 s hold).")),
        ("operator", str, "", typer.Option(
            help="Who touches the robot; in simulation, names a person with their own "
                 "strength and tempo (default: sim).")),
        ("hand", bool, True, typer.Option(help="The Panda carries its hand.")),
        ("notes", str, "", typer.Option(help="Free text stored in the metadata.")),
        ("out", Path, Path("sessions"), typer.Option(
            help="Output directory (created if needed).")),
        ("overwrite", bool, False, typer.Option(
            help="Replace an existing session file with the same name (and the --save-rrd "
                 "file).")),
        ("realtime", bool, False, typer.Option(
            help="Pace the capture at wall-clock speed and show the operator cue "
                 "(countdown, then a bell at the planned time).")),
        ("viewer", Viewer, "none", typer.Option(
            help="Show the capture live: rerun (native viewer), web (browser, 127.0.0.1) "
                 "or none.")),
        ("save_rrd", Path | None, None, typer.Option(
            help="Also write the live view to this .rrd file.")),
    ]
    return [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default,
                              annotation=Annotated[kind, option])
            for name, kind, default, option in spec]


def shared_options(sources: dict[str, type[Source]], taken: set[str]
                   ) -> tuple[dict[str, SharedOption], dict[str, str]]:
    """Return the source options by flag, and the problem of each source whose options
    clash with ``taken`` flags or with another source's option of another type."""
    options: dict[str, SharedOption] = {}
    problems: dict[str, str] = {}
    for name, cls in sources.items():
        declared = source_options(cls.Config)
        clash = [o.name for o in declared if "--" + o.name in taken or (
            "--" + o.name in options and options["--" + o.name].type != o.type)]
        if clash:
            problems[name] = f"source {name!r}: option(s) {', '.join(clash)} clash with " \
                             "another option"
            continue
        for opt in declared:
            flag = "--" + opt.name
            shared = options.setdefault(flag, SharedOption(
                "opt_" + opt.name.replace("-", "_"), flag, opt.type, opt.describe()))
            shared.fields[name] = opt.field
    return options, problems


def _source_parameter(opt: SharedOption) -> inspect.Parameter:
    names = ", ".join(opt.fields)
    decl = f"{opt.flag}/--no-{opt.flag[2:]}" if opt.type is bool else opt.flag
    info = typer.Option(decl, help=f"{opt.help} (source: {names})")
    return inspect.Parameter(opt.param, inspect.Parameter.KEYWORD_ONLY, default=None,
                             annotation=Annotated[opt.type | None, info])


def capture_command(sources: dict[str, type[Source]], options: dict[str, SharedOption],
                    extensions: tuple[CaptureExtension, ...] = ()) -> Callable[..., None]:
    """Return the ``capture`` command function for these sources, their options and the
    extensions' options."""

    def command(**values: Any) -> None:
        """Record one session and print the written file's path.

        Example: recorder capture --pose B --action adjust
        """
        name = values["source"]
        chosen: dict[str, Any] = {}
        for opt in options.values():
            value = values[opt.param]
            if name in opt.fields:
                chosen[opt.fields[name]] = value
            elif value is not None:
                raise InputError(f"{opt.flag} is not an option of source {name!r} (it belongs "
                                 f"to {', '.join(opt.fields)}); see recorder sources")
        choices = ProtocolChoices(
            action=values["action"], pose=values["pose"], condition=values["condition"],
            target_pose=values["target_pose"], speed_rad_s=values["speed"],
            link=values["link"], planned_at_s=values["planned_at"],
            duration_s=values["duration"], operator=values["operator"],
            with_hand=values["hand"], notes=values["notes"])
        _record(open_source(name, chosen, choices), values, extensions)

    params = _protocol_parameters(list(sources))
    for extension in extensions:
        params += extension.parameters
    for opt in options.values():
        params.append(_source_parameter(opt))
    command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    command.__annotations__ = {p.name: p.annotation for p in params}
    return command


def _flags(params: list[inspect.Parameter]) -> set[str]:
    """Return every flag the protocol parameters take (``--name`` and ``--no-name``)."""
    names = {"--help"}
    for p in params:
        flag = "--" + p.name.replace("_", "-")
        names |= {flag, "--no-" + flag[2:]}
    return names


def register_capture(app: typer.Typer, extensions: tuple[CaptureExtension, ...] = ()
                     ) -> None:
    """Add ``capture`` (for every usable source, with the ``extensions``' options) and
    ``sources`` to the recorder app."""
    classes, problems = load_sources()
    protocol = _protocol_parameters(list(classes))
    protocol += [p for extension in extensions for p in extension.parameters]
    options, clashes = shared_options(classes, _flags(protocol))
    problems |= clashes
    usable = {k: v for k, v in classes.items() if k not in clashes}
    app.command("capture")(capture_command(usable, options, extensions))

    @app.command("sources")
    def sources_command() -> None:
        """List the data sources (built in or installed by other packages) and their
        options, for recorder capture --source NAME."""
        for name, cls in usable.items():
            print(f"{name}: {(cls.__doc__ or '').strip().splitlines()[0]} "
                  f"({cls.__module__}.{cls.__qualname__})")
            for opt in source_options(cls.Config):
                print(f"  --{opt.name}  {opt.describe()}")
        for name, problem in problems.items():
            print(f"{name}: unusable: {problem}")


def _record(source: Source, values: dict[str, Any],
            extensions: tuple[CaptureExtension, ...]) -> None:
    from contactkit.recorder.capture.live_view import open_live_view  # rerun: when recording

    meta = source.session_meta()
    out = output_directory(values["out"])
    listeners = [listener for extension in extensions
                 if (listener := extension.start(values, meta)) is not None]
    live = open_live_view(values["viewer"], values["save_rrd"], meta, source.nominal_rate_hz,
                          err_console.print, overwrite=values["overwrite"])
    try:
        result = _capture(source, values, meta, out, listeners, live)
    except BaseException:
        if live is not None:
            live.abort()
        raise
    if live is not None:
        live.close()
    print(result.path)


def _capture(source: Source, values: dict[str, Any], meta, out: Path, listeners: list,
             live) -> Any:
    cue = None
    if values["realtime"] or live is not None or source.live:
        err_console.print(f"[bold]Recording[/] {meta.condition} pose {meta.pose}, "
                          f"{meta.action} at {source.planned_at_s:.2f} s of "
                          f"{source.duration_s:.1f} s")
        cue = OperatorCue(source.planned_at_s, meta.action, meta.link,
                          echo=None if live is None else live.cue)
    result = record_session(source, out, meta=meta, realtime=values["realtime"], cue=cue,
                            on_chunk=None if live is None else [live.on_chunk],
                            listeners=listeners, overwrite=values["overwrite"])
    return result
