"""One cache of the per-sample feature chain per session file and chain configuration.

The model-based and workspace timeseries (residual, gravity, inverse dynamics,
external power, wrench; :mod:`contactkit.features.timeseries`) cost a pinocchio
pass over every sample; the window, the scalar features and the grid applied after
them are cheap. :func:`chain_series` keeps those columns of each session in
``<contactkit cache>/chain/<key>.npz``, keyed by the session file (absolute path,
size, modification time, samples) and the chain settings (observer gain and
friction, wrench frame, hand), so features, grids and experiments that differ only
in their windows compute the chain once. A changed file or setting is another key.
Sessions not read from a file, or the cache switched off, compute as before.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict
from pathlib import Path

import numpy as np

from contactkit.features.timeseries import MODEL, WORKSPACE, ChainConfig, TimeseriesChain, expand
from contactkit.schemas import Session
from contactkit.util.cache import cache_dir

CACHED = frozenset(MODEL + WORKSPACE)
CACHE_ENV = "CONTACTKIT_CHAIN_CACHE"
"""Set to 0 to compute the chain every time."""


def _key(session: Session, config: ChainConfig) -> str | None:
    if session.path is None or os.environ.get(CACHE_ENV) == "0":
        return None
    path = Path(session.path).resolve()
    try:
        stat = path.stat()
    except OSError:
        return None
    doc = {"file": str(path), "size": stat.st_size, "mtime_ns": stat.st_mtime_ns,
           "samples": session.n_samples, "with_hand": session.meta.with_hand,
           "config": asdict(config)}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def _read(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path) as stored:
            return {name: stored[name] for name in stored.files}
    except (OSError, ValueError, EOFError):
        return {}


def _write(path: Path, series: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as out:
        np.savez(out, **series)
    tmp.replace(path)


def chain_series(session: Session, config: ChainConfig | None = None,
                 names: list[str] | tuple[str, ...] = ("dq", "tau", "r")
                 ) -> dict[str, np.ndarray]:
    """Return the named timeseries features of ``session`` (name -> (N, k) array, units
    as in :mod:`contactkit.features.timeseries`), the expensive ones from the cache
    when this session file and ``config`` were computed before. Equal to
    ``TimeseriesChain(config, session.meta.with_hand).compute(...)``."""
    config = config or ChainConfig()
    names = expand(list(names))
    key = _key(session, config)
    if key is None:
        return TimeseriesChain(config, session.meta.with_hand).compute(
            session.t, session.q, session.dq, session.tau, names)
    path = cache_dir() / "chain" / f"{key}.npz"
    stored = _read(path)
    missing = [n for n in names if n in CACHED and n not in stored]
    cheap = [n for n in names if n not in CACHED]
    computed: dict[str, np.ndarray] = {}
    if missing or cheap:
        computed = TimeseriesChain(config, session.meta.with_hand).compute(
            session.t, session.q, session.dq, session.tau, missing + cheap)
    if missing:
        stored.update({n: computed[n] for n in missing})
        _write(path, stored)
    return {n: stored[n] if n in CACHED else computed[n] for n in names}
