"""What the TOML map files (CAN frame maps, CSV column maps) share: reading the file,
turning every problem into one InputError naming it, and checking a field's value
against the allowed ones."""

from __future__ import annotations

import difflib
import tomllib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar, cast

from contactkit.schemas import InputError

Parsed = TypeVar("Parsed")
A = TypeVar("A")


def load_map_file(path: Path, what: str, parse: Callable[[dict, str], Parsed]) -> Parsed:
    """Read the TOML file ``path`` and return ``parse(document, str(path))``.

    ``what`` names the kind of file in messages ("frame map", "column map"). A missing
    or unreadable file, invalid TOML, and any KeyError, TypeError, ValueError,
    AttributeError or ArithmeticError of ``parse`` (a missing key, a value of the wrong
    type or out of range) become one :class:`InputError` naming the file.
    """
    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError as err:
        raise InputError(f"no such {what}", path) from err
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError) as err:
        raise InputError(f"not a valid TOML {what} ({type(err).__name__}: "
                         f"{str(err)[:200]})", path) from err
    except OSError as err:
        raise InputError(f"cannot read the {what} ({err.strerror or err})", path) from err
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
