"""Every parallel step goes through the one seam, contactkit.util.parallel.map_ordered:
no other module starts processes or pools of its own."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
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
