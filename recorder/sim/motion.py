"""Free motion as a real arm does it when nobody touches it: holds, point-to-point
moves and exciting-trajectory-like multi-sine motion, up to the Panda's limits.

A :class:`MotionPlan` is a sequence of segments, each starting where the previous one
ended, with zero velocity at every segment boundary:

* ``hold``: stay at the pose;
* ``move``: a quintic point-to-point move (zero velocity and acceleration at both ends)
  to a random pose, timed so that the furthest-moving joint peaks at a chosen fraction
  of its velocity limit and no joint exceeds 70 % of its acceleration limit;
* ``sines``: a sum of sines per joint around the pose, as in the exciting trajectories
  used to identify robot dynamics (Gaz et al. 2019: up to 1.8 rad/s), under a
  sin^2 envelope so it starts and ends at rest, scaled per joint to a chosen fraction
  of the velocity limit within 70 % of the acceleration limit and the joint range.

Angles in rad, speeds in rad/s, times in s.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from contactkit.robots import JointLimits

KINDS = ("hold", "move", "sines")
LIMIT_MARGIN_RAD = 0.25
ACCEL_FRACTION = 0.7
SPEED_FRACTION = (0.25, 0.85)
MOVE_SPAN_RAD = 1.2
HOLD_S = (0.4, 1.5)
SINES_S = (2.5, 5.0)
SINES_HZ = (0.3, 1.2)
HARMONICS = 4


@dataclass(frozen=True)
class Segment:
    """One piece of a motion plan: ``kind`` (hold, move, sines), start time and
    duration [s], start and end pose [rad] and, for sines, amplitudes [rad] (K x 7),
    frequencies [Hz] (K) and phases [rad] (K x 7)."""

    kind: str
    start_s: float
    duration_s: float
    q_from: tuple[float, ...]
    q_to: tuple[float, ...]
    amplitudes: tuple[tuple[float, ...], ...] = ()
    freqs_hz: tuple[float, ...] = ()
    phases: tuple[tuple[float, ...], ...] = ()

    def sample(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return (q [rad], dq [rad/s]), each (N, 7), at times ``tau`` [s] since the
        segment's start (clipped to the segment)."""
        q0, q1 = np.array(self.q_from), np.array(self.q_to)
        s = np.clip(tau / self.duration_s, 0.0, 1.0)[:, None]
        if self.kind == "move":
            blend = s**3 * (10.0 + s * (-15.0 + 6.0 * s))
            rate = 30.0 * s**2 * (1.0 - s) ** 2 / self.duration_s
            return q0 + (q1 - q0) * blend, (q1 - q0) * rate
        if self.kind == "hold":
            return np.broadcast_to(q0, (len(tau), q0.size)).copy(), np.zeros((len(tau), q0.size))
        return q0 + _sines(self, np.clip(tau, 0.0, self.duration_s), 0), \
            _sines(self, np.clip(tau, 0.0, self.duration_s), 1)


def _sines(segment: Segment, tau: np.ndarray, derivative: int) -> np.ndarray:
    """The enveloped sum of sines (derivative 0: offset [rad]; 1: velocity [rad/s])."""
    amp, freq = np.array(segment.amplitudes), np.array(segment.freqs_hz)
    phase = np.array(segment.phases)
    omega = 2.0 * np.pi * freq
    arg = omega[None, :, None] * tau[:, None, None] + phase[None]
    wave = (amp[None] * np.sin(arg)).sum(axis=1)
    envelope = np.sin(np.pi * tau / segment.duration_s)[:, None] ** 2
    if derivative == 0:
        return envelope * wave
    d_wave = (amp[None] * omega[None, :, None] * np.cos(arg)).sum(axis=1)
    d_envelope = (np.pi / segment.duration_s
                  * np.sin(2.0 * np.pi * tau / segment.duration_s))[:, None]
    return d_envelope * wave + envelope * d_wave


