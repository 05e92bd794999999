"""A source's options, read from its ``Config`` dataclass.

Each field of a source's ``Config`` is one option, declared as a
:class:`contactkit.util.params.Param` (see :func:`contactkit.util.params.dataclass_params`).
Its type (``str``, ``int``, ``float``, ``bool``, ``pathlib.Path``, a ``Literal`` or an
``Enum``, each optionally ``| None``) is the option's type; a field without a default is
required. The field's ``metadata`` documents it: ``help`` (one sentence), ``unit``
(``"s"``, ``"Hz"``, ``"rad"``...), ``constraints`` (:class:`contactkit.util.params.Interval`,
:class:`contactkit.util.params.Choice`), checked before the source is built, and, where
the option's name should differ from the field's, ``name`` (for example a field
``map_file`` shown as option ``--map``).
"""

from __future__ import annotations

from typing import Any

from contactkit.util.params import Param, dataclass_params
from contactkit.util.params import make_config as make_dataclass_config


def source_options(config_cls: type) -> list[Param]:
    """Return the options a source's ``Config`` dataclass declares, in field order.

    Raises TypeError when ``config_cls`` is not a dataclass.
    """
    return dataclass_params(config_cls)


def make_config(source: str, config_cls: type, values: dict[str, Any]) -> Any:
    """Return ``config_cls`` built from ``values`` (keyed by field name; None: not given,
    the field's default applies), each checked against its field's constraints. Raises
    InputError naming the source and a missing required option or a value it refuses
    (:func:`contactkit.util.params.make_config`)."""
    return make_dataclass_config(f"source {source!r}", config_cls, values)
