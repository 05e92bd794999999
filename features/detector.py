"""Contact detector on the observer residual: per-joint thresholds that grow with
motion, a slowly tracked baseline, and hysteresis.

The residual r of a real robot is not zero without contact: it carries a static
offset from model error (a hand the model gets slightly wrong: ~0.5 Nm per joint)
and an error that grows with speed and acceleration (up to 5.5 Nm on joint 2 in
fast free motion), while a touch adds 1-15 Nm on joints 1-4 and the held-pose
noise is ~0.05-0.2 Nm. The detector therefore works on

    e_j = rf_j - b_j                   (deviation from a baseline b, Nm)
    th_j = noise_j + speed_j s + accel_j a + dynamic_j d_j     (threshold, Nm)
    score = max_j |e_j| / th_j          (over the joints that count, see below)

where rf is r low-passed (first order, time constant ``smooth_s``: on the default
model's simulated calibration data a 30 ms low-pass halves the largest deviation at
rest, 0.63 to 0.30 Nm on joint 1, while a touch lasts at least tens of
milliseconds); b is an exponential average of
rf, updated while no contact is reported or pending (frozen from the first sample
above threshold until the release) with time constant ``baseline_s`` at rest and
``baseline_moving_s`` while the arm moves (s at least ``REST_SPEED``): the model
error, gravity's in particular, changes with the pose, and a baseline that lags a
slow 1.5 rad/s move by 2 s piles up more than 1 Nm on joint 2 of the simulated
Panda. s = |dq| (2-norm, rad/s) and a = |ddq| (2-norm of the joint acceleration
low-passed with the observer's own 20 ms time constant, rad/s^2) are both held as
a decaying peak (``motion_hold_s``) because model error reaches r through
the observer's lag. d_j [Nm] is joint j's own dynamic torque scale, the chain's
``tau_dyn`` (:mod:`contactkit.features.timeseries`): |M(q) ddq_f + C(q, dq) dq|_j +
0.5 s |dg(q)/dt|_j, held the same way; 0 when not given. A robot instance's masses
and inertias are off by up to +-15 %, so its model error in motion is about that
fraction of the model's own dynamic torque on each joint, and of gravity's change
while the baseline lags it: s and a, norms over all joints, put a threshold too high
where a joint carries little inertial torque and too low where it carries much.
Measured with the default model (its recipe calibrates on free motion of robot
instances 0-8, motion margin 2.5), on instances it never saw (``recorder simulate
--preset free-motion --sessions 16 --seed 5``, instances 22, 30, 31, 32, 40, 41;
``mixed-motion`` likewise on 22 and 31): 0 false events, where the detector calibrated
on instance 0 alone without d gave 11 (6 on free motion of instance 22, in 5 of its 16
sessions; with d still 5 there: one instance does not show the spread); calibrated on
instances 0-8 without d (margin 3) it gave 0 but found only 6 of the 16 mixed-motion
contacts (12 before, 12 with d): s and a must then cover the worst joint of the worst
instance. On ``thesis-static`` and ``thesis-dynamic`` (48 sessions each; seed 61 on
instance 27, seed 62 on instance 22) it finds the same contacts on links 3-7 (all but
3 of 25 on instance 27's dynamic preset, as before) and one contact fewer on links 1-2
(instance 22, dynamic), with no false event; the real free-motion log's peak score is
0.74 (0.70 before).
Contact starts when the score stays above 1 for ``min_on_s``
and ends when the joints that started it stay below ``release`` for ``min_off_s``
(hysteresis) while no joint's score is above :data:`HOLD_LOAD`; the other joints then
take their current residual as baseline. That
rule exists because a touch can leave a lasting offset on a joint it barely loads:
on the real Panda a wrist joint's static friction keeps up to 0.5 Nm after a push
on the upper arm, which would otherwise hold the contact on forever. The joints that
started it keep the baseline frozen at the onset, and for ``reacquire_s`` after the
release every joint's baseline follows r_f with the short time constant
``baseline_reacquire_s``: on a moving arm the model error drifts while the baseline is
frozen, and the stale part left at the release, with the threshold shrinking as the
contact's own jolt leaves the motion measures, gave a second, false contact right
after a contact (simulated thesis-dynamic sessions, robot instances 22 and 25). For
``reversal_s`` after a release, a joint the contact loaded (a score above
:data:`REVERSAL_LOAD` in it) whose deviation has the opposite sign of its deviation at
its largest score there, and is at most :data:`REVERSAL_SPAN` times as large, does not
count toward a new onset (and not in the score), while its baseline takes the deviation
in: a push keeps its direction, and a deviation turned against it is the contact's own
end measured against a baseline that took part of it in (a release decided on the onset
joints while the push still loads others, which then take the residual as baseline) or
that went stale while the arm moved. Without the rule such ends gave contacts that never
released once the arm stopped (2 false events in 384 simulated ``thesis-dynamic``
sessions on robot instances 51, 53, 55 and 57; none with it, and no contact lost). The
cost: a push the other way on the same joints, within ``reversal_s`` of a release and
no stronger than the contact was, is seen only on the joints it loads the same way
(synthetic touches 2.5 s apart on the real Gaz free-motion log: a shove that reversed a
push released 0.85 s before was missed, 1 of 40 touches). :data:`HOLD_LOAD` keeps a
contact on while another joint carries it: a slow adjust on link 4 crossed the threshold
on joint 2 (score 1.1), then loaded joint 1 nine times over; released on joint 2 alone,
its end 2 s later was a second, false contact (simulated ``thesis-dynamic``, robot
instance 34, with the arm identified from the dataset, whose thresholds are low); with the
rule, one contact, and no figure of the results pages moved (the ten thesis datasets with
the default model rebuilt, the real Panda and FR3 recordings, isolation). Onset
and release are stamped with the sample at which the detector *decides*, so they are
what an online consumer sees. The first ``warmup_s`` of a stream only sets the
baseline (the observer starts at r = 0).

After a gap, a step longer than :data:`contactkit.features.timing.RESTART_STEP_S`
(0.1 s), the detector restarts as at the start of a stream (the chain's observer
restarts there too, at r = 0): baseline, filters and motion measures are forgotten and
the warm-up runs again. A contact still on before the gap ends at the last sample
before it (``cut``: known only at the sample after the gap), so no contact spans a gap.

The coefficients noise/speed/accel (and dynamic, when the calibration data carry d)
are calibrated per robot from no-contact data (:func:`calibrate`): per joint, the
smallest linear envelope over (1, s, a, d_j) that covers every calibration sample,
times a margin. Beyond each joint's largest held d in the calibration data
(``dynamic_range``) its threshold grows by :data:`BEYOND_RANGE` (0.15) Nm per Nm of the
excess (:func:`beyond_range`): what no calibration sample showed, nothing covered, and a
detector calibrated on gentle motion took a shove's rebound for a contact.
:class:`Detector` is the
streaming form: :meth:`Detector.update` takes one sample (a live robot),
:meth:`Detector.run` a chunk at once, vectorised (a replay, :func:`detect` on whole
arrays), with the same onsets, releases and contact flags as sample by sample and the
same values to about 1e-12 (the filters' recurrences are solved in closed form).
"""

