"""The one seam for parallel work: map a function over items, in order, with progress.

Every parallel step (simulating datasets, reading sessions for statistics, feature
and grid extraction, evaluation splits, trainings) calls :func:`map_ordered`. The
local executor runs the items in a pool of processes on this machine (or in this
process with one worker); the results come back in the order of the items, so the
output never depends on the number of workers.

The executor is chosen by the ``scheduler`` argument, which every function that maps
jobs takes next to ``workers`` and passes on: None or ``local`` is the local pool;
``local:N`` or ``tcp://host:8786`` sends the jobs to Dask distributed (the ``dask``
extra, see :mod:`contactkit.util.dask_executor`), with the same results in the same
order. Nothing reads the environment here: the commands' ``--scheduler`` option takes
its default from ``$CONTACTKIT_SCHEDULER`` (:data:`SCHEDULER_ENV`) once, when the command
line is parsed, and passes the value down.

Functions and items must be picklable (module-level functions, plain data). A job
that reports a problem with an input returns it as data rather than raising, so one
bad session never stops a run; :func:`split_problems` separates them afterwards.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any, TypeVar

from contactkit.util.progress import ProgressCallback
from contactkit.util.workers import die_with_parent, join_parent, ordered_results

T = TypeVar("T")
R = TypeVar("R")

SCHEDULER_ENV = "CONTACTKIT_SCHEDULER"
"""The environment variable the commands' ``--scheduler`` option defaults to."""
WORKERS_PER_CPU = 4
"""A local pool holds at most this many processes per usable CPU (and no more than there
are jobs): ``--workers 100000`` would otherwise start processes until the machine stops."""

log = logging.getLogger(__name__)
CGROUP_CPU_FILES = (("/sys/fs/cgroup/cpu.max", None),  # cgroup v2: "quota period" or "max"
                    ("/sys/fs/cgroup/cpu/cpu.cfs_quota_us", "/sys/fs/cgroup/cpu/cpu.cfs_period_us"))


def available_cpus() -> int:
    """Return how many CPUs this process may really use (at least 1): the CPUs it may
    run on, further limited by a container's CPU quota (cgroup v1 or v2).

    ``os.cpu_count()`` counts the host's CPUs, which in a container limited to 2 CPUs
    of a large host would start a pool of dozens of processes on 2 CPUs' worth of time.
    """
    count = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
        os.cpu_count() or 1)
    for quota_file, period_file in CGROUP_CPU_FILES:
        try:
            fields = Path(quota_file).read_text().split()
            if period_file is not None:
                fields.append(Path(period_file).read_text().strip())
        except OSError:
            continue
        if len(fields) >= 2 and fields[0] not in ("max", "-1"):
            try:
                quota = float(fields[0]) / float(fields[1])
            except (ValueError, ZeroDivisionError):
                continue
            count = min(count, max(1, int(quota + 0.5)))
        break
    return max(1, count)


def resolve_scheduler(scheduler: str | None) -> str | None:
    """Return the Dask scheduler ``scheduler`` names, or None for the local pool (None,
    ``local`` or an empty string).

    A job already running on a Dask worker maps its own jobs locally (None), so a job
    never starts a cluster inside a cluster. Raises
    :class:`~contactkit.errors.InputError` on a malformed address.
    """
    if dask_worker_rank() is not None:
        return None
    chosen = (scheduler or "").strip()
    if chosen in ("", "local"):
        return None
    from contactkit.util.dask_executor import parse_scheduler

    parse_scheduler(chosen)
    return chosen


def dask_worker_rank() -> int | None:
    """Return the rank of the Dask worker this code runs on, None outside one.

    The rank is the worker's name where it is a number (a ``LocalCluster`` names its
    workers 0..N-1) or ends in one (``dask worker --nworkers N --name node`` names them
    node-0..node-N-1), else 0. Dask is not imported here: outside a worker it is
    usually not loaded at all.
    """
    distributed = sys.modules.get("distributed")
    if distributed is None:
        return None
    try:
        name = distributed.get_worker().name
    except ValueError:
        return None
    if isinstance(name, int):
        return name
    tail = str(name).rsplit("-", 1)[-1]
    return int(tail) if tail.isdigit() else 0


