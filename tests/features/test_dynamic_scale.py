"""The detector's dynamic torque term: the chain's ``tau_dyn`` (batch = streaming, a gap
restarts it), the per-joint ``dynamic`` coefficients (old files mean 0), the detector
with the term (batch = streaming) and its calibration."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from contactkit.features.detector import (
    DYNAMIC_FEATURE,
    Detector,
    DetectorConfig,
    calibrate,
    calibration_samples,
    detect,
)
from contactkit.features.observer import DDQ_FILTER_GAIN
from contactkit.features.timeseries import (
    GRAVITY_LAG_S,
    TimeseriesChain,
    columns_of,
)
from contactkit.robots.builtin import FR3
from contactkit.schemas.session import SampleBatch


def _motion(n: int = 800, gap_at: int | None = 500, seed: int = 0):
    """A smooth multi-sine move at 1 kHz (t [s], q [rad], dq [rad/s], tau [Nm]), with a
    0.5 s gap before sample ``gap_at``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    if gap_at is not None:
        t[gap_at:] += 0.5
    phase, freq = rng.uniform(0, 6, 7), rng.uniform(0.2, 0.6, 7)
    q = 0.3 * np.sin(2 * np.pi * freq * t[:, None] + phase)
    dq = 0.3 * 2 * np.pi * freq * np.cos(2 * np.pi * freq * t[:, None] + phase)
    return t, q, dq, rng.normal(0.0, 1.0, (n, 7))


def test_tau_dyn_is_its_definition_and_streams_as_it_computes() -> None:
    t, q, dq, tau = _motion()
    chain = TimeseriesChain(names=["r", DYNAMIC_FEATURE])
    whole = chain.compute(t, q, dq, tau)[DYNAMIC_FEATURE]
    assert columns_of(DYNAMIC_FEATURE) == [f"tau_dyn_{j}" for j in range(1, 8)]
    streamed = np.array([chain.update(t[k], q[k], dq[k], tau[k])[DYNAMIC_FEATURE]
                         for k in range(len(t))])
    assert np.abs(streamed - whole).max() <= 1e-9
    chain.reset()
    batch = SampleBatch(t, q, dq, tau)
    chunked = np.vstack([chain.feed(batch.take(slice(i, i + 37)))[DYNAMIC_FEATURE]
                         for i in range(0, len(t), 37)])
    assert np.abs(chunked - whole).max() <= 1e-9
    # by hand: ddq low-passed from 0 at the first sample, and restarted after the gap
    model = chain.model.model
    data = model.createData()
    ddq_f = np.zeros(7)
    for k in range(len(t)):
        if k in (0, 500):
            ddq_f = np.zeros(7)
        else:
            h = t[k] - t[k - 1]
            ddq_f = (ddq_f + DDQ_FILTER_GAIN * (dq[k] - dq[k - 1])) / (1 + DDQ_FILTER_GAIN * h)
        if k in (0, 1, 499, 500, 501, len(t) - 1):
            inertial = pin.rnea(model, data, q[k], dq[k], ddq_f) \
                - pin.computeGeneralizedGravity(model, data, q[k])
            rate = pin.computeGeneralizedGravityDerivatives(model, data, q[k]) @ dq[k]
            expected = np.abs(inertial) + GRAVITY_LAG_S * np.abs(rate)
            assert np.allclose(whole[k], expected, rtol=1e-9, atol=1e-9), k


def test_a_gap_restarts_tau_dyn_as_a_new_stream() -> None:
    t, q, dq, tau = _motion()
    chain = TimeseriesChain(names=[DYNAMIC_FEATURE])
    whole = chain.compute(t, q, dq, tau)[DYNAMIC_FEATURE]
    after = chain.compute(t[500:], q[500:], dq[500:], tau[500:])[DYNAMIC_FEATURE]
    assert np.abs(whole[500:] - after).max() <= 1e-12


