"""Dask distributed behind :func:`contactkit.util.parallel.map_ordered` (the ``dask`` extra).

A scheduler is named by a string:

* ``local:N`` starts a ``LocalCluster`` of N single-threaded worker processes on
  127.0.0.1 (for trying the cluster path on one machine);
* ``tcp://host:8786`` (or ``tls://``) connects to a running scheduler started with
  ``dask scheduler``, whose workers (``dask worker tcp://host:8786``) have contactkit
  installed and see the session files under the same paths.

One client per scheduler string is kept for the life of the process, so a command
that maps several steps starts its ``LocalCluster`` once. A worker that dies mid-run
loses nothing: the scheduler hands its jobs to the other workers (up to Dask's
``distributed.scheduler.allowed-failures`` deaths per job). An exception raised by
the mapped function propagates, as on the local path.
"""

from __future__ import annotations

import atexit
import itertools
import logging
import os
from collections.abc import Callable, Iterable, Iterator
from types import ModuleType
from typing import Any, TypeVar

from contactkit.errors import DependencyMissing, InputError, ResourceError
from contactkit.util.progress import ProgressCallback
from contactkit.util.workers import ordered_results

R = TypeVar("R")

CONNECT_TIMEOUT_S = 10.0
"""How long to wait for a remote scheduler before giving up [s]."""
JOBS_PER_WORKER = 8
"""Jobs per worker a known number of items is split into: few enough that scheduling
costs little, enough to balance the load and to lose little when a worker dies."""

log = logging.getLogger(__name__)
_clients: dict[str, Any] = {}


def parse_scheduler(address: str) -> tuple[str, int | None]:
    """Return ``("local", N)`` for ``local:N`` or ``(address, None)`` for a remote one.

    Raises :class:`InputError` on anything else.
    """
    if address.startswith("local:"):
        count = address.removeprefix("local:")
        if not count.isdigit() or int(count) < 1:
            raise InputError(f"scheduler {address!r}: local:N needs a worker count N >= 1")
        return "local", int(count)
    if address.startswith(("tcp://", "tls://")) and ":" in address.split("://", 1)[1]:
        return address, None
    raise InputError(f"scheduler {address!r} is not local, local:N or tcp://host:port")


def _require_distributed() -> ModuleType:
    try:
        import distributed
    except ImportError as err:
        raise DependencyMissing("a Dask scheduler needs Dask distributed: "
                                "pip install 'contactkit[dask]'") from err
    return distributed


def get_client(address: str) -> Any:
    """Return the (cached) ``distributed.Client`` of a scheduler string.

    Raises :class:`~contactkit.errors.ResourceError` when a remote scheduler does not
    answer, or has no worker, within :data:`CONNECT_TIMEOUT_S`, and
    :class:`~contactkit.errors.DependencyMissing` without the ``dask`` extra.
    """
    if address in _clients:
        return _clients[address]
    kind, count = parse_scheduler(address)
    distributed = _require_distributed()
    if kind == "local":
        import dask

        # Dask's nannies start workers with MALLOC_TRIM_THRESHOLD_=65536, which makes
        # glibc hand memory back to the system after every large free: one session's
        # features took 71 ms instead of 54 ms under it (bench_dask's +44 %).
        environ = {name: value for name, value in
                   dask.config.get("distributed.nanny.pre-spawn-environ").items()
                   if name != "MALLOC_TRIM_THRESHOLD_"}
        with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
            cluster = distributed.LocalCluster(n_workers=count, threads_per_worker=1,
                                               processes=True, host="127.0.0.1",
                                               dashboard_address=None,
                                               silence_logs=logging.CRITICAL)
        client = distributed.Client(cluster)
        client.register_plugin(_die_with_parent_plugin(os.getpid()))
        log.info("started a Dask LocalCluster of %d workers on 127.0.0.1", count)
    else:
        try:
            client = distributed.Client(address, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError) as err:
            raise ResourceError(f"cannot reach the Dask scheduler at {address} within "
                                f"{CONNECT_TIMEOUT_S:g} s") from err
        try:
            client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
        except TimeoutError as err:
            client.close()
            raise ResourceError(f"the Dask scheduler at {address} has no worker within "
                                f"{CONNECT_TIMEOUT_S:g} s (start some with `dask worker`)"
                                ) from err
        log.info("connected to the Dask scheduler at %s (%d worker threads)", address,
                 worker_count(client))
    _clients[address] = client
    return client


def _die_with_parent_plugin(parent_pid: int) -> Any:
    """Return a worker plugin for a LocalCluster: its workers end when this process
    (their parent) ends, even by SIGKILL (see
    :func:`contactkit.util.workers.die_with_parent`). Built here so that importing
    this module does not import distributed."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class DieWithParent(WorkerPlugin):
        name = "contactkit-die-with-parent"

        def setup(self, worker: Any) -> None:
            import os

            from contactkit.util.workers import die_with_parent

            if os.getppid() == parent_pid:
                die_with_parent(parent_pid)

    return DieWithParent()


def close_clients() -> None:
    """Close every client (and the local clusters) this process started."""
    while _clients:
        _, client = _clients.popitem()
        cluster = client.cluster
        client.close()
        if cluster is not None:
            cluster.close()


atexit.register(close_clients)


def worker_count(client: Any) -> int:
    """Return the number of worker threads the client's cluster has now (at least 1)."""
    threads: int = max(1, sum(client.nthreads().values()))
    return threads


def batch_size(total: int | None, workers: int) -> int:
    """Return how many items one Dask job takes: enough that each worker gets about
    :data:`JOBS_PER_WORKER` jobs when ``total`` (the item count) is known, else 1."""
    if not total:
        return 1
    return max(1, total // (workers * JOBS_PER_WORKER))


def _run_batch(fn: Callable[..., R], batch: list[Any]) -> list[R]:
    return [fn(item) for item in batch]


def _batches(items: Iterable[Any], size: int) -> Iterator[list[Any]]:
    iterator = iter(items)
    while batch := list(itertools.islice(iterator, size)):
        yield batch


def dask_map_ordered(fn: Callable[..., R], items: Iterable[Any], address: str, *,
                     progress: ProgressCallback | None = None, total: int | None = None,
                     in_flight: int = 4) -> Iterator[R]:
    """Yield ``fn(item)`` for each item in order, computed on the Dask cluster.

    Items go out in batches (:func:`batch_size`), so that a scheduler round trip per
    item is not paid for short jobs such as one session's features.
    At most ``in_flight`` jobs per worker thread are submitted at once (2 when
    batched), so ``items`` may be a lazy generator. ``progress(done, total)`` is called
    as jobs finish, counting items.
    """
    distributed = _require_distributed()
    client = get_client(address)
    workers = worker_count(client)
    size = batch_size(total, workers)

    def wait_first(jobs: list[Any]) -> Iterable[Any]:
        done: Iterable[Any] = distributed.wait(jobs, return_when="FIRST_COMPLETED").done
        return done

    if size == 1:
        yield from ordered_results(lambda item: client.submit(fn, item, pure=False),
                                   wait_first, items, in_flight * workers, progress, total)
        return
    assert total is not None  # a batch size above 1 needs the item count

    def batch_progress(done: int, _: int) -> None:
        if progress:
            progress(min(done * size, total), total)

    for results in ordered_results(
            lambda batch: client.submit(_run_batch, fn, batch, pure=False), wait_first,
            _batches(items, size), min(in_flight, 2) * workers, batch_progress,
            -(-total // size)):
        yield from results