from __future__ import annotations

import itertools
import json
import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import overload

import numpy as np

from contactkit.errors import InputError
from contactkit.features.observer import (
    DDQ_FILTER_GAIN,
    filtered_rate,
    reduce_rows,
    solve_recurrence,
)
from contactkit.features.timing import RESTART_STEP_S, restarts
from contactkit.robots import RobotSpec
from contactkit.robots.dynamics import ArmDynamics
from contactkit.robots.spec import N_JOINTS
from contactkit.util.atomic import write_text
from contactkit.util.safe_open import read_json

FORMAT = "contactkit-detector/1"
MIN_NOISE = 0.3  # Nm, floor of a calibrated at-rest threshold
REST_SPEED = 0.05  # rad/s, below this a sample counts as at rest
REVERSAL_LOAD = 0.5
"""The score a joint must have reached in a contact for its deviation's turn against the
contact's, after the release, not to start one (``DetectorConfig.reversal_s``)."""
REVERSAL_SPAN = 1.5
"""How much larger than the contact's own deviation on a joint (at its largest score) a
turned deviation may be and still count as the contact's end (the rest is a new push)."""
BEYOND_RANGE = 0.15
"""How much a joint's threshold grows [Nm] per Nm of its dynamic torque scale beyond the
calibration data's largest (``DetectorConfig.dynamic_range``): the spread of a robot
instance's masses and inertias about the nominal model's (+-15 %), what a model no data
checked there may be wrong by."""
MIN_DYNAMIC_RANGE = 0.1
"""The smallest ``dynamic_range`` a calibration records [Nm]: a joint the data barely moved
(d below this) grows from here, not from its noise."""
HOLD_LOAD = 3.0
"""A joint whose score is above this keeps a contact on, whether it started the contact or
not: a slow push that crossed the threshold first on a joint it barely loads, then
loads another one heavily, is not released while that one holds it."""
CALIBRATION_POINTS = 20000  # samples per fit (evenly thinned)
DYNAMIC_FEATURE = "tau_dyn"
"""The chain feature of the dynamic torque scale d (:mod:`contactkit.features.timeseries`)."""


def _zeros() -> np.ndarray:
    """Return seven zeros (e during the warm-up) [Nm]."""
    return np.zeros(N_JOINTS)


def _seven(value: object, name: str) -> tuple[float, ...]:
    values = np.asarray(value, dtype=float).ravel()
    if values.shape != (N_JOINTS,) or not np.isfinite(values).all() or (values < 0).any():
        raise ValueError(f"{name} must be 7 finite non-negative numbers")
    return tuple(float(v) for v in values)


@dataclass(frozen=True)
class DetectorConfig:
    """Detector settings. Per joint (7 values each): ``noise`` [Nm] at rest,
    ``speed`` [Nm per rad/s of |dq|], ``accel`` [Nm per rad/s^2 of |ddq|]. Timing
    in seconds; ``dynamic`` [Nm per Nm] per joint of its own dynamic torque scale
    d_j (the chain's ``tau_dyn``, see the module docstring; 0: not used);
    ``release`` is the score below which a contact ends (< 1);
    ``reacquire_s`` how long after a release the baseline follows with the time
    constant ``baseline_reacquire_s`` (0: not at all); for ``reversal_s`` after a
    release, a joint whose deviation has turned against the contact's does not start a
    contact (see the module docstring; 0: it does).
    ``dynamic_range`` [Nm] (7 values) is each joint's largest held dynamic torque
    scale d_j in the data the settings were calibrated on: beyond it the joint's
    threshold grows by :data:`BEYOND_RANGE` Nm per Nm of d_j over it (None: no bound; see
    :func:`beyond_range`).
    ``robot`` is the registry name of the arm the settings were calibrated on (None:
    not recorded); :meth:`for_robot` adapts them to another arm."""

    noise: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 0.5, 0.5, 0.5)
    speed: tuple[float, ...] = (2.0,) * N_JOINTS
    accel: tuple[float, ...] = (0.2,) * N_JOINTS
    dynamic: tuple[float, ...] = (0.0,) * N_JOINTS
    release: float = 0.7
    min_on_s: float = 0.01
    min_off_s: float = 0.05
    baseline_s: float = 2.0
    baseline_moving_s: float = 0.5
    reacquire_s: float = 0.5
    baseline_reacquire_s: float = 0.1
    reversal_s: float = 2.0
    motion_hold_s: float = 0.5
    warmup_s: float = 0.3
    smooth_s: float = 0.03
    dynamic_range: tuple[float, ...] | None = None
    robot: str | None = None
    source: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        for name in ("noise", "speed", "accel", "dynamic"):
            object.__setattr__(self, name, _seven(getattr(self, name), name))
        if min(self.noise) <= 0:
            raise ValueError("noise thresholds must be positive")
        if self.dynamic_range is not None:
            object.__setattr__(self, "dynamic_range",
                               _seven(self.dynamic_range, "dynamic_range"))
        if not 0 < self.release < 1:
            raise ValueError(f"release must lie in (0, 1), got {self.release}")
        for name in ("min_on_s", "min_off_s", "motion_hold_s", "warmup_s", "smooth_s",
                     "reacquire_s", "reversal_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative number of seconds")
        for name in ("baseline_s", "baseline_moving_s", "baseline_reacquire_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number of seconds")

    @property
    def chain_features(self) -> list[str]:
        """Return the chain features the detector reads: ``r``, and ``tau_dyn`` when a
        ``dynamic`` coefficient is positive or ``dynamic_range`` is set (else its terms
        are 0 without it)."""
        return ["r", DYNAMIC_FEATURE] if self.reads_dynamic else ["r"]

    @property
    def reads_dynamic(self) -> bool:
        """Return whether the thresholds grow with the dynamic torque scale (a positive
        ``dynamic`` coefficient, or a ``dynamic_range`` to grow beyond)."""
        return max(self.dynamic) > 0 or self.dynamic_range is not None

    def to_dict(self) -> dict:
        """Return the settings as a JSON-ready document (with its format tag)."""
        return {"format": FORMAT, **asdict(self)}

    def scaled(self, factor: float) -> DetectorConfig:
        """Return these settings with every threshold coefficient (``noise``, ``speed``,
        ``accel``, ``dynamic``) times ``factor`` (> 0): thresholds ``factor`` times as
        high [Nm], apart from the growth beyond ``dynamic_range``, which stays."""
        if not (math.isfinite(factor) and factor > 0):
            raise ValueError(f"a threshold scale must be a positive number, got {factor}")
        return replace(self._growth_times(factor),
                       noise=tuple(factor * v for v in self.noise))

    def _growth_times(self, factor: float) -> DetectorConfig:
        """Return these settings with the threshold's growth coefficients (``speed``,
        ``accel``, ``dynamic``) times ``factor``."""
        return replace(self, speed=tuple(factor * v for v in self.speed),
                       accel=tuple(factor * v for v in self.accel),
                       dynamic=tuple(factor * v for v in self.dynamic))

    def for_robot(self, robot: RobotSpec) -> DetectorConfig:
        """Return the settings for sessions of ``robot``: these, when they were
        calibrated on it; else with its detector defaults applied (the at-rest
        thresholds raised to ``robot.detector_floor_nm`` and the growth with speed,
        acceleration and dynamic torque times ``robot.detector_motion_scale``), as when the default
        model's detector, calibrated on a simulated Panda, runs on a real FR3."""
        if self.robot == robot.name:
            return self
        floor = robot.detector_floor_nm or (0.0,) * N_JOINTS
        scale = robot.detector_motion_scale
        return replace(self._growth_times(scale),
                       noise=tuple(max(n, f) for n, f in zip(self.noise, floor, strict=True)),
                       robot=robot.name)

    @classmethod
    def from_dict(cls, doc: dict, where: str | Path | None = None) -> DetectorConfig:
        """Build settings from :meth:`to_dict`'s document; InputError if it is invalid."""
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise InputError(f"not a detector calibration (format must be {FORMAT!r})", where)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(doc) - known - {"format"})
        if unknown:
            raise InputError(f"unknown detector setting {unknown[0]!r}", where)
        if not isinstance(doc.get("source", {}), dict):
            raise InputError("detector setting 'source' must be an object", where)
        settings = {k: v for k, v in doc.items() if k != "format"}
        # Calibrations written before these settings existed meant: no low-pass, one
        # baseline time constant.
        settings.setdefault("smooth_s", 0.0)
        settings.setdefault("baseline_moving_s", settings.get("baseline_s", 2.0))
        settings.setdefault("reacquire_s", 0.0)  # and no re-acquisition after a release
        settings.setdefault("dynamic", (0.0,) * N_JOINTS)  # and no dynamic torque term
        settings.setdefault("reversal_s", 0.0)  # and a reversed deviation could start one
        try:
            return cls(**settings)
        except (TypeError, ValueError, ArithmeticError) as err:
            raise InputError(f"invalid detector calibration: {str(err)[:200]}", where) from err


