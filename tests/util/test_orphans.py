"""Workers die with their parent (issue 25): after a SIGKILL of the command, neither the
local pool's workers nor a LocalCluster's keep running."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

CHILD = """
import os, sys, time
from contactkit.util.parallel import map_ordered

def job(_):
    time.sleep(600)
    return os.getpid()

if __name__ == "__main__":
    mode = sys.argv[1] if len(sys.argv) > 1 else None
    if mode == "polars":  # a thread pool in this process; workers come from a fork server
        import polars as pl
        pl.DataFrame({"a": [1, 2, 3]}).lazy().select(pl.col("a").sum()).collect()
        for _ in map_ordered(job, range(4), workers=2):
            pass
    else:
        for _ in map_ordered(job, range(4), workers=2, spawn=True, scheduler=mode):
            pass
"""


def _children(pid: int) -> set[int]:
    """Return the pids of all descendants of ``pid`` (from /proc)."""
    found, frontier = set(), {pid}
    while frontier:
        parent = frontier.pop()
        kids = set()
        try:  # children started by any thread (Dask's nannies start them from theirs)
            for task in os.listdir(f"/proc/{parent}/task"):
                with open(f"/proc/{parent}/task/{task}/children") as fh:
                    kids |= {int(p) for p in fh.read().split()}
        except OSError:
            pass
        frontier |= kids - found
        found |= kids
    return found


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not os.path.exists("/proc/self/task"), reason="needs Linux /proc")
@pytest.mark.timeout(240)
@pytest.mark.parametrize("scheduler", [None, "local:2", "polars"])
def test_workers_die_with_a_killed_parent(scheduler, tmp_path) -> None:
    if scheduler == "local:2":
        pytest.importorskip("distributed")
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    proc = subprocess.Popen([sys.executable, str(script), *([scheduler] if scheduler else [])],
                            start_new_session=True)
    try:
        workers: set[int] = set()
        deadline = time.monotonic() + 180
        while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
            workers = {p for p in _children(proc.pid) if _alive(p)}
        assert len(workers) >= 2, "the workers did not start"
        time.sleep(2.0)  # let the pool hand out its jobs
        workers = {p for p in _children(proc.pid) if _alive(p)}
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and any(_alive(p) for p in workers):
            time.sleep(0.2)
        left = [p for p in workers if _alive(p)]
        for pid in left:
            os.kill(pid, signal.SIGKILL)
        assert not left, f"{len(left)} workers outlived their parent"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
