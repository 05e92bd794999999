"""Contact isolation and identification: synthetic residuals, simulated sessions,
batch = streaming, and estimates without a point (no surface, too small)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from contactkit.classify.events.contact_events import batch_events, stream_events
from contactkit.features.detector import DetectorConfig, detect
from contactkit.features.isolation import NO_SURFACE, OK, TOO_SMALL, ContactIsolator, robot_isolator
from contactkit.features.timeseries import TimeseriesChain
from contactkit.recorder.protocol import pose_q
from contactkit.recorder.sim.forces import inward_push
from contactkit.recorder.sim.simulator import ArmSimulator, SimConfig, plan_session
from contactkit.robots import RobotSetup
from contactkit.robots.model import RobotModel
from contactkit.robots.surfaces import link_surface
from contactkit.schemas import read_session
from tests.conftest import make_session

DETECTOR = DetectorConfig(noise=(0.5,) * 7, speed=(0.5,) * 7, accel=(0.02,) * 7)
# Tolerances on noise-free residuals of well-conditioned contacts (the last loaded
# joint carries at least 1 Nm). Links 6-7 load six or more joints: the wrench, hence
# the force's line of action, is determined and the point is where it enters the
# surface; each contact's point within 1.5 cm, direction within 12 degrees and
# magnitude within 8 % (a refinement that must cross to another face of the coarse
# mesh stops short), median direction within 1 degree. Link 5 loads five joints for
# five unknowns: finitely many solutions, so the median over its contacts is held to
# those tolerances. Links 1-4 load fewer joints than the five unknowns (point on the
# surface, force): the link is recovered and the fit reproduces the residual within
# 2 % of its norm, but the point is only known to lie on a curve.
POINT_M, DIRECTION_DEG, MEDIAN_DEG, MAGNITUDE = 0.015, 12.0, 1.0, 0.08
FIT_SHARE = 0.02


@pytest.fixture(scope="module")
def isolator() -> ContactIsolator:
    return robot_isolator(RobotSetup(with_hand=True))


@pytest.fixture(scope="module")
def model() -> RobotModel:
    return RobotModel(RobotSetup())


def _contacts(model: RobotModel, link: int, count: int, seed: int
              ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Return ``count`` well-conditioned contacts on ``link``: (q, point [m] link frame,
    force [N] world, residual [Nm])."""
    rng = np.random.default_rng([seed, link])
    surface = link_surface(RobotSetup(), link)
    out = []
    while len(out) < count:
        q = pose_q("ABCDEFGH"[int(rng.integers(8))]) + rng.normal(0, 0.1, 7)
        point, inward = inward_push(rng, surface)
        force = 30.0 * model.frame_placement(q, link).rotation @ inward
        r = model.point_jacobian(q, link, point)[:3].T @ force
        if abs(r[link - 1]) >= 1.0:
            out.append((q, point, force, r))
    return out


@pytest.mark.parametrize("link", range(1, 8))
def test_synthetic_residuals_give_back_link_point_and_force(isolator, model, link) -> None:
    misses, angles, sizes = [], [], []
    for q, point, force, r in _contacts(model, link, 4, seed=1):
        est = isolator.estimate(0.0, q, r)
        assert est.status == OK and est.link == link
        assert est.error_nm <= FIT_SHARE * np.linalg.norm(r)
        placement = model.frame_placement(q, link)
        np.testing.assert_allclose(est.point_base, placement.rotation @ est.point_link
                                   + placement.translation, atol=1e-9)
        misses.append(np.linalg.norm(est.point_link - point))
        cos = est.force @ force / np.linalg.norm(est.force) / np.linalg.norm(force)
        angles.append(np.degrees(np.arccos(min(cos, 1.0))))
        sizes.append(abs(np.linalg.norm(est.force) / np.linalg.norm(force) - 1))
    if link >= 6:
        assert max(misses) <= POINT_M and max(angles) <= DIRECTION_DEG
        assert max(sizes) <= MAGNITUDE
    if link >= 5:
        assert np.median(misses) <= POINT_M and np.median(angles) <= MEDIAN_DEG
        assert np.median(sizes) <= MAGNITUDE


def test_a_link_without_surface_gives_no_point_and_no_error(model) -> None:
    bare = ContactIsolator(model, lambda k: None if k == 5 else link_surface(RobotSetup(), k))
    q, _, _, r = _contacts(model, 5, 1, seed=2)[0]
    est = bare.estimate(1.0, q, r)
    assert est.status == NO_SURFACE and est.link == 5
    assert est.point_link is None and est.point_base is None and est.force is None
    doc = json.loads(json.dumps(est.to_dict()))
    assert doc["status"] == NO_SURFACE and doc["point_base_m"] is None