def save_calibration(path: str | Path, config: DetectorConfig, *,
                     overwrite: bool = False) -> Path:
    """Write ``config`` as JSON to ``path`` atomically; return the path. An existing file
    is replaced only with ``overwrite``."""
    return write_text(path, json.dumps(config.to_dict(), indent=2) + "\n",
                      overwrite=overwrite)


def load_calibration(path: str | Path) -> DetectorConfig:
    """Read a calibration written by :func:`save_calibration`; InputError naming the
    file and the problem when it is missing, not JSON or not a valid calibration."""
    path = Path(path)
    if not os.path.lexists(path):
        raise InputError("no such calibration file", path)
    doc = read_json(path, "calibration")
    return DetectorConfig.from_dict(doc, path)


def dynamics_detector(dynamics: ArmDynamics | None) -> DetectorConfig | None:
    """Return the detector settings stored with identified ``dynamics`` (None without
    dynamics or settings); InputError naming their file when the settings are invalid."""
    if dynamics is None or dynamics.detector is None:
        return None
    return DetectorConfig.from_dict(json.loads(dynamics.detector), dynamics.source or None)


class DetectorState:
    """What the detector reports for one sample: ``contact`` (bool), ``score`` (max of
    |e|/threshold over the joints that count: see ``DetectorConfig.reversal_s``),
    ``onset`` / ``release`` (True at the sample where a contact is confirmed / ends),
    ``e`` (7,) deviation from the baseline [Nm] and ``threshold`` (7,) [Nm];
    ``restarted`` at the first sample after a gap, and ``cut`` when that gap closed a
    contact: it ended at the sample before this one.

    ``e`` and ``threshold`` are given as arrays, or as functions that return them (a
    live sample's, where most consumers read neither: two 7-vectors cost ~2.5 us), then
    computed when first read."""

    __slots__ = (
        "_e",
        "_threshold",
        "contact",
        "cut",
        "onset",
        "release",
        "restarted",
        "score",
    )

    def __init__(self, contact: bool, score: float, onset: bool, release: bool,
                 e: np.ndarray | Callable[[], np.ndarray],
                 threshold: np.ndarray | Callable[[], np.ndarray],
                 restarted: bool = False, cut: bool = False) -> None:
        self.contact, self.score, self.onset, self.release = contact, score, onset, release
        self.restarted, self.cut = restarted, cut
        self._e, self._threshold = e, threshold

    @property
    def e(self) -> np.ndarray:
        """Return the deviation from the baseline e [Nm] (7,)."""
        if callable(self._e):
            self._e = self._e()
        return self._e

    @property
    def threshold(self) -> np.ndarray:
        """Return the threshold [Nm] (7,)."""
        if callable(self._threshold):
            self._threshold = self._threshold()
        return self._threshold


class _JointFloats:
    """A detector state kept as seven Python floats in the attribute ``name``, given as
    a new array (7,) and taken from any array-like: the per-sample path works on the
    floats, :meth:`Detector.run`'s chunks on arrays."""

    def __init__(self, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, detector: None, owner: type | None = None) -> _JointFloats: ...

    @overload
    def __get__(self, detector: object, owner: type | None = None) -> np.ndarray: ...

    def __get__(self, detector: object, owner: type | None = None
                ) -> np.ndarray | _JointFloats:
        """Return the state as an array (the descriptor itself on the class)."""
        return self if detector is None else np.array(getattr(detector, self.name))

    def __set__(self, detector: object, value: np.ndarray) -> None:
        """Keep ``value`` as seven floats."""
        setattr(detector, self.name, np.asarray(value, dtype=float).tolist())


