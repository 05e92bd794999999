"""The contact detector: streaming = batch, calibration files, and real recordings
(calibrated on other data than it is tested on)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from contactkit.classify.events.metrics import EventScore, score_events
from contactkit.features.detector import (
    BEYOND_RANGE,
    MIN_DYNAMIC_RANGE,
    CalibrationData,
    Detector,
    DetectorConfig,
    calibrate,
    calibration_samples,
    detect,
    drop_outliers,
    load_calibration,
    save_calibration,
)
from contactkit.features.timeseries import TimeseriesChain
from contactkit.recorder.importers.arrays import load_joint_arrays
from contactkit.robots import RobotSetup
from contactkit.schemas import InputError
from tests.conftest import MINDLAB_FILES, load_mindlab


def _synthetic(n: int = 3000, rate: float = 1000.0, seed: int = 0):
    """A noisy held pose with one 0.4 s push of 3 Nm on joint 2 at t = 1.5 s."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    r = rng.normal(0.0, 0.05, (n, 7)) + 0.4
    r[(t > 1.5) & (t < 1.9), 1] += 3.0
    dq = rng.normal(0.0, 0.002, (n, 7))
    return t, r, dq


def test_streaming_equals_batch_and_never_looks_ahead() -> None:
    t, r, dq = _synthetic()
    batch = detect(t, r, dq)
    detector = Detector()
    states = [detector.update(t[k], r[k], dq[k]) for k in range(len(t))]
    # the same decisions; the filters solved vectorised agree to rounding
    assert np.array_equal(batch.contact, [s.contact for s in states])
    assert np.abs(batch.score - [s.score for s in states]).max() < 1e-9
    prefix = detect(t[:1700], r[:1700], dq[:1700])
    assert np.array_equal(prefix.contact, batch.contact[:1700])
    assert np.abs(prefix.e - batch.e[:1700]).max() < 1e-9


def test_one_push_is_one_contact_with_hysteresis() -> None:
    t, r, dq = _synthetic()
    found = detect(t, r, dq)
    assert len(found.intervals) == 1
    onset, release = found.intervals[0]
    assert 1.5 <= t[onset] <= 1.53
    assert 1.9 <= t[release] <= 2.0


def _stream(t: np.ndarray, r: np.ndarray, dq: np.ndarray) -> CalibrationData:
    return calibration_samples(t, r, dq)


def test_calibration_round_trip(tmp_path: Path) -> None:
    t, r, dq = _synthetic()
    quiet = t < 1.4
    config = calibrate([_stream(t[quiet], r[quiet], dq[quiet])], source={"files": ["x"]})
    path = save_calibration(tmp_path / "robot.json", config)
    loaded = load_calibration(path)
    assert loaded == config
    assert loaded.source == config.source
    assert min(loaded.noise) >= 0.3 and max(loaded.noise) < 0.6


@pytest.mark.parametrize("content, problem", [
    ("{not json", "not JSON"),
    ('{"format": "other"}', "not a detector calibration"),
    ('{"format": "contactkit-detector/1", "noise": [1, 2]}', "7 finite"),
    ('{"format": "contactkit-detector/1", "release": 2}', "release"),
    ('{"format": "contactkit-detector/1", "colour": 2}', "unknown detector setting"),
])
def test_bad_calibration_files_are_one_line_errors(tmp_path: Path, content: str,
                                                   problem: str) -> None:
    path = tmp_path / "robot.json"
    path.write_text(content)
    with pytest.raises(InputError) as err:
        load_calibration(path)
    assert problem in str(err.value) and "robot.json" in str(err.value)
    assert "\n" not in str(err.value)


def test_missing_calibration_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such calibration file"):
        load_calibration(tmp_path / "nope.json")


def test_defaults_survive_json() -> None:
    doc = json.loads(json.dumps(DetectorConfig().to_dict()))
    assert DetectorConfig.from_dict(doc) == DetectorConfig()


def test_calibrations_from_before_the_low_pass_keep_their_meaning() -> None:
    doc = DetectorConfig().to_dict()
    for name in ("smooth_s", "baseline_moving_s"):
        del doc[name]
    old = DetectorConfig.from_dict({**doc, "baseline_s": 3.0})
    assert old.smooth_s == 0.0 and old.baseline_moving_s == 3.0


