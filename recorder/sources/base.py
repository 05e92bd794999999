"""The protocol every data source implements."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Protocol

import numpy as np


class Source(Protocol):
    """A stream of samples of one session in session-file columns.

    ``columns`` lists the columns the source produces. ``live`` is true when the
    source is paced by the world (a robot or a bus); a simulated source is not, and
    the capture loop paces it in ``--realtime`` mode. ``metadata()`` returns the
    fields this source contributes to the session metadata (``source``,
    ``simulator``, ``source_info``...), and may be called again after the stream
    ends to report statistics.
    """

    name: str
    columns: list[str]
    live: bool

    def stream(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield chunks of rows (dict of equal-length arrays, ``t`` in s, increasing)."""
        ...

    def metadata(self) -> dict[str, Any]:
        """Return the session-metadata fields this source contributes."""
        ...
