"""What every executor of :func:`contactkit.util.parallel.map_ordered` shares: workers that
end with their parent, and the windowed loop that yields results in the items' order.
Both the local process pool and the Dask executor build on this module."""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from contactkit.util.progress import ProgressCallback

PR_SET_PDEATHSIG = 1
PARENT_POLL_S = 0.5
"""How often [s] a worker checks that its parent is alive, where the kernel cannot tell
it (PR_SET_PDEATHSIG is Linux only)."""


def die_with_parent(parent_pid: int | None = None) -> None:
    """Make this (worker) process end when its parent ends, also when the parent is
    killed with SIGKILL and cannot clean up: a killed command never leaves workers
    running (or blocked forever, holding their memory).

    On Linux the kernel sends SIGKILL on the parent's death (``PR_SET_PDEATHSIG``);
    elsewhere, and as a second guard, a daemon thread polls the parent pid every
    :data:`PARENT_POLL_S` s. ``parent_pid`` defaults to the current parent.
    """
    parent = os.getppid() if parent_pid is None else parent_pid
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the parent died before the line above
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(PARENT_POLL_S)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="contactkit-parent-watch", daemon=True).start()


def die_with(pid: int) -> None:
    """Make this (worker) process end when process ``pid`` ends, where that is not its
    parent: a fork server's worker (see :func:`contactkit.util.parallel.pool_context`),
    whose parent, the server, lives as long as its workers do. A daemon thread checks
    every :data:`PARENT_POLL_S` s that ``pid`` is still running (a zombie is not)."""
    def running() -> bool:
        try:
            with open(f"/proc/{pid}/stat") as fh:
                return fh.read().rsplit(")", 1)[-1].split()[0] != "Z"
        except FileNotFoundError:
            return False
        except OSError:  # no /proc: ask the kernel (a zombie still answers there)
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return False
            except PermissionError:
                pass
            return True

    def watch() -> None:
        while running():
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="contactkit-parent-watch", daemon=True).start()


def join_parent(pid: int, environ: dict[str, str], cwd: str) -> None:
    """Start a fork server's worker as a child of process ``pid`` would start: with its
    environment ``environ`` and working directory ``cwd`` as they are now (the server
    keeps those of when it started), ending with it (:func:`die_with`)."""
    os.environ.clear()
    os.environ.update(environ)
    os.chdir(cwd)
    die_with(pid)


def ordered_results(submit: Callable[[Any], Any],
                    wait_first: Callable[[list[Any]], Iterable[Any]],
                    items: Iterable[Any], limit: int, progress: ProgressCallback | None,
                    total: int | None) -> Iterator[Any]:
    """Run ``items`` through an executor and yield the results in the order of the items:
    the windowed collection loop every executor shares.

    ``submit(item)`` returns a future (``result()``, ``cancel()``); ``wait_first(futures)``
    blocks until at least one is done and returns the finished ones. At most ``limit``
    futures are pending at once; ``progress(done, total)`` is called as they finish, and
    the futures still pending when the caller stops (or a job raises) are cancelled.
    """
    results: dict[int, Any] = {}
    pending: dict[Any, int] = {}
    next_out = done = 0
    iterator = iter(enumerate(items))
    exhausted = False
    try:
        while not exhausted or pending:
            while not exhausted and len(pending) < limit:
                try:
                    index, item = next(iterator)
                except StopIteration:
                    exhausted = True
                    break
                pending[submit(item)] = index
            if not pending:
                break
            for job in wait_first(list(pending)):
                results[pending.pop(job)] = job.result()
                done += 1
                if progress:
                    progress(done, total or done + len(pending))
            while next_out in results:
                yield results.pop(next_out)
                next_out += 1
    finally:
        for job in pending:
            job.cancel()