def pool_context(spawn: bool = False
                 ) -> tuple[multiprocessing.context.BaseContext, Callable[..., None],
                            tuple[Any, ...]]:
    """Return the multiprocessing context of the local pool and the initializer of its
    workers with its arguments, which make them end with this process.

    Workers are never plain forks of this process: a fork copies the memory of every
    library's thread pool but none of its threads, and a child of a process whose pool
    has run can hang in its next call (Polars' after a query; OpenBLAS's, waiting for
    its threads in a forked worker of a notebook's kernel). With ``spawn``
    they are fresh interpreters; else, where the platform has it, they are forked from
    a clean server process (``forkserver``, started once, with this process's state
    then; Python 3.14's default), and take on this process's environment and working
    directory as they are at the map (:func:`~contactkit.util.workers.join_parent`);
    elsewhere they are spawned. Like spawned workers, a server's do not see what this
    process changed in its modules, and a script that maps must guard with
    ``if __name__ == "__main__":``."""
    if spawn or "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn"), die_with_parent, (os.getpid(),)
    return (multiprocessing.get_context("forkserver"), join_parent,
            (os.getpid(), dict(os.environ), os.getcwd()))


def map_ordered(fn: Callable[..., R], items: Iterable[Any], *, workers: int = 1,
                progress: ProgressCallback | None = None, total: int | None = None,
                spawn: bool = False, in_flight: int = 4,
                scheduler: str | None = None) -> Iterator[R]:
    """Yield ``fn(item)`` for each item, in the order of ``items``.

    ``workers`` <= 1 runs in this process. Otherwise a pool of ``workers`` processes,
    at most one per job and :data:`WORKERS_PER_CPU` per usable CPU (with a warning)
    (``spawn``: fresh interpreters; else forked from a clean server process, see
    :func:`pool_context`; scripts must guard with ``if __name__ == "__main__":``)
    holds at most ``in_flight`` jobs per worker, so ``items`` may be a lazy generator of
    large inputs. ``progress(done, total)`` is called as jobs finish; ``total`` defaults to
    ``len(items)`` where it has one. An exception raised by ``fn`` propagates.
    ``scheduler`` (see :func:`resolve_scheduler`) other than local sends the jobs to
    a Dask cluster instead; ``workers`` and ``spawn`` then do not apply.
    """
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    address = resolve_scheduler(scheduler)
    if address is not None:
        from contactkit.util.dask_executor import dask_map_ordered

        yield from dask_map_ordered(fn, items, address, progress=progress, total=total,
                                    in_flight=in_flight)
        return
    done = 0
    if workers <= 1:
        for item in items:
            result = fn(item)
            done += 1
            if progress:
                progress(done, total or done)
            yield result
        return
    most = WORKERS_PER_CPU * available_cpus()
    if workers > most:
        log.warning("%d workers asked for; using %d (%d per usable CPU)", workers, most,
                    WORKERS_PER_CPU)
    workers = max(1, min(workers, most, total or workers))
    context, initializer, initargs = pool_context(spawn)
    with ProcessPoolExecutor(workers, mp_context=context, initializer=initializer,
                             initargs=initargs) as pool:
        yield from ordered_results(
            lambda item: pool.submit(fn, item),
            lambda jobs: wait(jobs, return_when=FIRST_COMPLETED).done,
            items, in_flight * workers, progress, total)


def split_problems(results: Iterable[tuple[str, T | None, str | None]]
                   ) -> tuple[list[T], list[tuple[str, str]]]:
    """Split ``(name, value, problem)`` job results into the good values and the
    ``(name, problem)`` pairs of the jobs that reported a problem."""
    good: list[T] = []
    problems: list[tuple[str, str]] = []
    for name, value, problem in results:
        if problem is None:
            good.append(value)  # type: ignore[arg-type]
        else:
            problems.append((name, problem))
    return good, problems