@dataclass(frozen=True)
class MotionPlan:
    """A free-motion plan: segments back to back from t = 0; after the last one the
    arm holds its final pose."""

    segments: tuple[Segment, ...]

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return the commanded (q [rad], dq [rad/s]), each (N, 7), at times ``t`` [s]."""
        t = np.asarray(t, dtype=float)
        last = self.segments[-1]
        q, dq = last.sample(np.full(t.shape, last.duration_s))
        for seg in self.segments:
            inside = (t >= seg.start_s) & (t < seg.start_s + seg.duration_s)
            if inside.any():
                q[inside], dq[inside] = seg.sample(t[inside] - seg.start_s)
        return q, dq

    def moving_intervals(self) -> list[tuple[float, float]]:
        """Return the (start, end) times [s] of the segments in which the arm moves."""
        return [(s.start_s, s.start_s + s.duration_s) for s in self.segments
                if s.kind != "hold"]

    def as_dict(self) -> dict:
        """Return the plan as JSON-ready values."""
        return asdict(self)


def free_motion_plan(rng: np.random.Generator, q_start: np.ndarray, duration_s: float,
                     limits: JointLimits, first_hold_s: float = 1.0) -> MotionPlan:
    """Draw a free-motion plan of ``duration_s`` [s] from ``q_start`` [rad].

    It starts with a hold of ``first_hold_s`` (the observer settles), then draws
    moves (45 %), multi-sine stretches (30 %) and holds (25 %, never two in a row).
    """
    lo = limits.q_min + LIMIT_MARGIN_RAD
    hi = limits.q_max - LIMIT_MARGIN_RAD
    q = np.clip(np.asarray(q_start, dtype=float), lo, hi)
    segments = [Segment("hold", 0.0, first_hold_s, tuple(q), tuple(q))]
    t = first_hold_s
    while t < duration_s:
        kinds = ("move", "sines") if segments[-1].kind == "hold" else KINDS
        weights = np.array([{"hold": 0.25, "move": 0.45, "sines": 0.3}[k] for k in kinds])
        kind = kinds[int(rng.choice(len(kinds), p=weights / weights.sum()))]
        if kind == "hold":
            seg = Segment("hold", t, float(rng.uniform(*HOLD_S)), tuple(q), tuple(q))
        elif kind == "move":
            seg = _move(rng, t, q, lo, hi, limits)
        else:
            seg = _sines_segment(rng, t, q, lo, hi, limits)
        segments.append(seg)
        q = np.array(seg.q_to)
        t += seg.duration_s
    return MotionPlan(tuple(segments))


def _move(rng: np.random.Generator, t: float, q: np.ndarray, lo: np.ndarray, hi: np.ndarray,
          limits: JointLimits) -> Segment:
    target = np.clip(q + rng.uniform(-MOVE_SPAN_RAD, MOVE_SPAN_RAD, q.size), lo, hi)
    distance = np.abs(target - q)
    fraction = rng.uniform(*SPEED_FRACTION)
    # Quintic: peak speed 1.875 d / T, peak acceleration 5.7735 d / T^2.
    duration = max(float(np.max(1.875 * distance / (fraction * limits.dq_max))),
                   float(np.sqrt(np.max(5.7735 * distance / (ACCEL_FRACTION * limits.ddq_max)))),
                   0.3)
    return Segment("move", t, duration, tuple(q), tuple(target))


def _sines_segment(rng: np.random.Generator, t: float, q: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray, limits: JointLimits) -> Segment:
    duration = float(rng.uniform(*SINES_S))
    freqs = np.sort(rng.uniform(*SINES_HZ, HARMONICS))
    phases = rng.uniform(0.0, 2.0 * np.pi, (HARMONICS, q.size))
    amps = rng.normal(0.0, 1.0, (HARMONICS, q.size)) / (2.0 * np.pi * freqs[:, None])
    trial = Segment("sines", t, duration, tuple(q), tuple(q), _rows(amps), tuple(freqs),
                    _rows(phases))
    grid = np.linspace(0.0, duration, 400)
    offset = _sines(trial, grid, 0)
    speed = _sines(trial, grid, 1)
    accel = np.gradient(speed, grid, axis=0)
    target = rng.uniform(*SPEED_FRACTION, q.size) * limits.dq_max
    scale = target / np.abs(speed).max(axis=0)
    scale = np.minimum(scale, ACCEL_FRACTION * limits.ddq_max / np.abs(accel).max(axis=0))
    room = np.minimum(hi - q, q - lo)
    reach = np.maximum(offset.max(axis=0), -offset.min(axis=0))
    scale = np.minimum(scale, np.maximum(room, 0.0) / reach)
    return Segment("sines", t, duration, tuple(q), tuple(q), _rows(amps * scale),
                   tuple(float(f) for f in freqs), _rows(phases))


def _rows(a: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(x) for x in row) for row in a)
