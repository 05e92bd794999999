"""What the fuzz tests share: the property check, value strategies and a small TOML writer."""

from __future__ import annotations

import json
import math
from pathlib import Path

from hypothesis import event
from hypothesis import strategies as st

from contactkit.schemas import InputError

FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)
JSON_SCALARS = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20)
JSON_VALUES = st.recursive(JSON_SCALARS, lambda inner: st.lists(inner, max_size=8)
                           | st.dictionaries(st.text(max_size=10), inner, max_size=5),
                           max_leaves=20)


def refused_or(fn, *args, **kwargs):
    """Call ``fn``; return its result, or None when it refused with a one-line InputError."""
    try:
        result = fn(*args, **kwargs)
    except InputError as err:
        assert "\n" not in str(err) and err.problem
        event(f"{fn.__name__}: refused")
        return None
    event(f"{fn.__name__}: accepted")
    return result


def nothing_outside(root: Path, allowed: Path) -> None:
    """Assert that every session file under ``root`` lies inside ``allowed``."""
    for path in root.rglob("*.parquet"):
        assert path.resolve().is_relative_to(allowed.resolve()), path


def tables(value) -> list[dict]:
    """Return every table (dict) inside a parsed TOML document, the document first."""
    if isinstance(value, dict):
        return [value, *[t for v in value.values() for t in tables(v)]]
    if isinstance(value, list):
        return [t for v in value for t in tables(v)]
    return []


def mutate_document(doc: dict, data) -> dict:
    """Return a copy of ``doc`` with 1-3 values (or new keys) anywhere in it replaced by
    drawn JSON values, hostile numbers and type names."""
    doc = json.loads(json.dumps(doc))
    for _ in range(data.draw(st.integers(1, 3))):
        parent = data.draw(st.sampled_from(tables(doc)))
        key = data.draw(st.sampled_from([*sorted(parent), "extra"]))
        parent[key] = data.draw(JSON_VALUES | st.sampled_from(
            [-4, 0, 1e308, 10**400, "big", "int8", "{j}", "", [], {}]))
    return doc


def to_toml(doc: dict) -> str:
    """A small TOML writer for map documents (JSON-like values; tables of tables as
    inline tables; None as an empty string)."""
    def value(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int):
            return str(v)
        if isinstance(v, float):
            return repr(v) if math.isfinite(v) else ("nan" if v != v else
                                                     ("inf" if v > 0 else "-inf"))
        if isinstance(v, str):
            return json.dumps(v)
        if v is None:
            return '""'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return "{" + ", ".join(f"{json.dumps(k)} = {value(x)}" for k, x in v.items()) + "}"
    return "\n".join(f"{json.dumps(k)} = {value(v)}" for k, v in doc.items()) + "\n"
