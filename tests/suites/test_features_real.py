"""The feature chain checked on the real Panda recording (and the simulator against it)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from contactkit.features.observer import ObserverConfig
from contactkit.features.timeseries import ALL_TIMESERIES, ChainConfig, TimeseriesChain
from contactkit.features.windows import WindowSpec, find_window
from contactkit.recorder.importers.arrays import load_joint_arrays
from contactkit.recorder.sim.simulator import SimConfig, TrackingSimulator, plan_session
from contactkit.robots import RobotSetup
from contactkit.schemas import read_session
from tests.conftest import make_session


@pytest.fixture(scope="module")
def real(reference_dir: Path) -> dict[str, np.ndarray]:
    return load_joint_arrays(*(reference_dir / f for f in ("time.txt", "positions.txt",
                                                           "velocity.txt", "torques.txt")))


def _rms(x: np.ndarray) -> np.ndarray:
    return np.sqrt((x**2).mean(axis=0))


def test_residual_at_the_level_of_model_error(real) -> None:
    chain = TimeseriesChain(robot=RobotSetup(with_hand=False))
    r = chain.compute(real["t"], real["q"], real["dq"], real["tau"], ["r"])["r"]
    settled = real["t"] > 1.0
    rms = _rms(r[settled])
    assert 0.5 < rms[1] < 1.5, rms
    assert (np.delete(rms, 1) < 0.8).all(), rms
    no_friction = TimeseriesChain(ChainConfig(ObserverConfig(friction=False)),
                                  robot=RobotSetup(with_hand=False))
    r_raw = no_friction.compute(real["t"], real["q"], real["dq"], real["tau"], ["r"])["r"]
    assert (_rms(r_raw[settled]) > rms).sum() >= 5


@pytest.mark.parametrize("planned_at", [6.0, 10.0, 15.0])
@pytest.mark.parametrize("method", ["difference", "change"])
def test_window_methods_find_no_interaction_in_free_motion(real, planned_at: float,
                                                           method: str) -> None:
    window = find_window(real["t"], planned_at, WindowSpec(method=method), real["tau"])
    assert not window.found
    assert window.start_s == planned_at


def _assert_stream_equals_batch(t, q, dq, tau, with_hand: bool) -> None:
    batch = TimeseriesChain(robot=RobotSetup(with_hand=with_hand)).compute(t, q, dq, tau)
    online = TimeseriesChain(robot=RobotSetup(with_hand=with_hand))
    stream = {name: [] for name in ALL_TIMESERIES}
    for k in range(len(t)):
        sample = online.update(t[k], q[k], dq[k], tau[k])
        for name in ALL_TIMESERIES:
            stream[name].append(sample[name])
    for name in ALL_TIMESERIES:
        assert np.abs(np.array(stream[name]) - batch[name]).max() <= 1e-9, name


def test_batch_and_streaming_agree_on_real_recording(real) -> None:
    _assert_stream_equals_batch(real["t"], real["q"], real["dq"], real["tau"], with_hand=False)


def test_batch_and_streaming_agree_on_simulated_session(tmp_path) -> None:
    session = read_session(make_session(tmp_path, action="shove", rate_hz=1000.0))
    _assert_stream_equals_batch(session.t, session.q, session.dq, session.tau, with_hand=True)


@pytest.mark.parametrize("observer", [ObserverConfig(gain=(30.0, 40.0, 50.0, 60.0, 70.0, 80.0,
                                                                  90.0)),
                                      ObserverConfig(friction=False)])
def test_per_sample_residual_equals_the_batch_with_per_joint_gains_or_no_friction(
        real, observer: ObserverConfig) -> None:
    t, q, dq, tau = (real[c][:3000] for c in ("t", "q", "dq", "tau"))
    config = ChainConfig(observer)
    batch = TimeseriesChain(config, RobotSetup(with_hand=False), ["r", "f"]).compute(t, q, dq,
                                                                                   tau)
    online = TimeseriesChain(config, RobotSetup(with_hand=False), ["r", "f"])
    stream = [online.update(t[k], q[k], dq[k], tau[k]) for k in range(len(t))]
    for name in ("r", "f"):
        assert np.abs(np.array([s[name] for s in stream]) - batch[name]).max() <= 1e-9, name


def test_simulated_free_motion_residuals_are_the_size_of_real_ones(real) -> None:
    duration = 6.0
    chain = TimeseriesChain(robot=RobotSetup(with_hand=False))
    keep = real["t"] < duration
    r_real = chain.compute(real["t"][keep], real["q"][keep], real["dq"][keep],
                           real["tau"][keep], ["r"])["r"]
    rms_real = _rms(r_real[real["t"][keep] > 1.0])
    rms_sim = []
    for robot_seed in (0, 1):
        config = SimConfig(rate_hz=1000.0, with_hand=False, robot_seed=robot_seed)
        spec = plan_session(seed=1, condition="static", action="none", pose="A",
                            duration_s=duration, planned_at_s=3.0, robot=config.setup)
        spec = dataclasses.replace(spec, q_start=tuple(real["q"][0]))
        sim = TrackingSimulator(config, real["t"], real["q"], real["dq"])
        chunks = [c for _, c, _ in sim.run([spec])]
        cols = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}

        def joints(prefix, cols=cols):
            return np.column_stack([cols[f"{prefix}_{i}"] for i in range(1, 8)])

        r = chain.compute(cols["t"], joints("q"), joints("dq"), joints("tau"), ["r"])["r"]
        rms_sim.append(_rms(r[cols["t"] > 1.0]))
    ratio = np.mean(rms_sim, axis=0) / rms_real
    assert ((ratio > 1 / 3) & (ratio < 3)).all(), ratio
