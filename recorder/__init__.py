"""Recording: where sessions come from and what is said about them.

Subpackages, one job each:

* :mod:`~contactkit.recorder.sim`: the simulated arm (dynamics, touches, motion, noise)
  and simulated datasets;
* :mod:`~contactkit.recorder.sources`: live sources by name (simulated arm, CAN, Franka);
* :mod:`~contactkit.recorder.capture`: the capture loop, the crash-safe journal and the
  live view;
* :mod:`~contactkit.recorder.importers`: readers of other formats (arrays, CSV, ROS bags,
  CAN logs) into sessions, and the MCAP exporter;
* :mod:`~contactkit.recorder.stats`: dataset statistics and their report.

Beside them, :mod:`~contactkit.recorder.protocol` (poses, actions, timing),
:mod:`~contactkit.recorder.metadata` (building a session's metadata),
:mod:`~contactkit.recorder.info` (one session's summary),
:mod:`~contactkit.recorder.trajectory` (joint trajectory files: written, read, checked)
and :mod:`~contactkit.recorder.excitation` (exciting trajectories to identify an arm
from).
"""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
__all__ = ["capture", "excitation", "importers", "info", "metadata", "protocol", "sim",
           "sources", "stats", "trajectory"]
