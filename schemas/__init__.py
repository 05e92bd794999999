"""Arrow schemas, metadata model and validation shared by every contactkit stage: a
session's columns (:mod:`.columns`), its metadata (:mod:`.metadata`) and its file
(:mod:`.session`), the dataset index (:mod:`.dataset`) and feature tables
(:mod:`.features`).

Everything here depends on pyarrow, numpy and the robot registry (names, limits: no
pinocchio), so every other package may import it.
"""

from contactkit.errors import InputError
from contactkit.robots.spec import N_JOINTS
from contactkit.schemas.columns import joint_columns
from contactkit.schemas.metadata import ACTIONS, CONDITIONS, SCHEMA_VERSION, SessionMeta
from contactkit.schemas.session import (
    Session,
    new_session_id,
    read_session,
    read_session_meta,
    validate_session,
    write_session,
)

__all__ = [
    "ACTIONS",
    "CONDITIONS",
    "N_JOINTS",
    "SCHEMA_VERSION",
    "InputError",
    "Session",
    "SessionMeta",
    "joint_columns",
    "new_session_id",
    "read_session",
    "read_session_meta",
    "validate_session",
    "write_session",
]
