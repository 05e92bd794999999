"""Feature tables: one row per session (scalar features) or per sample (timeseries).

A scalar feature table is Parquet with the identifying columns below, then one
float64 column per feature named like ``range(tau_3)``. Its key-value metadata
``contactkit.features`` holds a JSON document with the feature configuration and
the ordered feature names, so a model can refuse a table made for other features.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.errors import InputError
from contactkit.schemas.session import atomic_write_parquet
from contactkit.util.safe_open import parse_json

FEATURES_KEY = b"contactkit.features"
FEATURE_TABLE_VERSION = 1
ID_COLUMNS: list[tuple[str, pa.DataType]] = [
    ("file", pa.string()),
    ("session_id", pa.string()),
    ("action", pa.string()),
    ("condition", pa.string()),
    ("pose", pa.string()),
    ("target_pose", pa.string()),
    ("link", pa.int8()),
    ("operator", pa.string()),
    ("speed_rad_s", pa.float64()),
    ("window_start_s", pa.float64()),
    ("window_end_s", pa.float64()),
    ("window_method", pa.string()),
    ("window_found", pa.bool_()),
    ("planned_at_s", pa.float64()),
]
ID_NAMES = [name for name, _ in ID_COLUMNS]


def feature_table_schema(feature_names: list[str], config: dict[str, Any]) -> pa.Schema:
    """Return the schema of a scalar feature table for these features and config."""
    doc = {"version": FEATURE_TABLE_VERSION, "config": config, "features": feature_names}
    fields = [pa.field(n, t) for n, t in ID_COLUMNS]
    fields += [pa.field(n, pa.float64()) for n in feature_names]
    return pa.schema(fields, metadata={FEATURES_KEY: json.dumps(doc).encode()})


def feature_table(info: Sequence[Mapping[str, object]], X: np.ndarray,
                  feature_names: list[str], config: dict[str, Any]) -> pa.Table:
    """Return a scalar feature table: the identifying columns (:data:`ID_COLUMNS`) from
    ``info``, one mapping per session, and the feature columns from the matrix ``X``
    (sessions, features), taken as float64 arrays as they are."""
    schema = feature_table_schema(feature_names, config)
    X = np.asarray(X, dtype=float).reshape(len(info), len(feature_names))
    columns = [pa.array([row[name] for row in info], type=kind) for name, kind in ID_COLUMNS]
    columns += [pa.array(np.ascontiguousarray(X[:, j])) for j in range(len(feature_names))]
    return pa.Table.from_arrays(columns, schema=schema)


def write_feature_table(path: str | Path, table: pa.Table, overwrite: bool = True) -> Path:
    """Write a scalar feature table (see :func:`feature_table`) atomically; return the
    path."""
    path = Path(path)
    atomic_write_parquet(table, path, overwrite=overwrite)
    return path


def read_feature_table(path: str | Path) -> tuple[pa.Table, dict[str, Any]]:
    """Read a scalar feature table; return it and its feature document
    (``config``, ``features``). Raises InputError on a foreign file."""
    path = Path(path)
    try:
        table = pq.read_table(path)
    except (pa.ArrowInvalid, OSError) as err:
        raise InputError(f"not a readable Parquet file ({err})", path) from err
    meta = table.schema.metadata or {}
    if FEATURES_KEY not in meta:
        raise InputError("not a contactkit feature table (no feature metadata)", path)
    try:
        doc = parse_json(meta[FEATURES_KEY], "feature metadata", path)
        names = doc["features"]
    except (ValueError, KeyError, TypeError) as err:
        raise InputError(f"feature metadata is not a feature document ({err})", path) from err
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)
            and isinstance(doc.get("config", {}), dict)):
        raise InputError("feature metadata needs a list of feature names and a config "
                         "object", path)
    missing = [n for n in ID_NAMES + names if n not in table.column_names]
    if missing:
        raise InputError(f"feature table lacks column {missing[0]!r}", path)
    types = dict(zip(table.column_names, table.schema.types, strict=True))
    for name in names:
        if not pa.types.is_floating(types[name]):
            raise InputError(f"feature column {name!r} has type {types[name]}, expected "
                             "float64", path)
    return table, doc
