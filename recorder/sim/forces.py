"""External force profiles of a human hand, one per action, and where they act.

A contact is a force of fixed direction (world frame) applied at a point on one
link, whose magnitude follows the action's profile from the onset time. Shapes and
parameter ranges (before a person's strength and tempo multipliers, see
:class:`Persona`):

=======  ==============================  ===========  =============  ================
action   shape                           peak [N]     rise [s]       total [s]
=======  ==============================  ===========  =============  ================
none     no force                        0            -              -
bump     half-sine pulse                 8 - 30       0.025 - 0.075  0.05 - 0.15
adjust   raised-cosine rise, hold, fall  8 - 30       0.3 - 0.6      0.9 - 2.4
shove    fast raised-cosine rise, short  40 - 110     0.04 - 0.10    0.19 - 0.60
         hold, slower fall
=======  ==============================  ===========  =============  ================

Why these are plausible for a hand: a bump is an accidental brush or knock that
ends as soon as the hand notices it, so it is short (tens of ms, the duration of
a transient impact) and light. An adjust is a deliberate, gentle guide: people
ramp a guiding force over a few hundred ms and hold it for about a second at the
level of a comfortable push (10-30 N, what pressing a door handle takes). A shove
is a vigorous arm push meant to stop the robot: voluntary push forces of standing
adults reach 100-200 N, and the rise of a ballistic push is under 100 ms; we stay
below the 140 N quasi-static limit ISO/TS 15066 gives for the hand. The thesis
tuned its profiles by eye against observer estimates (its Figure 5.3); these
ranges cover the same magnitudes and shapes.

Beyond the thesis (which only pushed the end link horizontally), the force acts on
any link 1-7, at a point on the link's surface (its collision mesh from the URDF),
in any 3-D direction that pushes into that surface, and each simulated person has
their own strength and tempo.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import cast

import numpy as np
import pyarrow as pa

from contactkit.errors import InputError
from contactkit.recorder.protocol import MAX_ONSET_DELAY_S
from contactkit.robots.model import RobotModel
from contactkit.robots.surfaces import LinkSurface, link_surface
from contactkit.schemas import Session, joint_columns

Vec3 = tuple[float, float, float]

PROFILE_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "bump": {"peak_n": (8.0, 30.0), "rise_s": (0.025, 0.075)},
    "adjust": {"peak_n": (8.0, 30.0), "rise_s": (0.3, 0.6), "hold_s": (0.3, 1.2),
               "fall_s": (0.3, 0.6)},
    "shove": {"peak_n": (40.0, 110.0), "rise_s": (0.04, 0.10), "hold_s": (0.05, 0.2),
              "fall_s": (0.1, 0.3)},
}


@dataclass(frozen=True)
class Persona:
    """A simulated person: multipliers on peak force (strength) and on durations (tempo)."""

    name: str
    strength: float
    tempo: float

    @classmethod
    def from_name(cls, name: str, variability: float = 1.0) -> Persona:
        """Return the persona of an operator name (deterministic: the same name always
        gives the same person). ``variability`` scales the spread between people."""
        seed = int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little")
        rng = np.random.default_rng(seed)
        return cls(name=name,
                   strength=float(np.exp(rng.normal(0.0, 0.25 * variability))),
                   tempo=float(np.exp(rng.normal(0.0, 0.2 * variability))))


@dataclass(frozen=True)
class Contact:
    """One applied force: profile parameters, onset [s], link, point and direction.

    ``point_local`` is in the link frame [m]; ``direction`` is a unit vector in the
    world frame. ``peak_n`` [N]; ``rise_s``, ``hold_s``, ``fall_s`` [s].
    """

    action: str
    onset_s: float
    link: int
    point_local: tuple[float, float, float]
    direction: tuple[float, float, float]
    peak_n: float
    rise_s: float
    hold_s: float = 0.0
    fall_s: float = 0.0

    @property
    def duration_s(self) -> float:
        """Time [s] from onset until the force is back to zero."""
        if self.action == "bump":
            return 2.0 * self.rise_s
        return self.rise_s + self.hold_s + self.fall_s

    def magnitude(self, t: np.ndarray | float) -> np.ndarray:
        """Return the force magnitude [N] at times ``t`` [s] (session time)."""
        tau = np.asarray(t, dtype=float) - self.onset_s
        out = np.zeros_like(tau)
        if self.action == "bump":
            inside = (tau >= 0) & (tau <= 2 * self.rise_s)
            out[inside] = self.peak_n * np.sin(np.pi * tau[inside] / (2 * self.rise_s))
            return out
        up = (tau >= 0) & (tau < self.rise_s)
        out[up] = self.peak_n * 0.5 * (1 - np.cos(np.pi * tau[up] / self.rise_s))
        hold = (tau >= self.rise_s) & (tau < self.rise_s + self.hold_s)
        out[hold] = self.peak_n
        t_fall = tau - self.rise_s - self.hold_s
        down = (t_fall >= 0) & (t_fall < self.fall_s)
        out[down] = self.peak_n * 0.5 * (1 + np.cos(np.pi * t_fall[down] / self.fall_s))
        return out

    def as_dict(self) -> dict:
        """Return the contact as plain JSON-ready values (for session metadata)."""
        return asdict(self)


MAX_DIRECTION_DRAWS = 100


def sample_contact(rng: np.random.Generator, action: str, planned_at_s: float, link: int,
                   surface: LinkSurface, link_rotation: np.ndarray,
                   persona: Persona) -> Contact | None:
    """Draw one contact for ``action`` (None for ``none``).

    The onset is the planned time plus U(0, 0.25) s. The direction is uniform on
    the sphere (world frame); the point is drawn, area-weighted, on the faces of the
    link's collision mesh that the force pushes into (outward normal at least 45
    degrees against the force). ``link_rotation`` is the link's world orientation at
    the start of the session.
    """
    if action == "none":
        return None
    if surface.empty:
        raise InputError(f"link {link} has no collision mesh to touch (a mesh the URDF "
                         "names could not be read, or it has none)")
    ranges = PROFILE_RANGES[action]
    draw = {k: float(rng.uniform(*v)) for k, v in ranges.items()}
    for _ in range(MAX_DIRECTION_DRAWS):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        facing = surface.normals @ (link_rotation.T @ direction) < -np.sqrt(0.5)
        weights = surface.areas * facing
        if weights.sum() > 0:
            break
        # a coarse collision mesh has no face within 45 degrees of some directions:
        # a hand cannot push into the link that way, so draw another direction
    else:
        raise ValueError(f"no face of link {link}'s collision mesh faces any drawn direction")
    _, point = surface_point(rng, surface, weights)
    return Contact(
        action=action,
        onset_s=planned_at_s + float(rng.uniform(0.0, MAX_ONSET_DELAY_S)),
        link=link,
        point_local=cast(Vec3, tuple(float(x) for x in point)),
        direction=cast(Vec3, tuple(float(x) for x in direction)),
        peak_n=draw["peak_n"] * persona.strength,
        rise_s=draw["rise_s"] * persona.tempo,
        hold_s=draw.get("hold_s", 0.0) * persona.tempo,
        fall_s=draw.get("fall_s", 0.0) * persona.tempo,
    )


def surface_point(rng: np.random.Generator, surface: LinkSurface, weights: np.ndarray
                  ) -> tuple[int, np.ndarray]:
    """Draw a face of ``surface`` with probability proportional to ``weights`` (one per
    face, e.g. its area) and a point uniform on it; return the face's index and the
    point [m] in the link frame."""
    face = int(rng.choice(len(weights), p=weights / weights.sum()))
    a, b = rng.random(2)
    if a + b > 1.0:
        a, b = 1.0 - a, 1.0 - b
    tri = surface.vertices[face]
    return face, tri[0] + a * (tri[1] - tri[0]) + b * (tri[2] - tri[0])


def inward_push(rng: np.random.Generator, surface: LinkSurface, spread: float = 0.4,
                max_angle_deg: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """Draw a well-conditioned push: a point uniform on ``surface`` (area-weighted) and a
    unit direction (link frame) along the face's inward normal, perturbed by ``spread``
    times a normal draw and at most ``max_angle_deg`` [deg] off the normal (drawn again
    until it is); return (point [m], direction), both in the link frame."""
    while True:
        face, point = surface_point(rng, surface, surface.areas)
        inward = -surface.normals[face]
        direction = inward + spread * rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        if direction @ inward >= np.cos(np.radians(max_angle_deg)):
            return point, direction


def contact_torque(model: RobotModel, t: np.ndarray, q: np.ndarray, contact: Contact
                   ) -> np.ndarray:
    """Return the joint torque [Nm] (N, 7) that ``contact`` applies to an arm moving
    through ``q`` [rad] (N, 7) at times ``t`` [s] (N,): J_k(q, p)^T F at the contact's
    point on its link, zero where its force is.

    Subtracted from a recording's measured torque (the motors hold the arm against the
    push), it makes a synthetic touch on real data: the residual then shows J^T F on
    top of the recording's own noise and model error.
    """
    magnitude = contact.magnitude(t)
    out = np.zeros((len(t), q.shape[1]))
    direction = np.array(contact.direction)
    point = np.array(contact.point_local)
    for k in np.flatnonzero(magnitude > 0):
        jac = model.point_jacobian(q[k], contact.link, point)
        out[k] = jac[:3].T @ (magnitude[k] * direction)
    return out


def add_synthetic_touches(session: Session, rng: np.random.Generator,
                          onsets_s: Sequence[float]) -> tuple[Session, list[Contact]]:
    """Return a copy of ``session`` (its complete samples) with a synthetic touch planned
    at each of ``onsets_s`` [s], and the touches.

    Each touch is drawn as the simulator draws one (a random link 1-7, bump, adjust or
    shove, a point of the link's collision surface and a direction that pushes into it,
    :func:`sample_contact`), and its joint torque (:func:`contact_torque`) is subtracted
    from the measured torque, as the motors of a stiffly held arm push back: a check of
    a detector on a real robot's free-motion recording with touches whose truth is known.
    """
    session = session.complete()
    robot = session.meta.robot_setup(session.path)
    model = RobotModel(robot)
    tau = session.tau.copy()
    contacts: list[Contact] = []
    for at in onsets_s:
        link = int(rng.integers(1, 8))
        action = ("bump", "adjust", "shove")[int(rng.integers(3))]
        rotation = model.frame_placement(session.q[np.searchsorted(session.t, at)],
                                         link).rotation
        contact = sample_contact(rng, action, at, link, link_surface(robot, link), rotation,
                                 Persona("synthetic", 1.0, 1.0))
        assert contact is not None  # a touch's action is never "none"
        tau -= contact_torque(model, session.t, session.q, contact)
        contacts.append(contact)
    table = session.table
    for j, name in enumerate(joint_columns("tau")):
        table = table.set_column(table.column_names.index(name), name, pa.array(tau[:, j]))
    return Session(session.meta, table, None), contacts
