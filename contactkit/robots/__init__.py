"""Robot models, chosen per session: the Panda, the FR3, plugins and ``urdf:PATH``.

The bottom of the layering beside :mod:`contactkit.util`: the simulator, the
feature chain, the detector, the viewer and the readers all ask here which arm a
session was recorded on. This package's top level loads without pinocchio (names,
limits, the registry); the dynamics are in :mod:`contactkit.robots.model` and the
collision surfaces in :mod:`contactkit.robots.surfaces`.
"""

from __future__ import annotations

from contactkit.robots.builtin import FR3, GAZ_FRICTION, PANDA
from contactkit.robots.registry import (
    DEFAULT_ROBOT,
    ENTRY_POINT_GROUP,
    URDF_PREFIX,
    canonical_robot_name,
    get_robot,
    robot_names,
    urdf_robot,
)
from contactkit.robots.spec import (
    N_JOINTS,
    ArmDynamics,
    FrictionModel,
    JointLimits,
    RobotSetup,
    RobotSpec,
)

__all__ = [
    "DEFAULT_ROBOT",
    "ENTRY_POINT_GROUP",
    "FR3",
    "GAZ_FRICTION",
    "N_JOINTS",
    "PANDA",
    "URDF_PREFIX",
    "ArmDynamics",
    "FrictionModel",
    "JointLimits",
    "RobotSetup",
    "RobotSpec",
    "canonical_robot_name",
    "get_robot",
    "robot_names",
    "urdf_robot",
]
