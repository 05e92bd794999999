"""One cache of the per-sample feature chain per session file and chain configuration.

The model-based and workspace timeseries (residual, gravity, inverse dynamics,
external power, wrench; :mod:`contactkit.features.timeseries`) cost a pinocchio
pass over every sample; the window, the scalar features and the grid applied after
them are cheap. :func:`chain_series` keeps those columns of each session in
``<contactkit cache>/chain/<key>/<feature>.parquet``, keyed by the session file
(absolute path, size, modification time, samples) and the chain settings (observer
gain and friction, wrench frame, hand, the gap after which it restarts), so features,
grids and experiments that differ only in their windows compute the chain once. A
changed file or setting is another key. Sessions not read from a file, or the cache
switched off, compute as before.

The cache is computed and written batch by batch (:meth:`TimeseriesChain.feed`, one Parquet
row group per batch), so filling it holds one batch of the session, however long
the session is; :func:`iter_chain_batches` reads it back the same way.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable, Iterator, Sequence
from contextlib import ExitStack
from dataclasses import asdict, replace
from pathlib import Path
from typing import cast

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.features.timeseries import (
    MODEL,
    WORKSPACE,
    ChainConfig,
    TimeseriesChain,
    columns_of,
    expand,
)
from contactkit.features.timing import RESTART_STEP_S
from contactkit.robots import RobotSetup
from contactkit.schemas import Session
from contactkit.schemas.session import SampleBatch, iter_sample_batches
from contactkit.util.atomic import any_regular_file, atomic_write
from contactkit.util.cache import cache_dir

CACHED = frozenset(MODEL + WORKSPACE)
CACHE_ENV = "CONTACTKIT_CHAIN_CACHE"
"""Set to 0 to compute the chain every time."""
BATCH_ROWS = 16_384
"""Samples computed (and cached in one row group) at a time (about 16 s at 1 kHz)."""


def _identity(settings: ChainConfig | RobotSetup) -> dict:
    """Return ``settings`` as a dictionary for a cache key, identified dynamics as their
    file's checksum."""
    dynamics = settings.dynamics
    return asdict(replace(settings, dynamics=None)) | {
        "dynamics": None if dynamics is None else dynamics.checksum}


def _key(session: Session, config: ChainConfig) -> str | None:
    if session.path is None or os.environ.get(CACHE_ENV) == "0":
        return None
    path = Path(session.path).resolve()
    try:
        stat = path.stat()
    except OSError:
        return None
    doc = {"file": str(path), "size": stat.st_size, "mtime_ns": stat.st_mtime_ns,
           "samples": session.n_samples,
           "robot": _identity(config.robot_setup(session.meta, session.path)),
           "urdf_sha256": session.meta.urdf_sha256,
           "config": _identity(config), "restart_step_s": RESTART_STEP_S}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def _read(path: Path, name: str, rows: int) -> np.ndarray | None:
    try:
        table = pq.read_table(path, columns=columns_of(name))
    except (OSError, pa.ArrowInvalid, KeyError):
        return None
    if table.num_rows != rows:
        return None
    return np.column_stack([table.column(c).to_numpy() for c in columns_of(name)])


def write_chain_files(batches: Iterable[SampleBatch], robot: RobotSetup, config: ChainConfig,
                      targets: dict[str, Path]) -> None:
    """Stream a session's complete samples (``batches``, consecutive chunks) through the
    chain and write each feature in ``targets`` (name -> Parquet path; its
    columns as in :func:`contactkit.features.timeseries.columns_of`) one row group per
    chunk, each file atomically."""
    chain = TimeseriesChain(config, robot, list(targets))
    writers: dict[str, pq.ParquetWriter] = {}
    with ExitStack() as stack:
        temps = {name: stack.enter_context(atomic_write(path, owned=any_regular_file))
                 for name, path in targets.items()}
        try:
            for batch in batches:
                if len(batch) == 0:
                    continue
                out = chain.feed(batch)
                for name, values in out.items():
                    group = pa.table({c: np.ascontiguousarray(v) for c, v in
                                      zip(columns_of(name), values.T, strict=True)})
                    if name not in writers:
                        writers[name] = pq.ParquetWriter(temps[name].file, group.schema)
                    writers[name].write_table(group)
        finally:
            for writer in writers.values():
                writer.close()
        for name, tmp in temps.items():
            tmp.keep = name in writers


def chain_series(session: Session, config: ChainConfig | None = None,
                 names: list[str] | tuple[str, ...] = ("dq", "tau", "r")
                 ) -> dict[str, np.ndarray]:
    """Return the named timeseries features of ``session`` (name -> (N, k) array, units
    as in :mod:`contactkit.features.timeseries`), the expensive ones from the cache
    when this session file and ``config`` were computed before. Equal to
    ``TimeseriesChain(config, config.robot_setup(session.meta)).compute(...)`` on the complete
    samples (exactly for sessions up to ``BATCH_ROWS`` samples, to about 1e-12 beyond)."""
    config = config or ChainConfig()
    names = expand(list(names))
    session = session.complete()
    key = _key(session, config)
    robot = config.robot_setup(session.meta, session.path)
    if key is None:
        return TimeseriesChain(config, robot).compute(
            session.t, session.q, session.dq, session.tau, names)
    directory = cache_dir() / "chain" / key
    rows = session.n_samples
    stored = {n: _read(directory / f"{n}.parquet", n, rows) for n in names if n in CACHED}
    missing = {n: directory / f"{n}.parquet" for n, v in stored.items() if v is None}
    if missing:
        directory.mkdir(parents=True, exist_ok=True)
        write_chain_files(iter_sample_batches(session, BATCH_ROWS), robot, config, missing)
        stored.update({n: _read(path, n, rows) for n, path in missing.items()})
    cheap = [n for n in names if n not in CACHED]
    computed = TimeseriesChain(config, robot).compute(
        session.t, session.q, session.dq, session.tau, cheap) if cheap else {}
    # every cached name is read back after writing
    return {n: cast(np.ndarray, stored[n]) if n in CACHED else computed[n] for n in names}


def iter_chain_batches(batches: Iterable[SampleBatch], robot: RobotSetup,
                       config: ChainConfig | None = None,
                       names: Sequence[str] = ("dq", "tau", "r")
                       ) -> Iterator[tuple[SampleBatch, dict[str, np.ndarray]]]:
    """Yield each chunk of a session's complete samples (``batches``, see
    :func:`contactkit.schemas.session.iter_sample_batches`) with its features (name ->
    (n, k) array), computed by one :class:`TimeseriesChain`: memory is bounded by one
    chunk."""
    chain = TimeseriesChain(config, robot, list(names))
    for batch in batches:
        if len(batch):
            yield batch, chain.feed(batch)