def test_a_one_sample_spike_is_low_passed_away_a_touch_is_not() -> None:
    t, r, dq = _synthetic()
    r[1000, 1] += 1.5  # one sample, 1 ms: a glitch, not a touch
    spiky = DetectorConfig(noise=(0.5,) * 7, min_on_s=0.0, smooth_s=0.0)
    assert t[detect(t, r, dq, spiky).intervals[0][0]] == pytest.approx(1.0)
    found = detect(t, r, dq, replace(spiky, smooth_s=0.03))
    assert len(found.intervals) == 1 and 1.5 <= t[found.intervals[0][0]] <= 1.53


def _slow_move(n: int = 9000, rate: float = 1000.0) -> tuple[np.ndarray, ...]:
    """A 6 s move at 1 rad/s along which the model error on joint 2 drifts by 1.5 Nm
    (gravity's error changes with the pose), with a 1 Nm push at t = 6 s."""
    rng = np.random.default_rng(1)
    t = np.arange(n) / rate
    dq = np.zeros((n, 7))
    dq[(t > 1.0) & (t < 7.0), 1] = 1.0
    r = rng.normal(0.0, 0.03, (n, 7))
    r[:, 1] += 1.5 * np.clip((t - 1.0) / 6.0, 0.0, 1.0)
    r[(t > 6.0) & (t < 6.4), 1] += 1.0
    return t, r, dq


def test_the_baseline_follows_model_error_that_changes_along_a_move() -> None:
    t, r, dq = _slow_move()
    config = DetectorConfig(noise=(0.3,) * 7, speed=(0.1,) * 7, accel=(0.0,) * 7)
    found = detect(t, r, dq, config)
    assert len(found.intervals) == 1
    onset, release = found.intervals[0]
    assert 6.0 <= t[onset] <= 6.1
    assert release is not None and 6.4 <= t[release] <= 6.6
    lagging = detect(t, r, dq, replace(config, baseline_moving_s=2.0))
    assert t[lagging.intervals[0][0]] < 6.0  # a 2 s baseline lags: a false contact


def _push_leaving_an_offset() -> tuple[np.ndarray, ...]:
    """A held pose, a 0.4 s push of 3 Nm on joint 2 at t = 1.5 s that jolts the arm,
    after which joint 2's residual keeps 0.3 Nm (what the frozen baseline took before
    the push no longer matches: on a moving arm the model error drifted meanwhile)."""
    t, r, dq = _synthetic(4000)
    push = (t > 1.5) & (t < 1.9)
    dq[push, 1] += 0.3 * np.sin(np.pi * (t[push] - 1.5) / 0.4)
    r[t >= 1.9, 1] += 0.3
    return t, r, dq


def test_the_baseline_reacquires_quickly_after_a_release() -> None:
    t, r, dq = _push_leaving_an_offset()
    config = DetectorConfig(noise=(0.3,) * 7, speed=(0.5,) * 7, accel=(0.3,) * 7)
    quick, slow = detect(t, r, dq, config), detect(t, r, dq, replace(config, reacquire_s=0.0))
    assert quick.intervals == slow.intervals and len(quick.intervals) == 1
    release = quick.intervals[0][1]
    assert release is not None
    later = np.searchsorted(t, t[release] + 0.3)
    # the stale 0.3 Nm is gone within 0.3 s (time constant 0.1 s) instead of lingering
    # near the threshold while the contact's own motion no longer raises it
    assert abs(quick.e[later, 1]) < 0.05 < 0.1 < abs(slow.e[later, 1])
    detector = Detector(config)
    states = [detector.update(t[k], r[k], dq[k]) for k in range(len(t))]
    assert np.array_equal(quick.contact, [s.contact for s in states])
    assert np.abs(quick.score - [s.score for s in states]).max() < 1e-9


def _push_ending_after_its_release():
    """A push of 3 Nm on joint 1 (1.5-2.0 s) that also loads joint 4 by 1.2 Nm, which
    stays on 1 s longer: the release, decided on joint 1, takes joint 4's 1.2 Nm into
    its baseline, and joint 4's drop at 3.0 s turns its deviation against the push."""
    t, r, dq = _synthetic(8000)
    r[(t > 1.5) & (t < 2.0), 0] += 3.0
    r[(t > 1.5) & (t < 3.0), 3] += 1.2
    return t, r, dq


