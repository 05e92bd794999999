"""Command-line options generated from parameter declarations: the one place where an
extension's parameters (a model kind's hyper-parameters, a data source's ``Config``
fields, a capture extension's options) become flags.

Declarations are :class:`contactkit.util.params.Param`. Several owners (kinds, sources)
may declare a parameter under the same option: :func:`shared_flags` merges them into
one flag when their types agree and reports the owners whose options clash. A command
takes the generated flags by being registered with :func:`command_with_flags`: its
function keeps its own typed signature (the options every owner shares) and receives
the generated flags' values, None for a flag not given, as ``ctx.meta[key]``; the flags
are added to the command as options, after its own, and ``--help`` lists them with
their help, unit, default and owners. :func:`owner_values` then picks the values of the
chosen owner and refuses a flag it does not take.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from collections.abc import Set as AbstractSet
from dataclasses import dataclass, field
from typing import Any, Literal, cast

import typer
import typer.core
import typer.main
import typer.models

from contactkit.errors import InputError
from contactkit.util.params import Choice, Param


@dataclass
class SharedFlag:
    """One generated option and the owners that take it.

    ``param`` is the declaration the option is built from (the first owner's);
    ``owners`` maps each owner's name to its own parameter's name behind the option;
    ``what`` names the kind of owner in the help (``"source"``; empty: owners not
    listed).
    """

    param: Param
    owners: dict[str, str] = field(default_factory=dict)
    what: str = ""

    @property
    def key(self) -> str:
        """The option's name in ``ctx.meta`` values (see :func:`flag_key`)."""
        return flag_key(self.param)

    def help(self) -> str:
        """Return the option's help: the declaration's, then the owners."""
        text = self.param.describe()
        return f"{text} ({self.what}: {', '.join(self.owners)})" if self.what else text


def flag_key(param: Param) -> str:
    """Return the key of ``param``'s flag in ``ctx.meta`` values: its option without
    dashes, in snake case (``--decide-after``: ``decide_after``)."""
    return param.option.removeprefix("--").replace("-", "_")


def shared_flags(owners: Mapping[str, Sequence[Param]], taken: AbstractSet[str] = frozenset(),
                 what: str = "", joins: Mapping[str, SharedFlag] | None = None
                 ) -> tuple[dict[str, SharedFlag], dict[str, str]]:
    """Return the flags of every owner's parameters by option (``--name``), and the problem
    of each owner whose options clash with a ``taken`` option or with another owner's
    option of another type (that owner's parameters get no flags). ``what`` names the
    kind of owner in the flags' help (empty: the owners are not listed). An owner's
    parameter with the option and type of one of the flags ``joins`` (by option) joins
    that flag (it becomes one of its owners) instead of getting its own; those flags are
    not in the result."""
    flags: dict[str, SharedFlag] = dict(joins or {})
    problems: dict[str, str] = {}
    for owner, params in owners.items():
        clash = [p.option for p in params if p.option in taken or (
            p.option in flags and flags[p.option].param.type != p.type)]
        if clash:
            problems[owner] = f"option(s) {', '.join(clash)} clash with another option"
            continue
        for p in params:
            flags.setdefault(p.option, SharedFlag(p, what=what)).owners[owner] = p.name
    return {o: f for o, f in flags.items() if o not in (joins or {})}, problems


def _option(flag: SharedFlag) -> typer.core.TyperOption:
    """Return the click option of a shared flag: typed as declared (a string restricted
    by a :class:`Choice` as a choice), None when not given. Typer's own builder makes it
    (``typer.main._get_param``, private: the tests of capture and train exercise it), so
    the generated options parse, convert and show in ``--help`` as a typed signature's."""
    p = flag.param
    decl = f"{p.option}/--no-{p.option[2:]}" if p.type is bool else p.option
    choices = [c.values for c in p.constraints if isinstance(c, Choice)]
    annotation = Literal[choices[0]] if p.type is str and choices else p.type
    meta = typer.models.ParamMeta(name=flag.key, annotation=annotation | None,
                                  default=typer.Option(None, decl, help=flag.help()))
    return cast(typer.core.TyperOption, typer.main._get_param(meta))  # an option's meta


def command_with_flags(app: typer.Typer, name: str, flags: Sequence[SharedFlag], *,
                       key: str) -> Callable[[Callable], Callable]:
    """Return a decorator that registers a function as command ``name`` of ``app`` with
    the generated ``flags`` as options after its own.

    The function takes ``ctx: typer.Context`` and finds the flags' values in
    ``ctx.meta[key]``, by :attr:`SharedFlag.key`, None for a flag not given.
    """
    options = [_option(flag) for flag in flags]

    class Command(typer.core.TyperCommand):
        """The command with the generated options (their values go to ``ctx.meta``)."""

        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.params.extend(options)

        def invoke(self, ctx: Any) -> Any:  # a typer.Context (click's, to the checker)
            ctx.meta[key] = {o.name: ctx.params.pop(o.name, None) for o in options}
            return super().invoke(ctx)

    return app.command(name, cls=Command)


def owner_values(flags: Mapping[str, SharedFlag], values: Mapping[str, Any], owner: str,
                 what: str) -> dict[str, Any]:
    """Return the given values (not None) of ``owner``'s flags, keyed by its parameter
    names; raise InputError for a flag given that ``owner`` does not take (``what``
    names the kind of owner and where to list them, e.g. ``"source"``)."""
    chosen: dict[str, Any] = {}
    for flag in flags.values():
        value = values.get(flag.key)
        if value is None:
            continue
        if owner not in flag.owners:
            raise InputError(f"{flag.param.option} is not an option of {what} {owner!r} (it "
                             f"belongs to {', '.join(flag.owners)})")
        chosen[flag.owners[owner]] = value
    return chosen
