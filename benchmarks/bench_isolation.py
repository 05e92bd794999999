"""Latency of contact isolation (:mod:`contactkit.features.isolation`): one update.

An update takes the joint positions and the residual's deviation from its baseline
and returns the touched link, point and force. The event pipeline makes one at the
decision, one at the peak and one every 20 ms (50 Hz) while a contact lasts. This
times updates on residuals of single contacts on every link 1-7 (random poses near
the thesis poses, points on the collision meshes, forces of 10-100 N within 40 deg of
the inward normal, plus white noise at the simulated Panda's residual noise at rest,
0.08 Nm on joint 1 to 0.009 Nm on the wrist), against baselines measured in the
same run: one pinocchio ``computeJointJacobians`` at the same q (the estimator makes
one per update) and numpy's norm of one 7-vector. Prints median and p99 [us] and
p99 / baseline p99; the aim is p99 <= 1 ms on the machine it runs on. On a machine
shared with other busy processes the wall-clock p99 of a sub-millisecond call is set
by the scheduler (a preempted update waits out another process's time slice, several
ms), so the update is also timed in the thread's own CPU time, with the share of
updates that waited more than 1 ms for the CPU, and, as in ``bench_events``, each
update's fastest CPU time over three passes: what the code costs, apart from the
moments a virtual machine's host runs something else.

    .venv/bin/python benchmarks/bench_isolation.py [--repeats N]
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pinocchio as pin
from bench_events import (  # the event benchmark's timing and table
    PASSES,
    cpu_timed,
    row,
    timed,
)

from contactkit.features.isolation import REST_NOISE_NM, robot_isolator
from contactkit.recorder.protocol import pose_q
from contactkit.recorder.sim.forces import inward_push
from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.robots.surfaces import link_surface

NOISE_NM = np.array(REST_NOISE_NM)


def contacts(n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """Return ``n`` (q [rad], residual [Nm], true link) of random single contacts."""
    model = RobotModel(RobotSetup())
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        link = int(rng.integers(1, 8))
        q = pose_q("ABCDEFGH"[int(rng.integers(8))]) + rng.normal(0, 0.1, 7)
        point, direction = inward_push(rng, link_surface(RobotSetup(), link))
        force = rng.uniform(10, 100) * model.frame_placement(q, link).rotation @ direction
        r = model.point_jacobian(q, link, point)[:3].T @ force + rng.normal(0, NOISE_NM, 7)
        out.append((q, r, link))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2000)
    n = parser.parse_args().repeats
    cases = contacts(n)
    isolator = robot_isolator(RobotSetup(with_hand=True))
    model, data = isolator.model, isolator.model.createData()
    for q, r, _ in cases[:50]:  # warm up
        isolator.estimate(0.0, q, r)
    jacobians = timed(lambda i: pin.computeJointJacobians(model, data, cases[i][0]), n)
    norm = timed(lambda i: np.linalg.norm(cases[i][1]), n)
    passes = [cpu_timed(lambda i: isolator.estimate(0.0, cases[i][0], cases[i][1]), n)
              for _ in range(PASSES)]
    updates, cpu = passes[0]
    fastest = np.min([cpu for _, cpu in passes], axis=0)  # the code's cost, less jitter
    found = [isolator.estimate(0.0, q, r).link == link for q, r, link in cases]
    base_j, base_n = float(np.percentile(jacobians, 99)), float(np.percentile(norm, 99))
    points = [len(s.points) for s in isolator.samples if s is not None]
    print(f"{n} updates, {sum(points)} surface samples ({min(points)}-{max(points)} per "
          f"link), link right in {np.mean(found):.1%} (noise at rest per joint)")
    print(f"{'':<44} {'median us':>10} {'p99 us':>9} {'p99/baseline':>13}")
    print(row("baseline: computeJointJacobians", jacobians, base_j, width=44))
    print(row("baseline: norm of a 7-vector", norm, base_n, width=44))
    print(row("isolation update / computeJointJacobians", updates, base_j, width=44))
    print(row("isolation update / norm", updates, base_n, width=44))
    print(row("isolation update, CPU time / computeJointJ.", cpu, base_j, width=44))
    print(row(f"the same, each update's fastest of {PASSES} passes", fastest, base_j,
              width=44))
    print(f"updates that waited > 1 ms for the CPU (preempted): "
          f"{np.mean(updates - cpu > 1000):.1%}")
    share = float(np.mean(updates)) * 50 / 1e6
    print(f"at 50 Hz during a contact: {share:.1%} of one core; p99 "
          f"{'within' if np.percentile(updates, 99) <= 1000 else 'above'} the 1 ms aim here "
          f"(CPU time: {'within' if np.percentile(cpu, 99) <= 1000 else 'above'})")


if __name__ == "__main__":
    main()