def test_a_contact_s_own_end_after_its_release_starts_no_contact() -> None:
    t, r, dq = _push_ending_after_its_release()
    config = DetectorConfig()
    found, before = detect(t, r, dq, config), detect(t, r, dq, replace(config, reversal_s=0.0))
    assert [t[on] for on, _ in found.intervals] == pytest.approx([1.52], abs=0.01)
    assert len(before.intervals) == 2 and t[before.intervals[1][0]] > 3.0
    # the turned joint does not count in the score; its baseline takes the drop in
    late = np.searchsorted(t, 3.1)
    assert found.score[late] < 1.0 < abs(found.e[late, 3]) / found.threshold[late, 3]
    assert abs(found.e[-1, 3]) < 0.3
    # a push the other way, larger than REVERSAL_SPAN times the contact's, is a contact
    other = r.copy()
    other[(t > 3.5) & (t < 3.9), 3] -= 3.0
    assert [t[on] for on, _ in detect(t, other, dq, config).intervals] == pytest.approx(
        [1.52, 3.52], abs=0.01)
    # and so is a push the same way
    r[(t > 3.5) & (t < 3.9), 0] += 3.0
    again = detect(t, r, dq, config)
    assert [t[on] for on, _ in again.intervals] == pytest.approx([1.52, 3.52], abs=0.01)
    detector = Detector(config)
    states = [detector.update(t[k], r[k], dq[k]) for k in range(len(t))]
    assert np.array_equal(again.contact, [s.contact for s in states])
    assert np.abs(again.score - [s.score for s in states]).max() < 1e-9
    # calibrations written before the rule keep their meaning
    old = {k: v for k, v in config.to_dict().items() if k != "reversal_s"}
    assert DetectorConfig.from_dict(old).reversal_s == 0.0


def test_a_heavily_loaded_joint_holds_the_contact_it_did_not_start() -> None:
    """A slow push crosses the threshold first on joint 2, barely, then loads joint 1
    ten times over while joint 2 falls back: one contact, held until joint 1 lets go
    (released on joint 2 alone, the push's end came 2 s later as a second contact)."""
    rng = np.random.default_rng(3)
    t = np.arange(5000) / 1000.0
    r = rng.normal(0.0, 0.02, (len(t), 7))
    r[:, 1] += 0.6 * np.clip((t - 1.5) / 0.1, 0, 1) * np.clip((2.0 - t) / 0.1, 0, 1)
    r[:, 0] -= 3.0 * np.clip((t - 1.6) / 0.3, 0, 1) * np.clip((3.5 - t) / 0.1, 0, 1)
    dq = np.zeros((len(t), 7))
    config = DetectorConfig(noise=(0.3,) * 7)
    found = detect(t, r, dq, config)
    assert len(found.intervals) == 1
    onset, release = found.intervals[0]
    assert 1.5 < t[onset] < 1.6 and 3.4 < t[release] < 3.6
    detector = Detector(config)
    states = [detector.update(t[k], r[k], dq[k]) for k in range(len(t))]
    assert np.array_equal(found.contact, [s.contact for s in states])


def test_calibrations_from_before_reacquisition_keep_their_meaning() -> None:
    doc = DetectorConfig().to_dict()
    del doc["reacquire_s"], doc["baseline_reacquire_s"]
    assert DetectorConfig.from_dict(doc).reacquire_s == 0.0
    with pytest.raises(ValueError, match="baseline_reacquire_s"):
        DetectorConfig(baseline_reacquire_s=0.0)


def test_motion_margin_widens_only_the_growth_with_motion() -> None:
    t, r, dq = _slow_move()
    quiet = t < 5.9
    part = calibration_samples(t[quiet], r[quiet], dq[quiet],
                               DetectorConfig(baseline_moving_s=2.0))
    narrow, wide = calibrate([part]), calibrate([part], motion_margin=3.0)
    assert wide.noise == narrow.noise
    assert max(narrow.speed) > 0
    np.testing.assert_allclose(np.array(wide.speed), 2.0 * np.array(narrow.speed))
    assert wide.source["motion_margin"] == 3.0 and narrow.source["motion_margin"] == 1.5


def test_calibration_skips_the_warm_up_after_every_gap() -> None:
    """The detector restarts after a gap (observer at r = 0, baseline set again): those
    samples are its own settling, not model error, so calibration leaves them out as it
    leaves out the stream's start."""
    t, r, dq = _synthetic()
    quiet = (t < 1.2) | (t > 2.2)  # a gap of 1 s where the push was
    template = DetectorConfig()
    part = calibration_samples(t[quiet], r[quiet], dq[quiet], template)
    assert part.t is not None and len(part.t) == len(part.abs_e)
    after_gap = part.t[part.t > 2.2]
    assert after_gap[0] >= 2.2 + template.warmup_s - 1e-9
    assert part.t[0] >= template.warmup_s - 1e-9
    whole = calibration_samples(t, r, dq, template)
    assert len(whole.t) - len(part.t) > (t[~quiet].size + template.warmup_s * 1000) * 0.99


