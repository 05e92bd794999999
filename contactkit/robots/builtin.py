"""The built-in robots: the Franka Emika Panda and the Franka Research 3 (FR3).

``panda``
    example-robot-data's Panda URDF (BSD-3-Clause, installed with the package, not
    copied into this one), whose link inertial parameters are the feasible
    parameters identified by Gaz et al. (IEEE RA-L 2019), with their friction model.
``fr3``
    Franka's own description (``frankaemika/franka_description``, Apache-2.0),
    turned into a plain URDF once by ``tools/make_fr3_urdf.py`` and shipped in
    ``contactkit/robots/data/fr3`` with its licence, notice and provenance. Its
    kinematics equal the Panda's; its link masses and inertias, joint limits and
    velocity limits differ. No friction model has been identified for it: on the real
    FR3 recordings the residual matches the robot's own estimate without one, and a
    Coulomb and viscous friction fitted on one recording, though it lowers the other's
    residual, takes it away from that estimate (docs/identification.md).

Acceleration and jerk limits come from each arm's datasheet (Franka's "Robot and
interface specifications" of the Panda and of the FR3; the Panda's are also libfranka's
rate limiter's ``kMaxJointAcceleration`` and ``kMaxJointJerk``); the torque-rate limit
(1000 Nm/s) is both arms'.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from contactkit.robots.spec import FrictionModel, RobotSpec

_PANDA_URDF = ("cmeel.prefix/share/example-robot-data/robots/panda_description/urdf/"
               "panda.urdf")
DATA = Path(__file__).resolve().parent / "data"
PANDA_DDQ_MAX = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)  # rad/s^2, Panda datasheet
FR3_DDQ_MAX = (10.0,) * 7  # rad/s^2, FR3 (libfranka's rate limiter since 2022)
# Joint jerk limits [rad/s^3]: the Panda's from its datasheet, as libfranka's
# include/franka/rate_limiting.h has them (kMaxJointJerk); the FR3's from its datasheet
# (Franka's FR3 "Robot and interface specifications", joint-space limits).
PANDA_JERK_MAX = (7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0)
FR3_JERK_MAX = (5000.0,) * 7
DTAU_MAX = (1000.0,) * 7  # Nm/s, both
# The motors' rotor inertia reflected through the gears [kg m^2], which the simulator puts
# on the plant side of the torque sensors (see contactkit.recorder.sim.simulator).
ARMATURE_KGM2 = (0.1, 0.1, 0.1, 0.1, 0.0, 0.0, 0.0)

# How a contact detector calibrated on the simulated Panda (the default model's) is
# adapted to a real FR3. Its wrist joints keep static-friction offsets that move by up
# to 0.5 Nm as the arm stops and starts (the robot's own estimate shows the same: 0.54
# Nm on joints 5-6 near rest, where the Panda's stays within 0.10), so their at-rest
# thresholds sit at 0.5 Nm; and its model error in motion (the robot's own estimate
# reaches 2.3 Nm on joint 1 at 0.6 rad/s) is larger than the simulated Panda's, so the
# growth with speed, acceleration and dynamic torque is 1.5 times the calibrated one.
# Chosen on the two real FR3 recordings in ../shared with the detector before its
# dynamic-torque term (0 events with them; 1.25 was the least scale that gave 0, 1.5
# leaves a margin); with the term their peak score is 0.83-0.85 of the threshold.
# docs/results.md ("On a real FR3") has the figures.
FR3_DETECTOR_FLOOR_NM = (0.3, 0.3, 0.3, 0.3, 0.5, 0.5, 0.5)
FR3_DETECTOR_MOTION_SCALE = 1.5

GAZ_FRICTION = FrictionModel(
    phi1=np.array([0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489]),
    phi2=np.array([5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336]),
    phi3=np.array([0.039533, 0.025882, -0.04607, 0.036194, 0.026226, -0.021047, 0.0035526]),
)
"""The Panda's joint friction identified by Gaz et al. 2019 (parameters per joint)."""


def panda_urdf_path() -> Path:
    """Return the path of the Panda URDF shipped by example-robot-data."""
    import importlib.metadata  # some 35 ms, paid only where the URDF is read

    dist = importlib.metadata.distribution("example-robot-data")
    return Path(str(dist.locate_file(_PANDA_URDF)))


def fr3_urdf_path() -> Path:
    """Return the path of the FR3 URDF (with the Franka Hand) shipped in this package."""
    return DATA / "fr3" / "fr3_hand.urdf"


def _franka(prefix: str, ddq_max: tuple[float, ...], jerk_max: tuple[float, ...]
            ) -> dict[str, Any]:
    return {
        "joint_names": tuple(f"{prefix}_joint{i}" for i in range(1, 8)),
        "link_frames": tuple(f"{prefix}_link{i}" for i in range(1, 8)),
        "flange": f"{prefix}_link8",
        "tcp": f"{prefix}_hand_tcp",
        "hand_frame": f"{prefix}_hand",
        "hand_links": (f"{prefix}_hand", f"{prefix}_leftfinger", f"{prefix}_rightfinger",
                       f"{prefix}_hand_tcp"),
        "ddq_max": ddq_max,
        "jerk_max": jerk_max,
        "dtau_max": DTAU_MAX,
        "armature_kgm2": ARMATURE_KGM2,
    }


PANDA = RobotSpec(
    name="panda",
    description="Franka Emika Panda (example-robot-data URDF, Gaz et al. 2019 parameters)",
    urdf_file=panda_urdf_path,
    friction=GAZ_FRICTION,
    provenance="example-robot-data (BSD-3-Clause): robots/panda_description/urdf/panda.urdf",
    aliases=("franka_panda",),
    **_franka("panda", PANDA_DDQ_MAX, PANDA_JERK_MAX),
)

FR3 = RobotSpec(
    name="fr3",
    description="Franka Research 3 (franka_description URDF)",
    urdf_file=fr3_urdf_path,
    friction=None,
    detector_floor_nm=FR3_DETECTOR_FLOOR_NM,
    detector_motion_scale=FR3_DETECTOR_MOTION_SCALE,
    provenance="frankaemika/franka_description (Apache-2.0), see "
               "contactkit/robots/data/fr3/PROVENANCE.md",
    aliases=("franka_fr3", "franka_research_3"),
    **_franka("fr3", FR3_DDQ_MAX, FR3_JERK_MAX),
)

BUILTIN = (PANDA, FR3)
