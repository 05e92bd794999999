"""Feature sets for training and evaluation: one row per session, with its labels
and grouping keys.

Features of a dataset directory are computed once per feature configuration and
cached in contactkit's cache directory (``features/`` under $CONTACTKIT_CACHE, else
$XDG_CACHE_HOME/contactkit or ~/.cache/contactkit; keyed by the configuration, the
dataset's path and the names, sizes and modification times of the session files), so
``train`` after ``evaluate`` does not recompute them. Nothing is written into the
dataset directory, which may be read-only or hold a planted ``.cache`` link. A feature
table written by ``classify features`` is read as is.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from contactkit.classify.kinds.kind import ModelKind, ModelOptions
from contactkit.classify.names import GROUP_KEYS
from contactkit.classify.schemes import limited_mask, relabel
from contactkit.features.extract import SessionFeatures, feature_rows
from contactkit.features.window_features import check_config
from contactkit.schemas import InputError
from contactkit.schemas.dataset import session_files
from contactkit.schemas.features import read_feature_table
from contactkit.schemas.session import atomic_write_parquet
from contactkit.util.atomic import any_regular_file
from contactkit.util.cache import cache_dir
from contactkit.util.safe_open import parse_json


@dataclass
class FeatureSet:
    """Feature matrix ``X`` (sessions x features), names, and per-session columns
    (action, condition, pose, target pose, operator, session id, speed, window)."""

    X: np.ndarray
    names: list[str]
    info: dict[str, np.ndarray]
    config: dict
    problems: list[tuple[str, str]]

    def __len__(self) -> int:
        return len(self.X)

    def labels(self, scheme: str = "full") -> np.ndarray:
        """Return class labels under a class scheme."""
        return relabel(self.info["action"], scheme)

    def groups(self, by: str) -> np.ndarray:
        """Return the group of each session for group-aware splits.

        ``pose`` is the pose where the contact happens: the held pose (static) or
        the target pose of the move (dynamic); ``session``, ``operator`` and
        ``condition`` are what they say.
        """
        if by == "pose":
            target = self.info["target_pose"]
            return np.array([t if t else p for p, t in zip(self.info["pose"], target,
                                                            strict=True)], dtype=object)
        if by == "session":
            return self.info["session_id"]
        if by in ("operator", "condition"):
            return self.info[by]
        raise InputError(f"unknown grouping {by!r} (expected one of {', '.join(GROUP_KEYS)})")

    def subset(self, mask: np.ndarray) -> FeatureSet:
        """Return the sessions where ``mask`` is true."""
        return FeatureSet(self.X[mask], self.names, {k: v[mask] for k, v in self.info.items()},
                          self.config, self.problems)

    def limited(self) -> FeatureSet:
        """Return the limited context: no shove in static, no adjust in dynamic."""
        return self.subset(limited_mask(self.info["action"], self.info["condition"]))

    def columns(self, names: Sequence[str]) -> FeatureSet:
        """Return a feature set restricted to the named feature columns."""
        index = [self.names.index(n) for n in names]
        return FeatureSet(self.X[:, index], list(names), self.info, self.config, self.problems)

    def fingerprint(self) -> str:
        """Return a SHA-256 of the session ids, labels and feature values (hex)."""
        digest = hashlib.sha256()
        digest.update("\n".join(self.info["session_id"].astype(str)).encode())
        digest.update("\n".join(self.info["action"].astype(str)).encode())
        digest.update(np.ascontiguousarray(self.X).tobytes())
        return digest.hexdigest()


def _from_table(table: pa.Table, doc: dict, problems: list, X: np.ndarray | None = None
                ) -> FeatureSet:
    """Return the feature set of a scalar feature table; ``X``, where given, is its
    feature matrix already in hand (not read back from the table)."""
    names = list(doc["features"])
    if X is None:
        X = np.column_stack([table.column(n).to_numpy(zero_copy_only=False) for n in names]) \
            if table.num_rows else np.zeros((0, len(names)))
    info = {}
    for key in ("file", "session_id", "action", "condition", "pose", "target_pose", "operator",
                "window_method"):
        info[key] = np.array(table.column(key).to_pylist(), dtype=object)
    for key in ("speed_rad_s", "window_start_s", "planned_at_s", "link"):
        info[key] = np.array([np.nan if v is None else v for v in table.column(key).to_pylist()],
                             dtype=float)
    info["window_found"] = np.array(table.column("window_found").to_pylist(), dtype=bool)
    return FeatureSet(X, names, info, doc["config"], problems)


PROBLEMS_KEY = b"contactkit.problems"
"""Key of a cached feature table's metadata that lists the sessions whose features
failed, ``[[file, problem], ...]``: a cache remembers failures as well as results, so a
command served from it (``evaluate`` after ``train``) names every failed session and
exits 2 as the first did."""


def _cached_problems(table: pa.Table) -> list[tuple[str, str]] | None:
    """Return the failed sessions a cached feature table remembers; None for a cache
    without a readable list (written before failures were remembered), which is then
    computed anew and replaced."""
    raw = (table.schema.metadata or {}).get(PROBLEMS_KEY)
    try:
        doc = None if raw is None else parse_json(raw, "cached problem list")
    except InputError:
        return None
    if not (isinstance(doc, list) and all(
            isinstance(p, list) and len(p) == 2 and all(isinstance(x, str) for x in p)
            for p in doc)):
        return None
    return [(name, problem) for name, problem in doc]


def _cache_key(source: Path, files: list[Path], config: dict) -> str:
    digest = hashlib.sha256(json.dumps(config, sort_keys=True).encode())
    digest.update(f"{source.resolve()}\n".encode())
    for path in files:
        try:
            stat = path.stat()
        except OSError:  # a dangling link: listed as a problem when its features fail
            digest.update(f"{path.name}:unreadable\n".encode())
            continue
        digest.update(f"{path.name}:{stat.st_size}:{stat.st_mtime_ns}\n".encode())
    return digest.hexdigest()[:16]


def load_features(sources: Sequence[Path], extractor: SessionFeatures, workers: int = 1,
                  progress: Callable[[int, int], None] | None = None,
                  cache: bool = True, *, scheduler: str | None = None) -> FeatureSet:
    """Return the feature set of one or more dataset directories or feature tables,
    computed in ``workers`` processes or on the Dask ``scheduler``.

    Several sources are concatenated (for example a static and a dynamic dataset).
    """
    parts = [_load_one(Path(s), extractor, workers, progress, cache, scheduler)
             for s in sources]
    if len(parts) == 1:
        return parts[0]
    names = parts[0].names
    for part in parts[1:]:
        if part.names != names:
            raise InputError("the sources have different feature columns")
    info = {k: np.concatenate([p.info[k] for p in parts]) for k in parts[0].info}
    return FeatureSet(np.vstack([p.X for p in parts]), names, info, parts[0].config,
                      [x for p in parts for x in p.problems])


def _load_one(source: Path, extractor: SessionFeatures, workers: int,
              progress: Callable[[int, int], None] | None, cache: bool,
              scheduler: str | None) -> FeatureSet:
    if source.is_file():
        table, doc = read_feature_table(source)
        return _from_table(table, doc, [])
    if not source.is_dir():
        raise InputError("no such dataset directory or feature table", source)
    files = session_files(source)
    if not files:
        raise InputError("no session files (*.parquet) in this directory", source)
    extractor.fit(None)
    config = extractor.config()
    keyed = config if extractor.dynamics is None else config | {  # identified: another key
        "dynamics": extractor.dynamics.checksum}
    cache_path = cache_dir() / "features" / f"{_cache_key(source, files, keyed)}.parquet" \
        if cache else None
    if cache_path is not None and cache_path.is_file():
        table, doc = read_feature_table(cache_path)
        problems = _cached_problems(table)
        if problems is not None:
            return _from_table(table, doc, problems)
    result = feature_rows(files, extractor, workers, progress, scheduler=scheduler)
    if not len(result):
        raise InputError("no session could be processed", source)
    table = result.table(config)
    if cache_path is not None:
        cache_path.parent.mkdir(exist_ok=True)
        remembered = table.replace_schema_metadata(table.schema.metadata | {
            PROBLEMS_KEY: json.dumps([list(p) for p in result.problems]).encode()})
        atomic_write_parquet(remembered, cache_path, overwrite=False, owned=any_regular_file)
    return _from_table(table, {"config": config, "features": result.names}, result.problems,
                       result.X)


def features_for(options: ModelOptions, kind: ModelKind) -> SessionFeatures:
    """Return the scalar-feature input ``options`` describe, with the kind's defaults."""
    return SessionFeatures(timeseries=list(options.timeseries or kind.default_timeseries),
                           scalars=list(options.scalars),
                           window=options.window or kind.default_window,
                           window_s=options.window_s)


def features_from_config(config: dict) -> SessionFeatures:
    """Return the scalar-feature input a model file's configuration describes; InputError
    (naming no file) if it is malformed
    (:func:`contactkit.features.window_features.check_config`)."""
    return SessionFeatures(**check_config(config))