class Detector:
    """Streaming contact detector (see the module docstring).

    :meth:`update` (a live robot's per-sample path) keeps the per-joint state as seven
    Python floats: on 7-vectors one pass of float arithmetic costs less than the
    dozen array operations it replaces. :attr:`baseline`, :attr:`r_f`, :attr:`ddq_f`
    and :attr:`dq_prev` give (and take) that state as arrays, which :meth:`run` works
    on."""

    def __init__(self, config: DetectorConfig | None = None) -> None:
        self.config = config or DetectorConfig()
        self._noise = np.array(self.config.noise)
        self._speed = np.array(self.config.speed)
        self._accel = np.array(self.config.accel)
        self._dynamic = np.array(self.config.dynamic)
        self._range = (None if self.config.dynamic_range is None
                       else np.array(self.config.dynamic_range))
        self._coefficients = list(zip(self.config.noise, self.config.speed,
                                      self.config.accel, self.config.dynamic,
                                      self.config.dynamic_range or (math.inf,) * N_JOINTS,
                                      strict=True))
        self._reads_dynamic = self.config.reads_dynamic
        self.reset()

    def _check_dynamic(self, dyn: object) -> None:
        """Refuse a stream without the dynamic torque scale when these settings grow with
        it: a caller that leaves it out would get thresholds too low in motion (false
        events), silently."""
        if dyn is None and self._reads_dynamic:
            raise ValueError(f"these detector settings read the chain's {DYNAMIC_FEATURE!r} "
                             "(a positive dynamic coefficient): compute it with the chain "
                             "(DetectorConfig.chain_features) and pass it as dyn")

    def reset(self) -> None:
        """Forget the past: the next sample starts a new stream."""
        self.t0: float | None = None
        self.t: float | None = None
        self._dq_prev = [0.0] * N_JOINTS
        self._ddq_f = [0.0] * N_JOINTS
        self.speed = 0.0
        self.accel = 0.0
        self._dyn = [0.0] * N_JOINTS
        self._baseline = [0.0] * N_JOINTS
        self._r_f = [0.0] * N_JOINTS
        self.contact = False
        self._since: float | None = None  # time the pending switch started
        self._released: float | None = None  # time of the last release
        self._onset_joints = np.ones(N_JOINTS, bool)
        # per joint, the largest score in the current contact and e there; after a
        # release, that e of the joints it loaded (score > REVERSAL_LOAD; else 0)
        self._peak = [0.0] * N_JOINTS
        self._peak_e = [0.0] * N_JOINTS
        self._reversal = [0.0] * N_JOINTS

    baseline = _JointFloats("_baseline")
    """The baseline b [Nm] (7,), a copy."""
    r_f = _JointFloats("_r_f")
    """The low-passed residual r_f [Nm] (7,) of the last sample, a copy."""
    ddq_f = _JointFloats("_ddq_f")
    """The low-passed joint acceleration [rad/s^2] (7,) of the last sample, a copy."""
    dq_prev = _JointFloats("_dq_prev")
    """The joint velocity [rad/s] (7,) of the last sample, a copy."""
    dyn = _JointFloats("_dyn")
    """The held dynamic torque scale d [Nm] (7,) of the last sample, a copy."""
    peak = _JointFloats("_peak")
    """Each joint's largest score in the current (or last) contact (7,), a copy."""
    peak_e = _JointFloats("_peak_e")
    """Each joint's deviation e [Nm] where :attr:`peak` was reached (7,), a copy."""
    reversal = _JointFloats("_reversal")
    """After a release, :attr:`peak_e` [Nm] of each joint the contact loaded (0: one it
    did not) (7,), a copy: for ``reversal_s``, a deviation of the other sign and at most
    :data:`REVERSAL_SPAN` times as large does not start a contact."""

    def motion(self, t: float, dq: np.ndarray, dyn: np.ndarray | None = None
               ) -> tuple[float, float]:
        """Advance the motion measures to sample ``t`` [s] with joint velocity ``dq``
        [rad/s] (7,) and dynamic torque scale ``dyn`` [Nm] (7,; None: 0); return (s
        [rad/s], a [rad/s^2]). The held d is kept in :attr:`dyn`."""
        hold = self.config.motion_hold_s
        floats: list[float] = np.asarray(dq, dtype=float).tolist()  # kept as dq_prev
        speed = math.hypot(*floats)  # |dq|, to rounding as sqrt(dq . dq)
        dyn_floats = [0.0] * N_JOINTS if dyn is None else np.asarray(dyn, dtype=float).tolist()
        if self.t is None:
            self.speed, self.accel, self._dyn = speed, 0.0, dyn_floats
        else:
            h = t - self.t
            if h > 0:  # the low-pass of ddq = (dq - dq_prev) / h; without a step it holds
                denominator = 1.0 + DDQ_FILTER_GAIN * h
                self._ddq_f = [(f + DDQ_FILTER_GAIN * (v - v0)) / denominator
                               for f, v, v0 in zip(self._ddq_f, floats, self._dq_prev,
                                                   strict=True)]
            decay = math.exp(-h / hold) if hold > 0 else 0.0
            self.speed = max(speed, self.speed * decay)
            self.accel = max(math.hypot(*self._ddq_f), self.accel * decay)
            self._dyn = [max(d, held * decay) for d, held in zip(dyn_floats, self._dyn,
                                                                 strict=True)]
        self._dq_prev = floats
        return self.speed, self.accel

    def run(self, t: np.ndarray, r: np.ndarray, dq: np.ndarray,
            dyn: np.ndarray | None = None) -> Detection:
        """Feed a chunk of samples at once: times ``t`` (n,) [s] after the previous
        sample, residual ``r`` [Nm], joint velocity ``dq`` [rad/s] and dynamic torque
        scale ``dyn`` [Nm] (the chain's ``tau_dyn``; None only for settings without
        the term, else ValueError) (n, 7); return
        their :class:`Detection` and carry the state on, as :meth:`update` sample by
        sample would (the same decisions; the filters' values to about 1e-12).

        The filters, the motion measures and a baseline that is tracked are linear
        recurrences, solved vectorised (:func:`contactkit.features.observer.
        solve_recurrence`); the state machine (tracking, onset pending, contact, release
        pending) moves from one switch to the next over whole stretches of samples."""
        t = np.asarray(t, dtype=float)
        r = np.asarray(r, dtype=float).reshape(-1, N_JOINTS)
        dq = np.asarray(dq, dtype=float).reshape(-1, N_JOINTS)
        n = len(t)
        self._check_dynamic(dyn)
        dyn = (np.zeros((n, N_JOINTS)) if dyn is None
               else np.asarray(dyn, dtype=float).reshape(-1, N_JOINTS))
        out = Detection(np.zeros(n, bool), np.zeros(n), np.zeros((n, N_JOINTS)),
                        np.zeros((n, N_JOINTS)), np.zeros((n, N_JOINTS)), np.zeros(n),
                        np.zeros(n), [], [], np.zeros(n, bool), np.zeros(n, bool), [],
                        np.zeros((n, N_JOINTS)))
        if n == 0:
            return out
        gaps = restarts(t, self.t).tolist()
        for start, stop in itertools.pairwise([0, *gaps, n]):
            if stop <= start:
                continue
            if start in gaps:
                out.restarts.append(start)
                if self.contact:
                    out.cuts.append(start)
                    if out.intervals and out.intervals[-1][1] is None:
                        out.intervals[-1] = (out.intervals[-1][0], start - 1)
                self.reset()
            _Run(self, t[start:stop], r[start:stop], dq[start:stop], dyn[start:stop], out,
                 start).run()
        return out

    def update(self, t: float, r: np.ndarray, dq: np.ndarray,
               dyn: np.ndarray | None = None) -> DetectorState:
        """Feed one sample: time [s], residual r [Nm] (7,), joint velocity [rad/s] (7,)
        and dynamic torque scale [Nm] (7,; the chain's ``tau_dyn``; None only for
        settings without the term, else ValueError).
        After a gap (a step over ``RESTART_STEP_S``) the detector restarts first.
        Returns the detector's :class:`DetectorState` at the sample."""
        t = float(t)  # a NumPy scalar's arithmetic costs several times a float's
        cfg = self.config
        self._check_dynamic(dyn)
        restarted = cut = False
        if self.t is not None and t - self.t > RESTART_STEP_S:
            restarted, cut = True, self.contact
            self.reset()
        s, a = self.motion(t, dq, dyn)
        d = self._dyn
        first = self.t is None
        h = 0.0 if self.t is None else t - self.t
        self.t = t
        if self.t0 is None:
            self.t0 = t
        r_floats: list[float] = np.asarray(r, dtype=float).tolist()
        if first or cfg.smooth_s == 0.0:
            self._r_f = r_floats
        else:
            gain = h / (cfg.smooth_s + h)
            self._r_f = [f + gain * (x - f) for f, x in zip(self._r_f, r_floats, strict=True)]
        if t - self.t0 < cfg.warmup_s:
            self._baseline = self._r_f
            return DetectorState(False, 0.0, False, False, _zeros, self._threshold(s, a, d),
                                 restarted, cut)
        # e = r_f - b and the threshold noise + speed s + accel a + dynamic d (+ the
        # growth beyond the calibrated range of d), inline, as the returned state
        # computes them when read
        r_f, before = self._r_f, self._baseline
        ratio = [abs(f - b) / (n + s * v + a * c + x * w
                               + (BEYOND_RANGE * (x - m) if x > m else 0.0))
                 for f, b, x, (n, v, c, w, m) in zip(r_f, before, d, self._coefficients,
                                                      strict=True)]
        onset = release = False
        if not self.contact:
            if self._released is not None and t - self._released < cfg.reversal_s:
                ratio = [0.0 if -REVERSAL_SPAN * y * y < (f - b) * y < 0.0 else x
                         for x, f, b, y in zip(ratio, r_f, before, self._reversal,
                                               strict=True)]
            score = max(ratio)
            if score > 1.0:
                self._since = t if self._since is None else self._since
                if t - self._since >= cfg.min_on_s - 1e-12:
                    self.contact, onset, self._since = True, True, None
                    self._onset_joints = np.array(ratio) > 1.0
                    self._peak = ratio
                    self._peak_e = [f - b for f, b in zip(r_f, before, strict=True)]
            else:
                self._since = None
                tau = cfg.baseline_moving_s if s >= REST_SPEED else cfg.baseline_s
                if self._released is not None and t - self._released < cfg.reacquire_s:
                    tau = cfg.baseline_reacquire_s
                gain = h / (tau + h)
                # zip's length check costs ~0.6 us: these lists are r_f's and b's,
                # checked above
                self._baseline = [b + gain * (f - b) for f, b in zip(r_f, before, strict=False)]
        else:
            score = max(ratio)
            for j, x in enumerate(ratio):
                if x > self._peak[j]:
                    self._peak[j], self._peak_e[j] = x, r_f[j] - before[j]
            if (max(itertools.compress(ratio, self._onset_joints.tolist())) < cfg.release
                    and score <= HOLD_LOAD):
                self._since = t if self._since is None else self._since
                if t - self._since >= cfg.min_off_s - 1e-12:
                    self.contact, release, self._since = False, True, None
                    self._released = t
                    self._reversal = [e if peak > REVERSAL_LOAD else 0.0
                                      for e, peak in zip(self._peak_e, self._peak,
                                                            strict=True)]
                    self._baseline = [b if held else f for b, f, held in zip(
                        self._baseline, self._r_f, self._onset_joints.tolist(),
                        strict=True)]
            else:
                self._since = None
        return DetectorState(self.contact, score, onset, release,
                             lambda: np.subtract(r_f, before), self._threshold(s, a, d),
                             restarted, cut)

    def _threshold(self, s: float, a: float, d: list[float]) -> Callable[[], np.ndarray]:
        """Return the function that computes the threshold [Nm] (7,) at speed ``s``
        [rad/s], acceleration ``a`` [rad/s^2] and held dynamic torque scale ``d`` [Nm]
        (7 floats): noise + speed s + accel a + dynamic d + :func:`beyond_range`."""
        held = np.array(d)
        return lambda: (self._noise + self._speed * s + self._accel * a + self._dynamic * held
                        + beyond_range(self._range, held))


