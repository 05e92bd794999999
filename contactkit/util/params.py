"""Parameter declarations: what an extension (a model kind, a data source) takes, with
its type, default, help, unit and constraints, declared once where the parameter is
defined.

A :class:`Param` says everything a command line and a check need: the command line's
options are generated from declarations (:mod:`contactkit.cli.flags`), and
:func:`check_params` checks values against them, as scikit-learn's
``_parameter_constraints`` do, but with one-line :class:`contactkit.errors.InputError`
messages. Constraints are :class:`Interval` (numbers) and :class:`Choice` (one of
named values). A source and an importer declare their options as the fields of a
``Config`` dataclass; :func:`dataclass_params` reads them as declarations and
:func:`make_config` builds one from given values.

This module imports nothing beyond the standard library and :mod:`contactkit.errors`,
so declaring parameters costs no start-up time.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import MISSING, dataclass
from typing import Any

from contactkit.errors import InputError

REQUIRED = MISSING
"""The ``default`` of a parameter that has none: the caller must give it."""


@dataclass(frozen=True)
class Interval:
    """Numbers from ``low`` to ``high`` (None: unbounded on that side); ``closed`` says
    which ends belong to the interval: "both", "left", "right" or "neither"."""

    low: float | None = None
    high: float | None = None
    closed: str = "both"

    def problem(self, value: Any) -> str | None:
        """Return why ``value`` lies outside the interval, or None when it lies inside."""
        if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
            return f"must be a number, got {value!r}"
        low_ok = self.low is None or (value >= self.low if self.closed in ("both", "left")
                                      else value > self.low)
        high_ok = self.high is None or (value <= self.high if self.closed in ("both", "right")
                                        else value < self.high)
        return None if low_ok and high_ok else f"must be {self.describe()}, got {value!r}"

    def describe(self) -> str:
        """Return the interval in words, for example ``in [0, 1)`` or ``at least 1``."""
        if self.high is None and self.low is not None:
            return f"at least {self.low:g}" if self.closed in ("both", "left") \
                else "positive" if self.low == 0 else f"above {self.low:g}"
        if self.low is None and self.high is not None:
            return f"at most {self.high:g}" if self.closed in ("both", "right") \
                else f"below {self.high:g}"
        left = "[" if self.closed in ("both", "left") else "("
        right = "]" if self.closed in ("both", "right") else ")"
        low = "-inf" if self.low is None else f"{self.low:g}"
        high = "inf" if self.high is None else f"{self.high:g}"
        return f"in {left}{low}, {high}{right}"


@dataclass(frozen=True)
class Choice:
    """One of ``values`` (strings)."""

    values: tuple[str, ...]

    def problem(self, value: Any) -> str | None:
        """Return why ``value`` is not one of the values, or None when it is."""
        if value in self.values:
            return None
        return f"must be one of {', '.join(self.values)}, got {value!r}"

    def describe(self) -> str:
        """Return the values in words."""
        return f"one of {', '.join(self.values)}"


@dataclass(frozen=True)
class Param:
    """One declared parameter.

    ``name`` is the keyword it is passed as (a Python identifier); ``type`` one of
    ``int``, ``float``, ``str``, ``bool``, ``pathlib.Path``, a ``Literal`` or an
    ``Enum``; ``default`` its value when not given (:data:`REQUIRED`: none);
    ``optional``: None is allowed too (the owner's own choice). ``help`` is one
    sentence, ``unit`` the unit in brackets (``"s"``, ``"Hz"``), ``constraints`` what a
    value must satisfy (all of them). ``flag`` is the command-line option's name where
    it differs from ``name`` with dashes (``"C"`` for ``--C``). ``grid`` are the values a
    search tries by default (empty: a search does not vary it).
    """

    name: str
    type: Any
    default: Any = REQUIRED
    help: str = ""
    unit: str | None = None
    constraints: tuple[Interval | Choice, ...] = ()
    optional: bool = False
    flag: str | None = None
    grid: tuple[Any, ...] = ()

    @property
    def option(self) -> str:
        """The command-line option, for example ``--patience`` or ``--C``."""
        return "--" + (self.flag or self.name.replace("_", "-"))

    @property
    def required(self) -> bool:
        """True when the parameter has no default."""
        return self.default is REQUIRED

    def describe(self) -> str:
        """Return the help text with the unit in brackets, and the default, on one line."""
        text = self.help
        if self.unit:
            text = f"{text.removesuffix('.')} [{self.unit}]."
        if self.required:
            text += " Required."
        elif self.default is not None:
            value = getattr(self.default, "value", self.default)
            text += f" Default: {value}."
        return text

    def check(self, value: Any, owner: str) -> Any:
        """Return ``value`` converted to the declared type (an int given for a float
        parameter becomes a float); raise InputError naming ``owner`` and the parameter
        when it breaks a constraint."""
        if value is None and (self.optional or self.default is None):
            return None
        if self.type is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if self.type in (int, float) and (isinstance(value, bool)
                                          or not isinstance(value, self.type)):
            raise InputError(f"{owner}: {self.name} must be {self.type.__name__}, got "
                             f"{value!r}")
        for constraint in self.constraints:
            problem = constraint.problem(value)
            if problem is not None:
                raise InputError(f"{owner}: {self.name} {problem}")
        return value


def check_params(params: Sequence[Param], values: Mapping[str, Any], owner: str
                 ) -> dict[str, Any]:
    """Return every declared parameter's value: the given one, checked, else its default.

    ``values`` are keyed by parameter name; a value of None counts as not given unless
    the parameter is ``optional``. Raises InputError, naming ``owner``, for a name
    that is not declared, a missing required parameter or a value that breaks a
    constraint.
    """
    declared = {p.name: p for p in params}
    unknown = sorted(set(values) - set(declared))
    if unknown:
        raise InputError(f"{owner} takes no parameter {unknown[0]!r} (its parameters: "
                         f"{', '.join(declared) or 'none'})")
    out = {}
    for p in params:
        given = values.get(p.name)
        if given is None and not (p.optional and p.name in values):
            if p.required:
                raise InputError(f"{owner} needs the parameter {p.name} ({p.option})")
            out[p.name] = p.default
        else:
            out[p.name] = p.check(given, owner)
    return out


def _without_none(annotation: Any) -> Any:
    """Return ``X`` for ``X | None`` (or ``Optional[X]``), else the annotation."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return annotation


def dataclass_params(cls: type) -> list[Param]:
    """Return the fields of dataclass ``cls`` as parameter declarations, in field order.

    A field's type is the parameter's type (``X | None`` makes it optional); a field
    without a default is required. Its ``metadata`` documents it: ``help``, ``unit``,
    ``constraints`` and, where the option should be named otherwise, ``name`` (a field
    ``map_file`` shown as ``--map``). Raises TypeError when ``cls`` is not a dataclass.
    """
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        default = f.default if f.default is not MISSING else (
            f.default_factory() if f.default_factory is not MISSING else REQUIRED)
        flag = f.metadata.get("name")
        out.append(Param(
            name=f.name, type=_without_none(hints[f.name]), default=default,
            help=f.metadata.get("help", ""), unit=f.metadata.get("unit"),
            constraints=tuple(f.metadata.get("constraints", ())),
            optional=_without_none(hints[f.name]) is not hints[f.name],
            flag=None if flag is None else flag.replace("_", "-")))
    return out


def check_settings(params: Sequence[Param], values: object, owner: str) -> dict[str, Any]:
    """Return the settings ``values`` (a stored document: a model file's, a table's) that
    give some of the declared parameters, checked strictly; the ones not given are left
    to their owner's defaults.

    Stricter than :func:`check_params`, as a document is not typed by a command line: it
    must be an object; a name that is not declared, None for a parameter that is not
    ``optional``, a value of the wrong type (a bool is no number, a number no bool or
    string, a string no list) and a float that is not finite are refused, like a
    broken constraint, with an InputError naming ``owner``."""
    if not isinstance(values, Mapping):
        raise InputError(f"{owner} must be an object, got {type(values).__name__}")
    declared = {p.name: p for p in params}
    unknown = sorted(str(k) for k in set(values) - set(declared))
    if unknown:
        raise InputError(f"{owner}: unknown setting {unknown[0][:80]!r} (known: "
                         f"{', '.join(declared) or 'none'})")
    out: dict[str, Any] = {}
    for name, value in values.items():
        p = declared[name]
        if value is None:
            if not p.optional:
                raise InputError(f"{owner}: {name} must be given, got None")
            out[name] = None
            continue
        if p.type in (bool, str, list, dict) and not isinstance(value, p.type):
            raise InputError(f"{owner}: {name} must be {p.type.__name__}, got {value!r:.80}")
        value = p.check(value, owner)
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"{owner}: {name} must be finite, got {value!r}")
        out[name] = value
    return out