def _part_with_spike(seed: int, spike_at: float | None) -> CalibrationData:
    rng = np.random.default_rng(seed)
    t = np.arange(2000) / 500.0
    abs_e = np.abs(rng.normal(0.0, 0.1, (len(t), 7)))
    if spike_at is not None:
        abs_e[np.abs(t - spike_at) < 0.05, 1] = 2.0  # a missed touch on joint 2
    speed = np.where(t < 1.0, 0.0, 0.5)  # held, then moving
    return CalibrationData(abs_e, speed, speed.copy(), np.ones((len(t), 7)), t)


def test_outliers_are_dropped_with_their_surroundings() -> None:
    """A sample far above what every stream shows is dropped with 0.5 s on each side;
    streams without one keep every sample, and the thresholds then follow them."""
    parts = [_part_with_spike(k, 2.0 if k == 3 else None) for k in range(6)]
    kept, share = drop_outliers(parts)
    assert [len(p.t) for p in kept[:3]] == [2000] * 3
    dropped = kept[3].t
    assert not ((dropped > 1.45) & (dropped < 2.55)).any()
    assert ((dropped > 1.3) & (dropped < 1.4)).any() and ((dropped > 2.6) & (dropped < 2.7)).any()
    assert share == pytest.approx((2000 - len(dropped)) / 12000)

    def threshold(config: DetectorConfig) -> float:  # joint 2's, at these samples
        return config.noise[1] + 0.5 * (config.speed[1] + config.accel[1]) + config.dynamic[1]

    assert threshold(calibrate(kept)) < 1.0 < 2.0 < threshold(calibrate(parts))
    with pytest.raises(ValueError, match="time stamps"):
        drop_outliers([replace(parts[0], t=None)])
    assert drop_outliers([]) == ([], 0.0)


# --- real recordings ---------------------------------------------------------------

@pytest.fixture(scope="module")
def gaz(reference_dir: Path) -> dict[str, np.ndarray]:
    data = load_joint_arrays(*(reference_dir / f for f in ("time.txt", "positions.txt",
                                                           "velocity.txt", "torques.txt")))
    chain = TimeseriesChain(robot=RobotSetup(with_hand=False))
    data["r"] = chain.compute(data["t"], data["q"], data["dq"], data["tau"], ["r"])["r"]
    return data


@pytest.fixture(scope="module")
def mindlab(mindlab_dir: Path) -> dict[str, dict[str, np.ndarray]]:
    chain = TimeseriesChain()
    out = {}
    for name in MINDLAB_FILES:
        data = load_mindlab(mindlab_dir / f"{name}.csv")
        data["r"] = chain.compute(data["t"], data["q"], data["dq"], data["tau"], ["r"])["r"]
        out[name] = data
    return out


def _part(data: dict[str, np.ndarray], keep: np.ndarray) -> dict[str, np.ndarray]:
    return {name: values[keep] for name, values in data.items()}


def _quiet_stretches(data: dict[str, np.ndarray], margin_s: float = 0.4) -> list[CalibrationData]:
    """No-contact stretches of a labelled recording, ``margin_s`` away from any touch."""
    t, touched = data["t"], data["contact"]
    near = np.zeros(len(t), bool)
    for k in np.flatnonzero(touched):
        near |= np.abs(t - t[k]) <= margin_s
    idx = np.flatnonzero(~near)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    template = DetectorConfig(warmup_s=0.1)
    return [calibration_samples(t[run], data["r"][run], data["dq"][run], template)
            for run in runs if len(run) > 50]


def test_residual_follows_the_robots_own_estimate(mindlab) -> None:
    r = np.concatenate([d["r"][d["t"] > 0.2] for d in mindlab.values()])
    ext = np.concatenate([-d["tau_ext"][d["t"] > 0.2] for d in mindlab.values()])
    corr = [np.corrcoef(r[:, j], ext[:, j])[0, 1] for j in range(4)]
    assert min(corr) >= 0.95, corr


