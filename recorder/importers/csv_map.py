"""CSV column maps: which columns of a lab's CSV export hold one sample (a small TOML file).

A map names the ``time`` column and its unit, the seven columns of each joint
quantity (``q``, ``dq``, ``tau`` required; ``q_d``, ``dq_d``, ``tau_ext_hat``
optional) either as a template with ``{j}`` for the joint index (counted from
``index_base``, 0 or 1) or as a list of seven names, their unit, a ``sign`` for
``tau_ext_hat`` (+1 when the column is libfranka's ``tau_ext_hat_filtered``, whose
sign is opposite to the momentum-observer residual; -1 when it is not), an optional
per-sample ``contact`` label column, and whether rows that repeat the previous row's
measured values are dropped. ``recorder/data/mindlab_csv_map.toml`` is the example.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from contactkit.recorder.importers.map_file import known_keys, load_map_file, one_of
from contactkit.robots import canonical_robot_name
from contactkit.schemas import N_JOINTS

# Unit name -> factor to the session's unit (s, rad, rad/s, Nm).
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
ANGLE_UNITS = {"rad": 1.0, "deg": 0.017453292519943295}
JOINT_UNITS = {
    "q": ANGLE_UNITS,
    "q_d": ANGLE_UNITS,
    "dq": {"rad/s": 1.0, "deg/s": ANGLE_UNITS["deg"]},
    "dq_d": {"rad/s": 1.0, "deg/s": ANGLE_UNITS["deg"]},
    "tau": {"Nm": 1.0, "mNm": 1e-3},
    "tau_ext_hat": {"Nm": 1.0, "mNm": 1e-3},
}
REQUIRED = ("q", "dq", "tau")
OPTIONAL = ("q_d", "dq_d", "tau_ext_hat")
KNOWN_KEYS = {"name", "robot", "delimiter", "index_base", "time", "contact", "repeated_rows",
              *REQUIRED, *OPTIONAL}


@dataclass(frozen=True)
class JointColumns:
    """The seven CSV columns of one joint quantity and the factor to session units."""

    names: tuple[str, ...]
    factor: float


@dataclass(frozen=True)
class CsvMap:
    """A parsed CSV column map.

    ``joints`` maps a session prefix (q, dq, tau, ...) to its CSV columns; ``time_factor``
    converts the time column to s; ``contact`` is the label column (None without one),
    whose nonzero values mean the person touches the arm; ``robot`` the arm the exports
    come from (a registry name, :mod:`contactkit.robots`; None: not said).
    """

    name: str
    delimiter: str
    time_column: str
    time_factor: float
    joints: dict[str, JointColumns]
    contact: str | None
    drop_repeated_rows: bool
    source: str
    robot: str | None = None

    def measured_columns(self) -> list[str]:
        """Return the CSV columns whose values define a repeated row (q, dq, tau)."""
        return [name for prefix in REQUIRED for name in self.joints[prefix].names]

    def describe(self) -> dict:
        """Return a JSON-ready description for session metadata."""
        return {"name": self.name, "source": self.source, "time": self.time_column,
                "columns": {p: list(c.names) for p, c in self.joints.items()},
                "contact": self.contact, "drop_repeated_rows": self.drop_repeated_rows}


def mindlab_map_path() -> Path:
    """Return the path of the shipped map for the MindLab ZHAW labelled CSV files."""
    return Path(str(resources.files("contactkit.recorder").joinpath(
        "data/mindlab_csv_map.toml")))


def load_csv_map(path: str | Path) -> CsvMap:
    """Parse and check a CSV column map; raise InputError naming the file and the problem."""
    return load_map_file(Path(path), "column map", _parse)


def _parse(doc: dict, source: str) -> CsvMap:
    known_keys(doc, KNOWN_KEYS, "the map")
    base = one_of(doc.get("index_base", 1), (0, 1), "index_base")
    time = known_keys(doc["time"], ("column", "unit"), "[time]", required=("column",))
    time_unit = one_of(time.get("unit", "s"), TIME_UNITS, "time unit")
    joints = {}
    for prefix in (*REQUIRED, *OPTIONAL):
        if prefix in doc:
            joints[prefix] = _joint_columns(prefix, doc[prefix], base)
        elif prefix in REQUIRED:
            raise ValueError(f"no columns for {prefix}")
    contact = doc.get("contact")
    if contact is not None:
        contact = str(known_keys(contact, ("column",), "[contact]", ("column",))["column"])
    delimiter = doc.get("delimiter", ",")
    if not (isinstance(delimiter, str) and len(delimiter.encode()) == 1
            and delimiter not in "\"\r\n"):
        raise ValueError(f"delimiter must be one single-byte character other than a quote "
                         f"or a line break, got {str(delimiter)[:20]!r}")
    repeated = one_of(doc.get("repeated_rows", "drop"), ("drop", "keep"), "repeated_rows")
    robot = doc.get("robot")
    return CsvMap(str(doc.get("name", Path(source).stem)), delimiter, str(time["column"]),
                  TIME_UNITS[time_unit], joints, contact, repeated == "drop", source,
                  None if robot is None else canonical_robot_name(str(robot)))


def _joint_columns(prefix: str, spec: dict, base: int) -> JointColumns:
    known_keys(spec, ("columns", "unit", "sign"), f"[{prefix}]", required=("columns",))
    columns = spec["columns"]
    if isinstance(columns, str):
        if "{j}" not in columns:
            raise ValueError(f"{prefix} columns template {columns!r} lacks {{j}}")
        names = tuple(columns.replace("{j}", str(j + base)) for j in range(N_JOINTS))
    else:
        if not (isinstance(columns, list) and all(isinstance(c, str) for c in columns)):
            raise ValueError(f"{prefix} columns must be a template or a list of names")
        names = tuple(columns)
        if len(names) != N_JOINTS:
            raise ValueError(f"{prefix} needs {N_JOINTS} columns, found {len(names)}")
    if len(set(names)) != len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise ValueError(f"{prefix} columns name {twice[:80]!r} more than once")
    units = JOINT_UNITS[prefix]
    unit = one_of(spec.get("unit", next(iter(units))), units, f"{prefix} unit")
    sign = one_of(spec.get("sign", 1), (1, -1) if prefix == "tau_ext_hat" else (1,),
                  f"{prefix} sign")
    return JointColumns(names, units[unit] * sign)