def check_names(values: object, name: str, owner: str) -> None:
    """Raise an InputError naming ``owner`` unless the setting ``name`` of a stored
    document, ``values``, is a non-empty list of names (strings)."""
    if not (values and isinstance(values, list | tuple)
            and all(isinstance(v, str) for v in values)):
        raise InputError(f"{owner}: {name} must be a non-empty list of names, got "
                         f"{values!r:.80}")


def parse_text(param: Param, text: str, owner: str) -> Any:
    """Return the command-line string ``text`` (``--option NAME=VALUE``'s value) as
    ``param``'s type: int, float, bool (true/false, yes/no, 1/0) or pathlib.Path; any
    other type keeps the string, for :meth:`Param.check`. Raises InputError naming
    ``owner`` when the text is not such a value."""
    kind = param.type
    try:
        if kind is bool:
            word = text.strip().lower()
            if word not in ("true", "false", "yes", "no", "1", "0"):
                raise ValueError(text)
            return word in ("true", "yes", "1")
        if kind in (int, float):
            return kind(text)
    except ValueError:
        raise InputError(f"{owner}: {param.name} must be {kind.__name__}, got "
                         f"{text!r:.80}") from None
    if kind is pathlib.Path:
        return pathlib.Path(text)
    return text


def make_config(owner: str, config_cls: type, values: Mapping[str, Any]) -> Any:
    """Return ``config_cls`` (a ``Config`` dataclass) built from ``values`` keyed by field
    name (None: not given, the field's default applies), each checked against its
    field's declaration. Raises InputError naming ``owner`` for a name it does not
    declare, a missing required option or a value it refuses."""
    given = {k: v for k, v in values.items() if v is not None}
    declared = dataclass_params(config_cls)
    missing = [o.option.removeprefix("--") for o in declared
               if o.required and o.name not in given]
    if missing:
        raise InputError(f"{owner} needs the option(s) {', '.join(missing)}")
    return config_cls(**check_params([o for o in declared if o.name in given], given, owner))
