"""What the TOML map files (CAN frame maps, CSV column maps) share: reading the file,
turning every problem into one InputError naming it, and checking a field's value
against the allowed ones."""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar, cast

from contactkit.schemas import InputError
from contactkit.util.safe_open import read_input_text
from contactkit.util.text import printable

Parsed = TypeVar("Parsed")
A = TypeVar("A")


def load_map_file(path: Path, what: str, parse: Callable[[dict, str], Parsed]) -> Parsed:
    """Read the TOML file ``path`` and return ``parse(document, str(path))``.

    ``what`` names the kind of file in messages ("frame map", "column map"). The file
    is read through :func:`~contactkit.util.safe_open.read_input_text` (a regular file
    of at most 1 MiB). A missing, special or unreadable file, invalid TOML, and any
    KeyError, TypeError, ValueError, AttributeError or ArithmeticError of ``parse`` (a
    missing key, a value of the wrong type or out of range) become one
    :class:`InputError` naming the file.
    """
    text = read_input_text(path, what, "map")
    try:
        doc = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as err:
        raise InputError(f"not a valid TOML {what} ({type(err).__name__}: "
                         f"{printable(str(err)[:200])})", path) from err
    try:
        return parse(doc, str(path))
    except KeyError as err:
        raise InputError(f"bad {what}: missing key {err}", path) from err
    except (TypeError, ValueError, AttributeError, ArithmeticError, RecursionError) as err:
        raise InputError(f"bad {what}: {str(err)[:300]}", path) from err


def known_keys(table: object, allowed: Iterable[str], where: str,
               required: Iterable[str] = ()) -> dict:
    """Return ``table`` when it is a TOML table that holds the ``required`` keys and no
    key outside ``allowed``; else raise ValueError naming the missing or first unknown key
    in ``where`` with a "did you mean" (:func:`load_map_file` turns it into an
    InputError). A typo such as ``units`` for ``unit`` or ``byte_oder`` would otherwise
    be ignored and import wrong values."""
    if not isinstance(table, dict):
        raise TypeError(f"{where} must be a table, got {type(table).__name__}")
    allowed = sorted(allowed)
    unknown = [str(key) for key in table if key not in allowed]

    def hint(key: str, among: list[str]) -> str:
        close = difflib.get_close_matches(key, among, n=1, cutoff=0.6)
        return f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(among)})"

    for key in required:
        if key not in table:
            found = difflib.get_close_matches(key, unknown, n=1, cutoff=0.6)
            also = f" (found {found[0][:80]!r}: a typo?)" if found else ""
            raise ValueError(f"missing key {key!r} in {where}{also}")
    if unknown:
        raise ValueError(f"unknown key {unknown[0][:80]!r} in {where}"
                         f"{hint(unknown[0], allowed)}")
    return table


def one_of(value: object, allowed: Iterable[A], what: str) -> A:
    """Return ``value`` when it is one of ``allowed`` (the same value and type: 1.0 is
    not 1); else raise ValueError naming ``what`` and the allowed values
    (:func:`load_map_file` turns it into an InputError)."""
    allowed = list(allowed)
    if not any(type(value) is type(a) and value == a for a in allowed):
        names = [str(a) for a in allowed]
        choices = names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"
        raise ValueError(f"{what} must be {choices}, got {value!r}")
    return cast(A, value)  # equal in value and type to one of allowed


def integer(value: object, what: str, low: int | None = None, high: int | None = None) -> int:
    """Return ``value`` when it is a TOML integer (not a boolean, not a string of digits,
    not a float) within [``low``, ``high``]; else raise ValueError naming ``what``
    (:func:`load_map_file` turns it into an InputError)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{what} must be an integer, got {str(value)[:40]!r}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise ValueError(f"{what} must be in [{low}, {high}], got {value}")
    return value


def number(value: object, what: str) -> float:
    """Return ``value`` as a float when it is a finite TOML number (integer or float, not
    a boolean or a string); else raise ValueError naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{what} must be a number, got {str(value)[:40]!r}")
    if not math.isfinite(value):
        raise ValueError(f"{what} must be finite, got {value}")
    return float(value)


def boolean(value: object, what: str) -> bool:
    """Return ``value`` when it is a TOML boolean (``true``/``false``, not the string
    ``"false"``, which Python reads as true); else raise ValueError naming ``what``."""
    if not isinstance(value, bool):
        raise ValueError(f"{what} must be true or false, got {str(value)[:40]!r}")
    return value