@dataclass
class Detection:
    """Batch detector output: per-sample ``contact`` (N,) bool, ``score`` (N,),
    ``e``, ``threshold`` and ``baseline`` (N, 7) [Nm], ``speed`` [rad/s] and
    ``accel`` [rad/s^2] (N,), the held dynamic torque scale ``dynamic`` [Nm] (N, 7)
    (:meth:`Detector.run` gives it), the contact intervals as sample indices
    (onset, release or None; a contact cut by a gap is released at the last sample
    before it; of a chunk, those that start in it) and the samples at which the
    detector restarted after a gap. :meth:`Detector.run` also gives the per-sample
    ``onset`` and ``release`` flags (N,) bool and the restarts that ended a contact
    (``cuts``)."""

    contact: np.ndarray
    score: np.ndarray
    e: np.ndarray
    threshold: np.ndarray
    baseline: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    intervals: list[tuple[int, int | None]]
    restarts: list[int] = field(default_factory=list)
    onset: np.ndarray | None = None
    release: np.ndarray | None = None
    cuts: list[int] = field(default_factory=list)
    dynamic: np.ndarray | None = None


def detect(t: np.ndarray, r: np.ndarray, dq: np.ndarray,
           config: DetectorConfig | None = None, dyn: np.ndarray | None = None) -> Detection:
    """Run :class:`Detector` over a whole stream (t (N,) [s], r, dq and the dynamic
    torque scale dyn (N, 7); None only for settings without the term) with
    :meth:`Detector.run`; return a
    :class:`Detection` equal to feeding the samples one at a time."""
    return Detector(config).run(t, r, dq, dyn)


SWITCH_CHUNK = 256
"""Samples the vectorised detector (:meth:`Detector.run`) looks ahead for the next
switch of its state; doubled while none comes, so a stretch without switches costs a
few vectorised passes and a switch costs at most this many samples' work."""


