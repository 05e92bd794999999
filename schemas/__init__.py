"""Arrow schemas, metadata model and validation shared by every contactkit stage.

Everything here depends on pyarrow only, so every other package may import it.
"""

from contactkit.errors import InputError
from contactkit.schemas.session import (
    ACTIONS,
    CONDITIONS,
    N_JOINTS,
    SCHEMA_VERSION,
    Session,
    SessionMeta,
    joint_columns,
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
