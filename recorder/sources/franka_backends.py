"""Read-only connections to a Franka robot: one class per client library.

Both backends open the robot through libfranka and only ever call its
``read_once()``, which blocks until the robot's next 1 kHz state; nothing here
commands the robot. ``pylibfranka`` (the official bindings) talks to an FR3 with
robot system 5.9 or newer; ``panda-python`` (``panda_py``, which bundles libfranka
0.9.2) talks to a Panda. Both return libfranka ``RobotState`` objects with the same
field names, so :func:`state_row` reads either.
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import Any, Protocol

import numpy as np

from contactkit.errors import ContactkitError, DependencyMissing, check_choice
from contactkit.schemas import InputError

BACKENDS = ("auto", "pylibfranka", "panda-python")
EXTRAS = {"pylibfranka": ("pylibfranka", "fr3"), "panda-python": ("panda_py", "panda")}
ROW_FIELDS = (("q", 7), ("dq", 7), ("tau_J", 7), ("q_d", 7), ("dq_d", 7),
              ("tau_ext_hat_filtered", 7), ("O_F_ext_hat_K", 6))
ROW_WIDTH = 1 + sum(n for _, n in ROW_FIELDS) + 2
"""Robot time [s], the joint and wrench fields, robot mode, command success rate."""


class ConnectionLost(RuntimeError):
    """The robot stopped answering (network error or libfranka timeout)."""


class Backend(Protocol):
    """An open, read-only connection to one robot."""

    name: str

    def read(self) -> Any:
        """Return the next libfranka ``RobotState`` (blocks up to 1 ms at 1 kHz); raise
        :class:`ConnectionLost` when the robot stops answering."""
        ...

    def describe(self) -> dict[str, Any]:
        """Return the client library and its version for the session metadata."""
        ...

    def close(self) -> None:
        """Close the connection."""
        ...


def state_row(state: Any, out: np.ndarray) -> None:
    """Write one libfranka ``RobotState`` into ``out`` (length :data:`ROW_WIDTH`): robot time
    [s], q [rad], dq [rad/s], tau_J [Nm], q_d, dq_d, tau_ext_hat_filtered [Nm],
    O_F_ext_hat_K [N, Nm], robot mode (as its integer) and command success rate [0..1]."""
    out[0] = state.time.to_sec()
    i = 1
    for name, n in ROW_FIELDS:
        out[i:i + n] = getattr(state, name)
        i += n
    mode = state.robot_mode
    out[i] = getattr(mode, "value", mode)
    out[i + 1] = state.control_command_success_rate


def _import(backend: str) -> Any:
    module, extra = EXTRAS[backend]
    try:
        return importlib.import_module(module)
    except ImportError as err:
        raise DependencyMissing(f"the franka source's {backend} backend needs the {module} "
                                f"module: pip install 'contactkit[{extra}]'") from err


def _version(distribution: str) -> str | None:
    import importlib.metadata  # some 35 ms, paid only where a backend is looked at

    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return None


class PylibfrankaBackend:
    """The official libfranka bindings (FR3, robot system 5.9 or newer)."""

    name = "pylibfranka"
    robot: Any = "fr3"  # the arm's name on the class; the libfranka robot when open

    def __init__(self, host: str, realtime_kernel: bool, module: Any = None) -> None:
        self.lib = module or _import(self.name)
        config = self.lib.RealtimeConfig.kEnforce if realtime_kernel else \
            self.lib.RealtimeConfig.kIgnore
        self.robot = self.lib.Robot(host, config)

    def read(self) -> Any:
        """Return the next robot state; raise ConnectionLost on a network error."""
        try:
            return self.robot.read_once()
        except self.lib.NetworkException as err:
            raise ConnectionLost(str(err).splitlines()[0]) from err

    def describe(self) -> dict[str, Any]:
        """Return the client library and its version."""
        return {"client": "pylibfranka", "client_version": _version("pylibfranka")}

    def close(self) -> None:
        """Drop the connection (libfranka closes it when the robot object goes)."""
        self.robot = None


class PandaPyBackend:
    """``panda_py`` (panda-python, bundling libfranka 0.9.2: the Panda's last release).

    Only its bare libfranka robot is opened (``panda_py.libfranka.Robot``), not a
    ``panda_py.Panda``, whose constructor configures the robot's collision behaviour.
    """

    name = "panda-python"
    robot: Any = "panda"  # the arm's name on the class; the libfranka robot when open

    def __init__(self, host: str, realtime_kernel: bool, module: Any = None) -> None:
        self.lib = module or _import(self.name)
        libfranka = self.lib.libfranka
        config = libfranka.RealtimeConfig.kEnforce if realtime_kernel else \
            libfranka.RealtimeConfig.kIgnore
        # libfranka's exceptions are std::runtime_error; this binding does not name them
        self.network_error = getattr(libfranka, "NetworkException", RuntimeError)
        self.robot = libfranka.Robot(host, realtime_config=config)
        self.server_version = int(self.robot.server_version())

    def read(self) -> Any:
        """Return the next robot state; raise ConnectionLost on a network error."""
        try:
            return self.robot.read_once()
        except self.network_error as err:
            raise ConnectionLost(str(err).splitlines()[0]) from err

    def describe(self) -> dict[str, Any]:
        """Return the client library, its version and the robot's FCI protocol version."""
        return {"client": "panda-python", "client_version": _version("panda-python"),
                "server_version": self.server_version}

    def close(self) -> None:
        """Drop the connection."""
        self.robot = None


BackendClass = type[PylibfrankaBackend] | type[PandaPyBackend]
BACKEND_CLASSES: dict[str, BackendClass] = {"pylibfranka": PylibfrankaBackend,
                                            "panda-python": PandaPyBackend}


def _installed(backend: str) -> bool:
    return importlib.util.find_spec(EXTRAS[backend][0]) is not None


def open_backend(host: str, backend: str, realtime_kernel: bool) -> Backend:
    """Connect to the robot at ``host`` with ``backend`` and return the connection.

    ``auto`` tries pylibfranka, then panda-python, among those installed: a Panda
    answers pylibfranka with an incompatible-version error, and panda-python is
    tried next. Raises InputError when no backend is installed or none connects.
    """
    check_choice("franka backend", backend, BACKENDS)
    if backend != "auto":
        return _connect(BACKEND_CLASSES[backend], host, realtime_kernel)
    candidates = [name for name in BACKEND_CLASSES if _installed(name)]
    if not candidates:
        raise DependencyMissing("the franka source needs pylibfranka (FR3: pip install "
                                "'contactkit[fr3]') or panda-python (Panda: pip install "
                                "'contactkit[panda]')")
    answers = []
    for name in candidates:
        try:
            return _connect(BACKEND_CLASSES[name], host, realtime_kernel)
        except ContactkitError as err:
            answers.append(f"{name}: {err}")
    raise InputError(f"no franka backend connects to {host}: " + "; ".join(answers))


def _connect(cls: BackendClass, host: str, realtime_kernel: bool) -> Backend:
    try:
        return cls(host, realtime_kernel)
    except ContactkitError:
        raise
    except Exception as err:  # libfranka raises its own exception types per binding
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise InputError(f"cannot connect to the robot at {host} with {cls.name}: "
                         f"{first}") from err