class _Run:
    """One :meth:`Detector.run` over a chunk without gaps (``t`` (n,) [s], ``r`` [Nm],
    ``dq`` [rad/s], ``dyn`` [Nm] (n, 7)), writing rows ``offset`` on of ``out``."""

    def __init__(self, detector: Detector, t: np.ndarray, r: np.ndarray, dq: np.ndarray,
                 dyn: np.ndarray, out: Detection, offset: int) -> None:
        self.det, self.cfg, self.out, self.offset = detector, detector.config, out, offset
        self.t, self.r = t, r
        first = detector.t is None
        before = t[0] if detector.t is None else detector.t
        self.h = np.diff(t, prepend=before)  # 0 at a stream's first sample
        if detector.t0 is None:
            detector.t0 = float(t[0])
        self.speed, self.accel, self.ddq_f = self._motion(dq, first, before)
        self.dynamic = self._held_dynamic(dyn, first, before)
        self.threshold = (detector._noise + detector._speed * self.speed[:, None]
                          + detector._accel * self.accel[:, None]
                          + detector._dynamic * self.dynamic
                          + beyond_range(detector._range, self.dynamic))
        self.r_f = self._smooth(first)
        detector.dq_prev = dq[-1]

    def _motion(self, dq: np.ndarray, first: bool, before: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the speed [rad/s], accel [rad/s^2] (n,) and low-passed ddq (n, 7) of
        :meth:`Detector.motion` at every sample."""
        det, n = self.det, len(self.t)
        lo = 1 if first else 0  # a stream's first sample has no step
        ddq_f = np.empty((n, N_JOINTS))
        ddq_f[:lo] = det.ddq_f
        if n > lo:
            previous = np.concatenate((dq[:1] if first else det.dq_prev[None], dq[:-1]))
            ddq_f[lo:] = filtered_rate(self.h[lo:, None], dq[lo:] - previous[lo:],
                                       ddq_f[0] if first else det.ddq_f)
        speed = np.sqrt(np.einsum("ij,ij->i", dq, dq))
        accel = np.sqrt(np.einsum("ij,ij->i", ddq_f, ddq_f))
        accel[:lo] = 0.0
        elapsed = (self.t - before) / det.config.motion_hold_s \
            if det.config.motion_hold_s > 0 else None
        speed = _peak_hold(speed, 0.0 if first else det.speed, elapsed)
        accel = _peak_hold(accel, 0.0 if first else det.accel, elapsed)
        det.ddq_f, det.speed, det.accel = ddq_f[-1], float(speed[-1]), float(accel[-1])
        return speed, accel, ddq_f

    def _held_dynamic(self, dyn: np.ndarray, first: bool, before: float) -> np.ndarray:
        """Return the held dynamic torque scale of :meth:`Detector.motion` [Nm] (n, 7)
        at every sample."""
        det = self.det
        elapsed = (self.t - before) / det.config.motion_hold_s \
            if det.config.motion_hold_s > 0 else None
        held = _peak_hold(dyn, np.zeros(N_JOINTS) if first else det.dyn, elapsed)
        det.dyn = held[-1]
        return held

    def _smooth(self, first: bool) -> np.ndarray:
        """Return the low-passed residual r_f [Nm] (n, 7)."""
        det, smooth = self.det, self.cfg.smooth_s
        if smooth == 0.0:
            r_f = self.r.copy()
        else:
            lo = 1 if first else 0
            r_f = np.empty_like(self.r)
            r_f[:lo] = self.r[:lo]
            if len(self.r) > lo:
                h = self.h[lo:, None]
                a = np.broadcast_to(smooth / (smooth + h), (len(h), N_JOINTS))
                r_f[lo:] = solve_recurrence(a, h / (smooth + h) * self.r[lo:],
                                            r_f[0] if first else det.r_f)
        det.r_f = r_f[-1]
        return r_f

    def _write(self, start: int, stop: int, e: np.ndarray | float, score: np.ndarray | float,
               baseline: np.ndarray, contact: bool) -> None:
        rows = slice(self.offset + start, self.offset + stop)
        out = self.out
        out.e[rows], out.score[rows], out.baseline[rows] = e, score, baseline
        out.contact[rows] = contact
        out.threshold[rows] = self.threshold[start:stop]
        out.speed[rows], out.accel[rows] = self.speed[start:stop], self.accel[start:stop]
        assert out.dynamic is not None  # Detector.run gives it
        out.dynamic[rows] = self.dynamic[start:stop]

    def _ratio(self, start: int, stop: int, baseline: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        e = self.r_f[start:stop] - baseline
        return e, np.abs(e) / self.threshold[start:stop]

    def _unturned(self, start: int, stop: int, e: np.ndarray, ratio: np.ndarray
                  ) -> np.ndarray:
        """Return ``ratio`` (rows ``start:stop``, no contact) with 0 for the joints whose
        deviation ``e`` has turned against the last contact's within ``reversal_s`` of
        its release (:meth:`Detector.update`'s rule)."""
        det = self.det
        if det._released is None:
            return ratio
        window = self.t[start:stop] - det._released < self.cfg.reversal_s
        if not window.any():
            return ratio
        reversal = det.reversal
        turned = e * reversal
        return np.where(window[:, None] & (turned < 0.0)
                        & (turned > -REVERSAL_SPAN * reversal * reversal), 0.0, ratio)

    def _peaks(self, e: np.ndarray, ratio: np.ndarray) -> None:
        """Raise each joint's :attr:`Detector.peak` to its largest ``ratio`` among these
        contact rows (the first where it ties), with ``e`` there [Nm]."""
        if not len(ratio):
            return
        det = self.det
        rows = np.argmax(ratio, axis=0)
        best = ratio[rows, np.arange(N_JOINTS)]
        higher = best > det.peak
        det.peak = np.where(higher, best, det.peak)
        det.peak_e = np.where(higher, e[rows, np.arange(N_JOINTS)], det.peak_e)

    def run(self) -> None:
        """Run the state machine over the chunk; leave the detector's state after it."""
        det, cfg, t = self.det, self.cfg, self.t
        n = len(t)
        warm = int(np.count_nonzero(t - det.t0 < cfg.warmup_s))
        if warm:
            self._write(0, warm, 0.0, 0.0, self.r_f[:warm], False)
            det.baseline = self.r_f[warm - 1]
        i, size = warm, SWITCH_CHUNK
        while i < n:
            stop = min(n, i + size)
            if det.contact:
                done = self._contact(i, stop)
            elif det._since is None:
                done = self._track(i, stop)
            else:
                done = self._pending(i, stop)
            size = size * 2 if done == stop else SWITCH_CHUNK
            i = done
        det.t = float(t[-1])

    def _track(self, i: int, stop: int) -> int:
        """No contact, none pending: the baseline follows r_f. Return the first sample
        over threshold (which starts a pending onset), or ``stop``."""
        det, cfg = self.det, self.cfg
        h = self.h[i:stop]
        tau = np.where(self.speed[i:stop] >= REST_SPEED, cfg.baseline_moving_s, cfg.baseline_s)
        if det._released is not None:
            tau[self.t[i:stop] - det._released < cfg.reacquire_s] = cfg.baseline_reacquire_s
        gain = (h / (tau + h))[:, None]
        after = solve_recurrence(np.broadcast_to(1.0 - gain, (len(h), N_JOINTS)),
                                 gain * self.r_f[i:stop], det.baseline)
        e, ratio = self._ratio(i, stop, np.concatenate((det.baseline[None], after[:-1])))
        ratio = self._unturned(i, stop, e, ratio)
        score = reduce_rows(np.maximum, ratio)
        over = np.flatnonzero(score > 1.0)
        k = int(over[0]) if over.size else len(h)
        self._write(i, i + k, e[:k], score[:k], after[:k], False)
        if k:
            det.baseline = after[k - 1]
        if k < len(h):
            det._since = float(self.t[i + k])
        return i + k

    def _pending(self, i: int, stop: int) -> int:
        """Over threshold since ``_since``, baseline frozen: the onset is confirmed after
        ``min_on_s`` unless the score falls back first. Return the next sample to run."""
        det, cfg = self.det, self.cfg
        e, ratio = self._ratio(i, stop, det.baseline)
        ratio = self._unturned(i, stop, e, ratio)
        score = reduce_rows(np.maximum, ratio)
        low = np.flatnonzero(score <= 1.0)
        ready = np.flatnonzero(self.t[i:stop] - det._since >= cfg.min_on_s - 1e-12)
        end = stop - i
        fall = int(low[0]) if low.size else end
        onset = int(ready[0]) if ready.size and ready[0] < fall else None
        if onset is None:
            self._write(i, i + fall, e[:fall], score[:fall], det.baseline, False)
            if fall < end:
                det._since = None  # this sample is tracked again
            return i + fall
        self._write(i, i + onset, e[:onset], score[:onset], det.baseline, False)
        self._write(i + onset, i + onset + 1, e[onset], score[onset], det.baseline, True)
        assert self.out.onset is not None  # Detector.run gives the per-sample flags
        self.out.onset[self.offset + i + onset] = True
        self.out.intervals.append((self.offset + i + onset, None))
        det.contact, det._since = True, None
        det._onset_joints = ratio[onset] > 1.0
        det.peak, det.peak_e = ratio[onset], e[onset]
        return i + onset + 1

    def _contact(self, i: int, stop: int) -> int:
        """In contact, baseline frozen: released once the onset joints stay below
        ``release`` for ``min_off_s``. Return the next sample to run."""
        det, cfg = self.det, self.cfg
        e, ratio = self._ratio(i, stop, det.baseline)
        score = reduce_rows(np.maximum, ratio)
        below = ((reduce_rows(np.maximum, ratio[:, det._onset_joints]) < cfg.release)
                 & (score <= HOLD_LOAD))
        end = stop - i
        if det._since is None:
            start = np.flatnonzero(below)
            k = int(start[0]) if start.size else end
            self._peaks(e[:k], ratio[:k])
            self._write(i, i + k, e[:k], score[:k], det.baseline, True)
            if k < end:
                det._since = float(self.t[i + k])
            return i + k
        above = np.flatnonzero(~below)
        back = int(above[0]) if above.size else end
        ready = np.flatnonzero(self.t[i:stop] - det._since >= cfg.min_off_s - 1e-12)
        release = int(ready[0]) if ready.size and ready[0] < back else None
        if release is None:
            k = min(back + 1, end)
            self._peaks(e[:k], ratio[:k])
            self._write(i, i + k, e[:k], score[:k], det.baseline, True)
            if back < end:
                det._since = None
            return i + k
        self._write(i, i + release, e[:release], score[:release], det.baseline, True)
        self._peaks(e[:release + 1], ratio[:release + 1])
        det.reversal = np.where(det.peak > REVERSAL_LOAD, det.peak_e, 0.0)
        k = i + release
        others = ~det._onset_joints
        baseline = det.baseline
        baseline[others] = self.r_f[k][others]
        det.baseline = baseline
        self._write(k, k + 1, e[release], score[release], baseline, False)
        row = self.offset + k
        assert self.out.release is not None  # Detector.run gives the per-sample flags
        self.out.release[row] = True
        if self.out.intervals and self.out.intervals[-1][1] is None:
            self.out.intervals[-1] = (self.out.intervals[-1][0], row)
        det.contact, det._since, det._released = False, None, float(self.t[k])
        return k + 1


def beyond_range(dynamic_range: np.ndarray | None, dynamic: np.ndarray) -> np.ndarray:
    """Return what each joint's threshold grows by [Nm] at held dynamic torque scale
    ``dynamic`` [Nm] (..., 7) beyond ``dynamic_range`` [Nm] (7,; the calibration data's
    largest; None: no growth): :data:`BEYOND_RANGE` times the excess.

    Model error is linear in the dynamics that excite it, and where the calibration data
    never went, nothing showed how large it gets: the calibrated growth may be 0 (an arm
    identified on the gentle motion between contacts, whose error there stayed under the
    at-rest floor) and still wrong by more at a motion several times as strong. That
    detector took the rebound after a shove (joint 4's d at 22 Nm against the 4.2 Nm it
    was calibrated on, |e| 0.57 Nm) for a contact (simulated ``thesis-dynamic``, robot
    instance 66)."""
    if dynamic_range is None:
        return np.zeros_like(dynamic, dtype=float)
    return BEYOND_RANGE * np.maximum(dynamic - dynamic_range, 0.0)


def _peak_hold(values: np.ndarray, before: float | np.ndarray, elapsed: np.ndarray | None
               ) -> np.ndarray:
    """Return x_k = max(values_k, x_{k-1} exp(-(T_k - T_{k-1}))) with x_{-1} = ``before``
    and ``elapsed`` T (n,) the time since x_{-1} in units of the hold time (None: no
    hold, x = values), vectorised in the log domain (a sample that sets the peak keeps
    its value exactly). ``values`` (n,) with one ``before``, or (n, k) with k of them,
    one per column."""
    if elapsed is None:
        return values.copy()
    if values.ndim == 2:
        elapsed = elapsed[:, None]
    with np.errstate(divide="ignore"):
        shifted = np.log(values) + elapsed
        start = np.log(before)
    peak = np.maximum(np.maximum.accumulate(shifted, axis=0), start)
    return np.where(shifted >= peak, values, np.exp(peak - elapsed))


@dataclass
class CalibrationData:
    """No-contact samples for :func:`calibrate`: |e| (N, 7) [Nm], speed (N,) [rad/s],
    accel (N,) [rad/s^2] and the held dynamic torque scale (N, 7) [Nm] (None: not
    given, the ``dynamic`` coefficients are not fitted); ``t`` (N,) [s] their time stamps
    (None: not known; :func:`drop_outliers` needs them)."""

    abs_e: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    dynamic: np.ndarray | None = None
    t: np.ndarray | None = None

    def subset(self, keep: np.ndarray) -> CalibrationData:
        """Return the samples where the boolean mask ``keep`` (N,) is true."""
        return CalibrationData(self.abs_e[keep], self.speed[keep], self.accel[keep],
                               None if self.dynamic is None else self.dynamic[keep],
                               None if self.t is None else self.t[keep])


def calibration_samples(t: np.ndarray, r: np.ndarray, dq: np.ndarray,
                        template: DetectorConfig | None = None,
                        dyn: np.ndarray | None = None) -> CalibrationData:
    """Return the deviations and motion measures of one no-contact stream, with the
    baseline tracked throughout (no detection), after the warm-up at its start and after
    every gap (where the detector restarts: the observer's own settling is no model
    error); with the dynamic torque scale ``dyn`` [Nm] (N, 7) (the chain's
    ``tau_dyn``), its held value too; with the samples' time stamps."""
    template = template or DetectorConfig()
    quiet = replace(template, noise=(1e9,) * N_JOINTS)
    found = detect(t, r, dq, quiet, dyn)
    starts = np.concatenate(([0], found.restarts)).astype(int)
    since = t - t[starts[np.searchsorted(starts, np.arange(len(t)), side="right") - 1]]
    keep = since >= template.warmup_s
    assert found.dynamic is not None  # Detector.run gives it
    return CalibrationData(np.abs(found.e[keep]), found.speed[keep], found.accel[keep],
                           None if dyn is None else found.dynamic[keep], t[keep])


OUTLIER_FACTOR = 4.0
""":func:`drop_outliers`' limit: this many times the median over the streams of each
joint's largest |e|."""
OUTLIER_WINDOW_S = 0.5
"""What :func:`drop_outliers` drops on each side of a sample over its limit [s]."""


def drop_outliers(parts: list[CalibrationData], factor: float = OUTLIER_FACTOR,
                  window_s: float = OUTLIER_WINDOW_S) -> tuple[list[CalibrationData], float]:
    """Return ``parts`` (each with its time stamps ``t``) without the samples within
    ``window_s`` [s] of a sample whose |e_j| exceeds ``factor`` times the median over
    the parts of joint j's largest |e|, and the share of samples dropped.

    For calibration data that may hold a contact nobody marked (motion taken from
    sessions with contact, around the contacts a detector found): :func:`calibrate`
    covers every sample, so one missed touch would set the thresholds. A part's model
    error is of the same size as the others'; a touch stands out from it. On simulated
    ``thesis-dynamic`` sessions of robot instance 57, with the identified model, the
    largest |e| on joint 2 was 0.12-0.16 Nm in sessions without contact and 0.38-2.2 Nm
    in the five whose touch the detector had missed."""
    if not parts:
        return [], 0.0
    if any(part.t is None for part in parts):
        raise ValueError("drop_outliers needs each part's time stamps")
    largest = np.array([part.abs_e.max(axis=0) if len(part.abs_e) else np.zeros(N_JOINTS)
                        for part in parts])
    limit = factor * np.median(largest, axis=0)
    kept, dropped, total = [], 0, 0
    for part in parts:
        assert part.t is not None
        over = part.t[(part.abs_e > limit).any(axis=1)]
        near = np.zeros(len(part.t), dtype=bool)
        if over.size:
            first = np.searchsorted(over, part.t - window_s, side="left")
            near = (first < over.size) & (over[np.minimum(first, over.size - 1)]
                                          <= part.t + window_s)
        kept.append(part.subset(~near))
        dropped += int(near.sum())
        total += len(part.t)
    return kept, dropped / max(total, 1)


def _envelope(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Smallest mean of x c over the samples with x c >= y, c >= 0 (a linear program)."""
    from scipy.optimize import linprog  # here: loading a calibration needs no scipy

    result = linprog(x.mean(axis=0), A_ub=-x, b_ub=-y, bounds=[(0, None)] * x.shape[1],
                     method="highs")
    if not result.success:
        raise InputError(f"detector calibration failed: {result.message}")
    return result.x


def _thin(y: np.ndarray, points: int) -> np.ndarray:
    """Indices of the largest y in each of about ``points`` consecutive blocks."""
    step = max(1, len(y) // points)
    blocks = len(y) // step
    return np.argmax(y[:blocks * step].reshape(blocks, step), axis=1) + np.arange(blocks) * step


def calibrate(parts: list[CalibrationData], template: DetectorConfig | None = None,
              margin: float = 1.5, source: dict | None = None,
              motion_margin: float | None = None,
              floor: float | tuple[float, ...] = MIN_NOISE,
              bound_dynamic: bool = True) -> DetectorConfig:
    """Fit the detector's per-joint threshold coefficients to no-contact data.

    Two steps per joint: ``noise`` is the largest |e| among samples at rest (speed
    below 0.05 rad/s; ``template``'s value when there are none), so that the final
    threshold at rest is at least ``floor`` [Nm], one value or one per joint (default
    :data:`MIN_NOISE`, 0.3 Nm: the static-friction offsets a real wrist joint keeps
    after being moved: up to 0.5 Nm on the MindLab Panda; the free-motion log's joint 7
    model error is 0.2 Nm);
    then ``speed``, ``accel`` and (when every part carries the dynamic torque scale
    d, else 0) ``dynamic`` are the smallest (by mean) envelope
    speed s + accel a + dynamic d_j >= |e_j| - noise_j over every sample. ``noise`` is
    multiplied by ``margin``, the others by ``motion_margin`` (default: ``margin``; wider when
    the calibration data come from another arm than the one it will run on, such as
    a simulator, whose model error in motion matches the real arm's only roughly).
    Calibration data without motion leave speed and accel at 0, and data without
    rest keep the template's noise: record both holds and free motion. With
    ``bound_dynamic`` and data that carry d, each joint's largest d is kept as
    ``dynamic_range``: the thresholds grow beyond it (:func:`beyond_range`). Returns
    ``template`` with the fitted coefficients.
    """
    if not parts:
        raise InputError("no no-contact data to calibrate on")
    abs_e = np.concatenate([p.abs_e for p in parts])
    x = np.column_stack([np.concatenate([p.speed for p in parts]),
                         np.concatenate([p.accel for p in parts])])
    dynamic = (np.concatenate([p.dynamic for p in parts])
               if all(p.dynamic is not None for p in parts) else None)
    if len(x) < 100:
        raise InputError(f"too little no-contact data to calibrate on ({len(x)} samples "
                         "after the warm-up)")
    template = template or DetectorConfig()
    motion_margin = margin if motion_margin is None else motion_margin
    rest = x[:, 0] < REST_SPEED
    noise = abs_e[rest].max(axis=0) if rest.any() else np.array(template.noise) / margin
    noise = np.maximum(noise, np.asarray(floor, dtype=float) / margin)
    moving = np.zeros((N_JOINTS, 3))
    for j in range(N_JOINTS):
        excess = abs_e[:, j] - noise[j]
        if (excess > 0).any():
            idx = _thin(excess, CALIBRATION_POINTS)
            over = excess[idx] > 0
            xj = x if dynamic is None else np.column_stack([x, dynamic[:, j]])
            moving[j, :xj.shape[1]] = _envelope(excess[idx][over], xj[idx][over])
    dynamic_range = tuple(np.maximum(dynamic.max(axis=0), MIN_DYNAMIC_RANGE)) \
        if bound_dynamic and dynamic is not None else None
    return replace(template, noise=tuple(margin * noise), dynamic_range=dynamic_range,
                   speed=tuple(motion_margin * moving[:, 0]),
                   accel=tuple(motion_margin * moving[:, 1]),
                   dynamic=tuple(motion_margin * moving[:, 2]),
                   source=dict(source or {}, margin=margin, motion_margin=motion_margin,
                               samples=len(x), rest_samples=int(rest.sum())))
