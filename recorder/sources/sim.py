"""The simulated Panda as a capture source."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from contactkit.recorder.sim import PandaSimulator, SessionSpec, SimConfig
from contactkit.schemas import joint_columns

SIM_COLUMNS = ["t", *joint_columns("q"), *joint_columns("dq"), *joint_columns("tau"),
               *joint_columns("q_d"), *joint_columns("dq_d"), "f_ext_x", "f_ext_y", "f_ext_z",
               "contact"]


class SimSource:
    """One simulated session, streamed in chunks of ``chunk`` samples."""

    name = "sim"
    columns = SIM_COLUMNS
    live = False

    def __init__(self, spec: SessionSpec, config: SimConfig, chunk: int = 10) -> None:
        self.spec = spec
        self.config = config
        self.chunk = chunk

    def stream(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield the session's rows, ``chunk`` samples at a time."""
        for _, columns, _ in PandaSimulator(self.config).run([self.spec], chunk=self.chunk):
            yield columns

    def metadata(self) -> dict[str, Any]:
        """Return source, simulator parameters and seed for the session metadata."""
        return {"source": self.name,
                "simulator": {"seed": self.spec.seed, "config": self.config.to_dict(),
                              "session": self.spec.as_dict()}}
