"""A source's options, read from its ``Config`` dataclass.

Each field of a source's ``Config`` is one option. Its type (``str``, ``int``,
``float``, ``bool``, ``pathlib.Path``, a ``Literal`` or an ``Enum``, each optionally
``| None``) is the option's type; a field without a default is required. The field's
``metadata`` documents it: ``help`` (one sentence), ``unit`` (``"s"``, ``"Hz"``,
``"rad"``...) and, where the option's name should differ from the field's, ``name``
(for example a field ``map_file`` shown as option ``map``).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import MISSING, dataclass
from typing import Any

from contactkit.schemas import InputError


@dataclass(frozen=True)
class SourceOption:
    """One option of a source: its field, option name, type, help, unit and default."""

    field: str
    name: str
    type: Any
    help: str
    unit: str | None
    default: Any
    required: bool

    def describe(self) -> str:
        """Return the help text with the unit in brackets, and the default, on one line."""
        text = self.help
        if self.unit:
            text = f"{text.removesuffix('.')} [{self.unit}]."
        if self.required:
            text += " Required."
        elif self.default is not None:
            value = self.default.value if hasattr(self.default, "value") else self.default
            text += f" Default: {value}."
        return text


def _without_none(annotation: Any) -> Any:
    """Return ``X`` for ``X | None`` (or ``Optional[X]``), else the annotation."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return annotation


def source_options(config_cls: type) -> list[SourceOption]:
    """Return the options a source's ``Config`` dataclass declares, in field order.

    Raises TypeError when ``config_cls`` is not a dataclass.
    """
    hints = typing.get_type_hints(config_cls)
    options = []
    for f in dataclasses.fields(config_cls):
        required = f.default is MISSING and f.default_factory is MISSING
        default = None if required else (
            f.default if f.default is not MISSING else f.default_factory())
        options.append(SourceOption(
            field=f.name, name=f.metadata.get("name", f.name).replace("_", "-"),
            type=_without_none(hints[f.name]), help=f.metadata.get("help", ""),
            unit=f.metadata.get("unit"), default=default, required=required))
    return options


def make_config(source: str, config_cls: type, values: dict[str, Any]) -> Any:
    """Return ``config_cls(**values)``, values keyed by field name (None: not given, the
    field's default applies). Raises InputError naming a missing required option."""
    given = {k: v for k, v in values.items() if v is not None}
    missing = [o.name for o in source_options(config_cls)
               if o.required and o.field not in given]
    if missing:
        raise InputError(f"source {source!r} needs the option(s) {', '.join(missing)}")
    return config_cls(**given)