def test_a_small_residual_is_too_small_to_isolate(isolator) -> None:
    est = isolator.estimate(0.0, pose_q("B"), np.full(7, 0.1))
    assert est.status == TOO_SMALL and est.link is None and est.force is None
    assert est.to_dict()["link"] is None


def _same(a: object, b: object, tol: float = 1e-9) -> bool:
    """Return whether two JSON-like values are equal, numbers to ``tol`` (relative, and
    absolute near zero): the batch detector solves its filters in closed form."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k], tol) for k in a)
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y, tol) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        return abs(a - b) <= tol * max(1.0, abs(a), abs(b)) or (a != a and b != b)
    return a == b


def test_batch_and_streaming_give_the_same_estimates(tmp_path, isolator) -> None:
    session = read_session(make_session(tmp_path, action="adjust", link=6, seed=5,
                                        duration_s=3.5, planned_at_s=1.0))
    t, q, dq, tau = session.t, session.q, session.dq, session.tau
    r = TimeseriesChain().compute(t, q, dq, tau, ["r"])["r"]
    batch = batch_events(t, r, detect(t, r, dq, DETECTOR), None, 0.15, q, isolator)
    streamed, _ = stream_events(t, r, dq, DETECTOR, None, 0.15, q, isolator)
    assert len(batch) == len(streamed) >= 1
    for a, b in zip(batch, streamed, strict=True):  # the same to 1e-9, the project's bar
        assert _same(a.to_dict(), b.to_dict())
        assert _same([e.to_dict() for e in a.contact_track],
                     [e.to_dict() for e in b.contact_track])
    event = batch[0]
    assert event.contact_at_decision is not None and event.contact_at_peak is not None
    assert event.contact_at_peak.link == 6
    steps = np.diff([e.t_s for e in event.contact_track])
    assert steps.max() <= 0.02 + 0.002 + 1e-9  # 50 Hz, at the 500 Hz samples
    doc = json.loads(json.dumps(event.to_dict()))
    assert doc["contact_at_peak"]["link"] == 6 and len(doc["contact_at_peak"]["force_n"]) == 3


def test_isolation_sees_the_detectors_deviation_not_a_residual_spike(isolator, model) -> None:
    # a steady 3 Nm link-6 push with one sample of 0.5 Nm more on joint 7 (the
    # observer's velocity noise reaches the raw residual sample by sample): on the raw
    # residual the peak of |e| is that sample, and there link 7 explains it best; the
    # detector's low-passed deviation keeps the push's pattern, and every estimate is
    # made on it, batch and streaming alike
    (q, _, _, push), = _contacts(model, 6, 1, seed=1)
    push = 3.0 * push / np.linalg.norm(push)
    t = np.arange(0.0, 3.0, 0.002)
    ramp = np.clip(np.minimum(t - 1.0, 2.0 - t) / 0.1, 0.0, 1.0)
    r = ramp[:, None] * push[None, :]
    spike = int(np.searchsorted(t, 1.5))
    r[spike, 6] += 0.5 if push[6] >= 0 else -0.5
    qs, dq = np.tile(q, (len(t), 1)), np.zeros((len(t), 7))
    detection = detect(t, r, dq, DETECTOR)
    assert isolator.estimate(t[spike], q, r[spike] - detection.baseline[spike]).link == 7
    (event,) = batch_events(t, r, detection, None, 0.15, qs, isolator)
    (streamed,), _ = stream_events(t, r, dq, DETECTOR, None, 0.15, qs, isolator)
    assert _same(event.to_dict(), streamed.to_dict())
    assert event.contact_at_peak is not None and event.contact_at_peak.link == 6
    for estimate in [event.contact_at_peak, *event.contact_track]:
        k = int(np.searchsorted(t, estimate.t_s))
        assert estimate.residual_nm == pytest.approx(np.linalg.norm(detection.e[k]), rel=1e-9)


@pytest.mark.parametrize("gap_s", [1.1, 1.5])
def test_a_gap_that_cuts_a_contact_gives_the_same_estimates_batch_and_streaming(
        isolator, model, gap_s) -> None:
    # the event is released at the last sample before the gap (before its decision at
    # 1.1 s, after it at 1.5 s); streaming learns it at the sample after the gap
    (q, _, _, push), = _contacts(model, 6, 1, seed=1)
    t = np.arange(0.0, 3.0, 0.002)
    r = np.clip(np.minimum(t - 1.0, 2.0 - t) / 0.1, 0.0, 1.0)[:, None] * push[None, :]
    t[int(np.searchsorted(t, gap_s)):] += 2.0
    qs, dq = np.tile(q, (len(t), 1)), np.zeros((len(t), 7))
    batch = batch_events(t, r, detect(t, r, dq, DETECTOR), None, 0.15, qs, isolator)
    streamed, _ = stream_events(t, r, dq, DETECTOR, None, 0.15, qs, isolator)
    assert len(batch) == len(streamed) >= 1
    assert batch[0].release_s is not None and batch[0].release_s < gap_s
    assert batch[0].contact_at_decision is not None and batch[0].contact_at_peak is not None
    for a, b in zip(batch, streamed, strict=True):
        assert _same(a.to_dict(), b.to_dict())


# Rate per link at which a simulated static shove's event (at its peak) names the true
# link, 5 sessions per link, with the simulator's sensor noise and model error: links
# 3-7 at least 4 of 5, links 1-2 at least 3 of 5 (link 1 loads one joint, link 2
# two: a push near their axes leaves too little to isolate). Measured with the
# noise-weighted fit: 33 of 35 (link 1 twice too small to isolate, one link-3 contact
# named 4); unweighted it was 32 of 35.
SIM_RATE = {1: 0.6, 2: 0.6, 3: 0.8, 4: 0.8, 5: 0.8, 6: 0.8, 7: 0.8}


def test_simulated_sessions_name_the_touched_link(isolator) -> None:
    config = SimConfig(rate_hz=500.0)
    specs = [plan_session(seed=100 * link + k, condition="static", action="shove",
                          pose="ABCDEFGH"[(link + k) % 8], link=link, duration_s=2.0,
                          planned_at_s=0.8, pose_jitter_rad=0.1)
             for link in range(1, 8) for k in range(5)]
    parts: dict[int, list[dict[str, np.ndarray]]] = {}
    found: dict[int, list[int | None]] = {link: [] for link in range(1, 8)}
    for index, columns, finished in ArmSimulator(config).run(specs):
        parts.setdefault(index, []).append(columns)
        if not finished:
            continue
        chunks = parts.pop(index)
        data = {k: np.concatenate([c[k] for c in chunks]) for k in columns}
        t = data["t"]
        q, dq, tau = (np.column_stack([data[f"{p}_{j}"] for j in range(1, 8)])
                      for p in ("q", "dq", "tau"))
        r = TimeseriesChain().compute(t, q, dq, tau, ["r"])["r"]
        events = batch_events(t, r, detect(t, r, dq, DETECTOR), None, 0.15, q, isolator)
        peaks = [e.contact_at_peak for e in events if e.contact_at_peak is not None]
        best = max(peaks, key=lambda e: e.residual_nm, default=None)
        found[specs[index].link].append(None if best is None else best.link)
    for link, links in found.items():
        rate = np.mean([x == link for x in links])
        assert len(links) == 5 and rate >= SIM_RATE[link], (link, links)


def test_a_torque_on_joint_1_alone_is_link_1_and_ambiguous(isolator) -> None:
    est = isolator.estimate(0.0, pose_q("B"), np.array([2.0, 0, 0, 0, 0, 0, 0]))
    assert est.status == OK and est.link == 1 and est.ambiguous
    assert np.isfinite(est.error_nm) and np.all(np.isfinite(est.force))


def test_model_error_the_detector_expects_does_not_move_the_link(isolator, model) -> None:
    # 0.3 Nm of model error on joint 6 is thirty times its noise at rest, but a joint
    # whose detector threshold has grown to 5 Nm (the arm moving) weighs that much less
    threshold = np.full(7, 0.3)
    threshold[5] = 5.0
    for q, _, _, r in _contacts(model, 5, 6, seed=3):
        biased = r + np.eye(7)[5] * 0.3
        assert isolator.estimate(0.0, q, biased, threshold).link == 5


def test_threads_never_share_an_isolator() -> None:
    """An isolator owns pinocchio data, so each thread gets its own, built once."""
    import threading

    robot = RobotSetup(with_hand=True)
    mine = robot_isolator(robot)
    assert robot_isolator(robot) is mine
    other: list[object] = []
    worker = threading.Thread(target=lambda: other.append(robot_isolator(robot)))
    worker.start()
    worker.join()
    assert other[0] is not mine and other[0].data is not mine.data