def test_calibrations_written_before_the_dynamic_term_mean_none() -> None:
    doc = DetectorConfig().to_dict()
    assert list(doc["dynamic"]) == [0.0] * 7
    del doc["dynamic"]
    old = DetectorConfig.from_dict(doc)
    assert old.dynamic == (0.0,) * 7 and old.chain_features == ["r"]
    with pytest.raises(ValueError, match="dynamic"):
        DetectorConfig(dynamic=(-1.0,) * 7)
    assert DetectorConfig(dynamic=(0.1,) * 7).chain_features == ["r", DYNAMIC_FEATURE]
    # on another arm the term grows as the speed and acceleration terms do
    fr3 = DetectorConfig(dynamic=(0.1,) * 7, robot="panda").for_robot(FR3)
    assert fr3.dynamic == pytest.approx((0.1 * FR3.detector_motion_scale,) * 7)


def _residual(seed: int = 1):
    """A move whose residual error is 5 % of the dynamic torque scale, plus noise, with
    (in the test) a push after the gap."""
    t, q, dq, tau = _motion(3000, 1500, seed)
    dyn = TimeseriesChain(names=[DYNAMIC_FEATURE]).compute(t, q, dq, tau)[DYNAMIC_FEATURE]
    rng = np.random.default_rng(seed)
    r = 0.05 * dyn * np.sin(3 * t)[:, None] + rng.normal(0.0, 0.02, dyn.shape)
    return t, r, dq, dyn


def test_the_detector_with_the_term_streams_as_it_runs() -> None:
    t, r, dq, dyn = _residual()
    r[2000:2100, 0] += 3.0
    config = DetectorConfig(speed=(0.0,) * 7, accel=(0.0,) * 7, dynamic=(0.1,) * 7)
    batch = detect(t, r, dq, config, dyn)
    detector = Detector(config)
    states = [detector.update(t[k], r[k], dq[k], dyn[k]) for k in range(len(t))]
    assert np.array_equal(batch.contact, [s.contact for s in states])
    assert np.abs(batch.score - [s.score for s in states]).max() < 1e-9
    assert np.abs(batch.threshold - [s.threshold for s in states]).max() < 1e-9
    assert batch.dynamic is not None and (batch.dynamic >= dyn - 1e-12).all()  # held
    assert len(batch.intervals) == 1 and 2.5 <= t[batch.intervals[0][0]] <= 2.53
    # settings with the term refuse a stream without its input (a caller that forgot it
    # would get thresholds too low in motion), batch and live alike
    with pytest.raises(ValueError, match="read the chain's 'tau_dyn'"):
        detect(t, r, dq, config)
    with pytest.raises(ValueError, match="read the chain's 'tau_dyn'"):
        Detector(config).update(t[0], r[0], dq[0])
    plain = replace(config, dynamic=(0.0,) * 7)
    assert detect(t, r, dq, plain).intervals  # without the term, no input is needed




def test_calibration_fits_the_term_where_the_error_follows_it() -> None:
    parts, plain = [], []
    for seed in (1, 2, 3):
        t, r, dq, dyn = _residual(seed)
        parts.append(calibration_samples(t, r, dq, dyn=dyn))
        plain.append(calibration_samples(t, r, dq))
    assert plain[0].dynamic is None and parts[0].dynamic.shape == (len(parts[0].speed), 7)
    template = DetectorConfig(noise=(0.1,) * 7)  # no rest in the data: its noise is kept
    fitted = calibrate(parts, template, margin=1.0, floor=0.1)
    assert fitted.dynamic[1] > 0.02  # joint 2, where gravity's rate is largest
    assert max(calibrate(plain, template, margin=1.0, floor=0.1).dynamic) == 0.0
    t, r, dq, dyn = _residual(1)  # the envelope covers its samples: no contact
    assert detect(t, r, dq, fitted, dyn).intervals == []


def test_the_default_recipe_calibrates_the_term_on_several_instances(tmp_path) -> None:
    from contactkit.cli.default_model import RECIPE, _instances, recipe_dir

    detector = RECIPE["detector"]
    assert detector["dynamic"] and len(detector["instances"]["robot_seeds"]) >= 2
    # the key follows the detector's recipe
    plain = {**RECIPE, "detector": {k: v for k, v in detector.items()
                                    if k not in ("dynamic", "instances")}}
    assert recipe_dir(None, plain) != recipe_dir()
    spec = {"preset": "free-motion", "robot_seeds": [3], "sessions": 1}
    (path,) = _instances(spec, 1, None, tmp_path, 0, None)
    assert path.parent.name == "free-motion-robot3"
    assert _instances(None, 1, None, tmp_path, 0, None) == []
