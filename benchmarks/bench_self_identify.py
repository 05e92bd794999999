"""A moving arm's dataset scored with its arm identified from itself: time, by workers.

``classify predict --events`` identifies a moving arm's dataset from itself,
cross-fitted over two halves of its poses, then scores its sessions
(:mod:`contactkit.features.self_identification`). This times the two steps through the
library the command calls, on a dataset given as an argument or, by default, the 128
sessions of the ``mixed-motion`` preset (8 s each at 500 Hz, one robot instance):

- the baseline, measured in the same run: scoring every session with the nominal
  model (``--no-identify``), one process;
- the identification of both halves, one after the other (``--workers 1``) and at once
  (``--workers 2``);
- scoring with the identified arms, one process and two.

Prints each time [s] and its ratio to the baseline, the end-to-end ratio of ``--workers
2`` to ``--workers 1``, and whether both give the same events (they must). With two
workers on a machine of one core the ratio shows the pool's cost, not a gain.

    .venv/bin/python benchmarks/bench_self_identify.py [DATASET_DIR]
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from contactkit.classify.prediction import predict_events
from contactkit.cli.default_model import model_or_default
from contactkit.features.self_identification import (
    cross_fitted_dynamics,
    dynamics_by_session,
    survey,
)
from contactkit.recorder.sim.dataset import simulate_dataset
from contactkit.recorder.sim.simulator import SimConfig
from contactkit.schemas.dataset import session_files

SESSIONS, ROBOT_SEED = 128, 11


def _timed(work):
    started = time.perf_counter()
    result = work()
    return result, time.perf_counter() - started


def run(directory: Path) -> None:
    model = model_or_default(None)
    detector = model.detector_config()
    paths = session_files(directory)
    surveyed = survey(paths)

    def scored(own, workers):
        return [(str(p), [e.to_dict() for e in events or []], problem) for p, events, problem
                in predict_events(model, paths, None, own=own, workers=workers)]

    nominal, base_s = _timed(lambda: scored({}, 1))
    folds_1, identify_1 = _timed(lambda: cross_fitted_dynamics(surveyed, detector, workers=1))
    folds_2, identify_2 = _timed(lambda: cross_fitted_dynamics(surveyed, detector, workers=2))
    events_1, score_1 = _timed(lambda: scored(dynamics_by_session(folds_1), 1))
    events_2, score_2 = _timed(lambda: scored(dynamics_by_session(folds_2), 2))
    motion = sum(s.motion_s for s in surveyed)
    print(f"{len(paths)} sessions, {motion:.0f} s of motion; {sum(len(e) for _, e, _ in nominal)}"
          f" events with the nominal model, {sum(len(e) for _, e, _ in events_1)} identified")
    print(f"  baseline: scoring with the nominal model, 1 process   {base_s:7.1f} s   1.00")
    for name, seconds in (("identifying both halves, --workers 1", identify_1),
                          ("identifying both halves, --workers 2", identify_2),
                          ("scoring identified,       --workers 1", score_1),
                          ("scoring identified,       --workers 2", score_2)):
        print(f"  {name:52s}{seconds:7.1f} s {seconds / base_s:6.2f}")
    whole_1, whole_2 = identify_1 + score_1, identify_2 + score_2
    print(f"  end to end: --workers 1 {whole_1:.1f} s, --workers 2 {whole_2:.1f} s, ratio "
          f"{whole_2 / whole_1:.2f}; same events: {events_1 == events_2}")


def main() -> None:
    if len(sys.argv) > 1:
        run(Path(sys.argv[1]))
        return
    with tempfile.TemporaryDirectory() as directory:
        simulate_dataset(Path(directory), "mixed-motion", SESSIONS, ROBOT_SEED, 1,
                         SimConfig(rate_hz=500.0, robot_seed=ROBOT_SEED))
        run(Path(directory))


if __name__ == "__main__":
    main()
