"""Every parallel step goes through the one seam, contactkit.util.parallel.map_ordered:
no other module starts processes or pools of its own."""

from __future__ import annotations

import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("contactkit", "schemas", "features", "classify", "recorder", "replay")
POOLS = re.compile(r"\b(ProcessPoolExecutor|ThreadPoolExecutor|multiprocessing|joblib|"
                   r"n_jobs\s*=|dask\.|distributed\.)")
SEAM = {Path("contactkit/util/parallel.py"), Path("contactkit/util/dask_executor.py")}


def test_no_pool_outside_the_seam() -> None:
    offenders = [f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
                 for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))
                 if path.relative_to(ROOT) not in SEAM
                 for number, line in enumerate(path.read_text().splitlines(), 1)
                 if POOLS.search(line.split("#")[0])]
    assert not offenders, "\n".join(offenders)


def test_default_workers_follow_the_container_cpu_quota(tmp_path, monkeypatch) -> None:
    from contactkit.util import parallel

    v2, quota, period = tmp_path / "cpu.max", tmp_path / "quota", tmp_path / "period"
    monkeypatch.setattr(parallel, "CGROUP_CPU_FILES", ((str(v2), None),
                                                       (str(quota), str(period))))
    assert parallel.available_cpus() == len(os.sched_getaffinity(0))  # no cgroup files
    v2.write_text("max 100000\n")
    assert parallel.available_cpus() == len(os.sched_getaffinity(0))  # no quota
    v2.write_text("100000 100000\n")
    assert parallel.available_cpus() == 1
    v2.unlink()
    quota.write_text("50000\n")
    period.write_text("100000\n")
    assert parallel.available_cpus() == 1  # half a CPU still gets one worker


def test_a_pool_is_never_larger_than_the_machine_or_the_jobs(monkeypatch, caplog) -> None:
    """`--workers 100000` starts at most WORKERS_PER_CPU processes per usable CPU (with a
    warning), and never more processes than jobs."""
    import concurrent.futures

    from contactkit.util import parallel

    sizes: list[int] = []

    class Recording(concurrent.futures.ThreadPoolExecutor):
        def __init__(self, workers, **kwargs) -> None:
            sizes.append(workers)
            super().__init__(workers)

    monkeypatch.setattr(parallel, "ProcessPoolExecutor", Recording)
    monkeypatch.setattr(parallel, "available_cpus", lambda: 2)
    assert list(parallel.map_ordered(abs, [-1, -2, -3], workers=100_000)) == [1, 2, 3]
    assert list(parallel.map_ordered(abs, range(-50, 0), workers=100_000)) == list(
        range(50, 0, -1))
    assert sizes == [3, 2 * parallel.WORKERS_PER_CPU]
    assert "100000 workers asked for; using 8" in caplog.text


POLARS_IN_PARENT = """
import os
import sys

import polars as pl
from contactkit.util.parallel import map_ordered

def job(n):
    return pl.DataFrame({"a": list(range(n))}).lazy().select(pl.col("a").sum()).collect().item()

def where(_):
    return os.environ.get("CK_LATER"), os.getcwd()

if __name__ == "__main__":
    pl.DataFrame({"a": list(range(10000))}).lazy().group_by(pl.col("a") % 7).agg(
        pl.len()).collect()  # starts Polars' thread pool here
    print(list(map_ordered(job, [10, 100, 1000], workers=2)))
    os.environ["CK_LATER"] = "set later"  # after the fork server started
    os.chdir(sys.argv[1])
    print(set(map_ordered(where, range(4), workers=2)))
"""


def test_a_parent_that_ran_polars_still_gets_working_workers(tmp_path: Path) -> None:
    """A forked child of a process whose Polars thread pool has started hangs in its first
    query (the CI's import test hung so, after an earlier in-process import); the pool
    forks its workers from a clean server instead, and they take on the parent's
    environment and working directory of the moment, not the server's."""
    import subprocess
    import sys

    script = tmp_path / "polars_parent.py"
    script.write_text(POLARS_IN_PARENT)
    later = tmp_path / "later"
    later.mkdir()
    done = subprocess.run([sys.executable, str(script), str(later)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    sums, seen = done.stdout.strip().splitlines()
    assert sums == "[45, 4950, 499500]"
    # the workers see the parent's environment and directory as they are at the map
    assert seen == str({("set later", str(later))})