def _events(data: dict[str, np.ndarray], config: DetectorConfig) -> list[tuple[float, float]]:
    found = detect(data["t"], data["r"], data["dq"], config)
    t = data["t"]
    return [(float(t[on]), float(t[-1] if off is None else t[off])) for on, off in found.intervals]


def test_calibrated_on_other_data_real_robot(gaz, mindlab) -> None:
    """Calibrate on the first half of the free-motion log and four MindLab files; test
    on the second half of the log and the fifth file, for each fifth file."""
    first = gaz["t"] < gaz["t"][-1] / 2
    head = _part(gaz, first)
    motion = calibration_samples(head["t"], head["r"], head["dq"])
    second = _part(gaz, ~first)
    total = EventScore()
    for held_out in MINDLAB_FILES:
        parts = [motion] + [p for name in MINDLAB_FILES if name != held_out
                            for p in _quiet_stretches(mindlab[name])]
        config = calibrate(parts)
        assert _events(second, config) == [], held_out
        data = mindlab[held_out]
        total = total + score_events(data["t"], data["contact"], _events(data, config))
    assert total.detected == total.touches
    assert total.false_per_min <= 1.0
    assert total.delay_ms(50) <= 60.0


def _swing(amplitude: float, n: int = 7000, rate: float = 1000.0) -> tuple[np.ndarray, ...]:
    """A held pose for 1 s, then joint 2 swinging as amplitude sin(2 pi t) [rad/s]; its
    dynamic torque scale d is 2 Nm per rad/s^2 of its acceleration, and the model error
    0.05 Nm per rad/s^2 (a mass the model gets slightly wrong). Returns t, r, dq and d."""
    rng = np.random.default_rng(4)
    t = np.arange(n) / rate
    moving = t >= 1.0
    dq = np.zeros((n, 7))
    dq[moving, 1] = amplitude * np.sin(2 * np.pi * t[moving])
    ddq = np.zeros((n, 7))
    ddq[moving, 1] = amplitude * 2 * np.pi * np.cos(2 * np.pi * t[moving])
    dyn = 2.0 * np.abs(ddq)
    r = rng.normal(0.0, 0.01, (n, 7)) + 0.05 * ddq
    return t, r, dq, dyn


def test_beyond_the_calibrated_dynamics_the_thresholds_grow() -> None:
    """Calibrated on a gentle swing (the error stays under the at-rest floor, so nothing
    grows with motion), the detector meets the same swing eight times faster, where the
    error, linear in the acceleration, is eight times larger. Without the range that is
    a contact; with it, the threshold grows with d beyond the largest d calibrated on."""
    t, r, dq, dyn = _swing(0.4)
    gentle = calibration_samples(t, r, dq, dyn=dyn)
    bounded, unbounded = calibrate([gentle]), calibrate([gentle], bound_dynamic=False)
    assert max(bounded.dynamic) == 0.0 and max(bounded.accel) == 0.0  # flat thresholds
    assert bounded.reads_dynamic and not unbounded.reads_dynamic
    assert unbounded.dynamic_range is None and bounded.dynamic_range is not None
    assert 4.5 < bounded.dynamic_range[1] <= 2.0 * 0.4 * 2 * np.pi  # the held d's peak
    assert bounded.dynamic_range[0] == MIN_DYNAMIC_RANGE  # joint 1 never moved
    t, r, dq, dyn = _swing(3.2)
    assert len(detect(t, r, dq, unbounded).intervals) >= 1
    found = detect(t, r, dq, bounded, dyn)
    assert found.intervals == []
    grown = BEYOND_RANGE * (found.dynamic[:, 1] - bounded.dynamic_range[1])
    np.testing.assert_allclose(found.threshold[:, 1], bounded.noise[1] + np.maximum(grown, 0))
    detector = Detector(bounded)
    states = [detector.update(t[k], r[k], dq[k], dyn[k]) for k in range(len(t))]
    assert np.abs(found.score - [s.score for s in states]).max() < 1e-9
    assert np.abs(found.threshold[-1] - states[-1].threshold).max() < 1e-9
    assert DetectorConfig.from_dict(json.loads(json.dumps(bounded.to_dict()))) == bounded
    with pytest.raises(ValueError, match="dynamic_range"):
        DetectorConfig(dynamic_range=(1.0,) * 6)
    with pytest.raises(ValueError, match="dynamic"):
        detect(t, r, dq, bounded)  # it reads d: leaving it out is refused
