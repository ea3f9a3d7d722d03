"""The columns of the recordings CSV (``formats.md`` §2), as one table of data.

Every place that reads, writes or names a recordings column takes the names, units and
rules from :data:`GROUPS`: the loader (:mod:`cstiffjax.io.recordings`), the writer, the
generators, the commands, the residual channels of the fits and the labels of the
diagnosis. One :class:`Group` is one row of the contract's table (``fx fy fz``,
``l0_1 … l0_m``); a per-cable group names its columns with the pattern ``{i}`` (the
1-based cable index). Whatever is not a contract column is a numeric covariate
(:data:`COVARIATES`).

A later contract version adds an optional column by appending a :class:`Group` with
``since`` set to that version (version 3: ``session``, per-cable ``swivel_{i}``, the AHRS's
``roll pitch yaw``, each filling a :class:`~cstiffjax.io.recordings.Recordings` field named by
``field``) or makes one optional by emptying its ``required`` (version 3: ``x y z`` and, on a
CDPR, ``rx ry rz``). ``t_set_{i}`` (tension set-points, version 3) are covariates whose names
the loader checks (:data:`SETPOINT`). Groups that share a
``field`` fill that field's columns in table order (``pose`` = position + rotation).
"""

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

CONTRACT_VERSION = 3
"""Version of the data contracts (``formats.md``) this table follows."""

KINDS = ("cdpr", "csjm")
"""Robot kinds (``kind`` of the robot description, formats.md §1)."""

CABLE = "{i}"
"""Placeholder of the 1-based cable index in a per-cable column pattern."""


@dataclass(frozen=True)
class Group:
    """One row of the contract's column table: columns with one unit, meaning and rule.

    **Fields:**

    - ``key``: short name of the group (``"l0"``, ``"force"``).
    - ``names``: the header names, in the order they fill ``field``; a per-cable group has
      one pattern with :data:`CABLE` (``("l0_{i}",)``).
    - ``unit``: SI unit of the values.
    - ``quantity``: what a value is, in a few words (messages, channel labels).
    - ``meaning``: the contract's description of the columns.
    - ``field``: the :class:`~cstiffjax.io.recordings.Recordings` field the columns fill.
    - ``role``: ``"input"`` (what a model is given) or ``"measurement"`` (what it predicts).
    - ``required``: the robot kinds whose recordings must have these columns.
    - ``used``: the robot kinds whose recordings take the values; for the others the columns
      are checked like any optional column and the field holds zeros.
    - ``absent``: the value when the file has no such column (``nan``: not recorded).
    - ``empty_ok``: an empty cell is a value not recorded (masked out), not an error.
    - ``positive``: values must be > 0 (for the kinds in ``used``).
    - ``integer``: values must be whole numbers.
    - ``together``: a file has all of the group's columns or none of them.
    - ``since``: the contract version that added the group.
    """

    key: str
    names: tuple[str, ...]
    unit: str
    quantity: str
    meaning: str
    field: str
    role: str
    required: tuple[str, ...] = ()
    used: tuple[str, ...] = KINDS
    absent: float = 0.0
    empty_ok: bool = False
    positive: bool = False
    integer: bool = False
    together: bool = False
    since: int = 1

    @property
    def per_cable(self) -> bool:
        """Whether the group has one column per cable (``l0_1 … l0_m``)."""
        return CABLE in self.names[0]

    @property
    def prefix(self) -> str:
        """The name before ``_{i}`` of a per-cable group (``"l0"``); ``""`` otherwise."""
        return self.names[0].split("_" + CABLE)[0] if self.per_cable else ""

    def columns(self, m: int) -> tuple[str, ...]:
        """The header names for a robot with ``m`` cables."""
        if self.per_cable:
            return tuple(self.names[0].replace(CABLE, str(i)) for i in range(1, m + 1))
        return self.names


NAN = float("nan")
GROUPS: tuple[Group, ...] = (
    Group("session", ("session",), "", "session",
          "integer id of a recording session: its own clock, length zeros and AHRS yaw zero (reported under "
          "this id, e.g. `yaw_zero[session 9]`)", "session",
          "input", integer=True, since=3),
    Group("time", ("time",), "s", "time", "s since the start of the session", "time", "input", absent=NAN),
    Group("l0", ("l0_" + CABLE,), "m", "commanded unstrained length",
          "commanded unstrained cable length from the exit point to the attachment", "l0", "input",
          required=("cdpr",), used=("cdpr",), positive=True),
    Group("force", ("fx", "fy", "fz"), "N", "external force",
          "external force on the platform, base frame, platform weight excluded", "wrench", "input"),
    Group("moment", ("mx", "my", "mz"), "N·m", "external moment",
          "external moment about the platform reference point, base frame", "wrench", "input"),
    Group("position", ("x", "y", "z"), "m", "position",
          "measured position of the platform reference point, base frame", "pose", "measurement",
          used=("cdpr",), absent=NAN, together=True),
    Group("rotation", ("rx", "ry", "rz"), "rad", "orientation",
          "measured orientation as a rotation vector (axis × angle), base frame", "pose", "measurement",
          required=("csjm",), absent=NAN, together=True),
    Group("tension", ("t_" + CABLE,), "N", "tension", "measured cable tension at the exit point (winch side)",
          "tensions", "measurement", absent=NAN, empty_ok=True),
    Group("joint_moment", ("tx", "ty", "tz"), "N·m", "moment about O",
          "measured moment on the platform about O, platform frame", "moment", "measurement",
          required=("csjm",)),
    Group("swivel", ("swivel_" + CABLE,), "rad", "swivel angle",
          "measured swivel angle of the cable's pulley about pulley_axis, from swivel_zero", "swivel",
          "measurement", used=("cdpr",), absent=NAN, empty_ok=True, since=3),
    Group("ahrs", ("roll", "pitch", "yaw"), "rad", "AHRS angle",
          "AHRS orientation, Z-Y-X Euler angles; yaw from an unknown zero per session", "ahrs", "measurement",
          used=("cdpr",), absent=NAN, together=True, since=3),
)
"""The contract's columns, in the order of its table (and of the files the writer makes)."""

SETPOINT = "t_set_" + CABLE
"""Per-cable tension set-point column (version 3, N): a covariate of the diagnosis whose
cable index must name one of the robot's cables."""

POSE_CHANNELS = ("position", "rotation", "tension", "swivel", "ahrs")
"""The measurement groups that constrain a CDPR's pose: a recordings file needs one of them."""

COVARIATES = "covariates"
"""The :class:`~cstiffjax.io.recordings.Recordings` field of every other numeric column
(temperature, humidity, …: carried into the diagnosis so a mismatch can be tied to it)."""

FIELDS: tuple[str, ...] = tuple(dict.fromkeys(g.field for g in GROUPS))
"""The :class:`~cstiffjax.io.recordings.Recordings` fields the contract columns fill."""


def group(key: str) -> Group:
    """The group named ``key`` (``KeyError`` lists the keys)."""
    for g in GROUPS:
        if g.key == key:
            return g
    raise KeyError(f"no column group {key!r}; groups: {[g.key for g in GROUPS]}")


def column_names(m: int, groups=GROUPS) -> tuple[str, ...]:
    """Every contract column name for ``m`` cables (of ``groups``), in table order."""
    return tuple(name for g in groups for name in g.columns(m))


def required_columns(kind: str, m: int) -> tuple[str, ...]:
    """The columns a recordings file of a ``kind`` robot with ``m`` cables must have."""
    return column_names(m, [g for g in GROUPS if kind in g.required])


def field_columns(field: str, m: int) -> tuple[str, ...]:
    """The names of the columns of the Recordings field ``field``, in its column order
    (``field_columns("pose", m) == ("x", "y", "z", "rx", "ry", "rz")``)."""
    if field not in FIELDS:
        raise KeyError(f"no recordings field {field!r} with contract columns; fields: {list(FIELDS)}")
    return column_names(m, [g for g in GROUPS if g.field == field])


def fixed_names() -> tuple[str, ...]:
    """The names of the groups that are not per cable (``time``, ``fx``, …, ``tz``)."""
    return tuple(name for g in GROUPS if not g.per_cable for name in g.names)


def cable_prefixes() -> tuple[str, ...]:
    """The prefixes of the per-cable columns (``"l0"``, ``"t"``)."""
    return tuple(g.prefix for g in GROUPS if g.per_cable)


def cable_column(prefix: str, i: int | str) -> str:
    """The per-cable column ``prefix`` of cable ``i`` (1-based): ``cable_column("t", 3) == "t_3"``;
    a symbol for ``i`` names any cable (``cable_column("l0", "i") == "l0_i"``)."""
    for g in GROUPS:
        if g.per_cable and g.prefix == prefix:
            return g.names[0].replace(CABLE, str(i))
    raise KeyError(f"no per-cable column {prefix!r}; per-cable columns: {list(cable_prefixes())}")


def find(name: str, m: int | None = None) -> Group | None:
    """The group of the contract column ``name`` (``None``: a covariate). With ``m``
    given, a per-cable name must have an index 1..m; without, any index from 1 matches."""
    for g in GROUPS:
        if g.per_cable:
            head, _, idx = name.rpartition("_")
            # ASCII digits only ('²'.isdigit() is true, int('²') fails); no 0, no leading zeros
            canonical = idx.isascii() and idx.isdigit() and str(int(idx)) == idx and int(idx) >= 1
            if head == g.prefix and canonical and (m is None or int(idx) <= m):
                return g
        elif name in g.names:
            return g
    return None


def unit(name: str) -> str:
    """SI unit of the contract column ``name`` (``""`` for a covariate)."""
    g = find(name)
    return g.unit if g else ""


def to_columns(m: int, arrays: Mapping[str, np.ndarray], covariates: Mapping[str, np.ndarray] | None = None
               ) -> dict[str, np.ndarray]:
    """The columns of a recordings file, name -> ``(n,)`` values, in table order, then the covariates.

    **Arguments:**

    - ``m``: the number of cables.
    - ``arrays``: Recordings-field name (:data:`FIELDS`) -> values, ``(n,)`` for ``time``,
      else ``(n, k)`` with one column per name of :func:`field_columns`; fields left out
      are not written.
    - ``covariates``: covariate name -> ``(n,)`` values (must not be a contract name).

    **Returns:** a ``dict`` for :func:`cstiffjax.io.recordings.write_recordings`.

    **Raises:** ``KeyError`` naming an unknown field; ``ValueError`` naming a field of the
    wrong width or a covariate that is a contract column.
    """
    unknown = set(arrays) - set(FIELDS)
    if unknown:
        raise KeyError(f"unknown recordings field(s) {sorted(unknown)}; fields: {list(FIELDS)}")
    cols = {}
    for field in FIELDS:
        if field not in arrays:
            continue
        names, a = field_columns(field, m), np.asarray(arrays[field])
        a = a[:, None] if a.ndim == 1 else a
        if a.shape[1] != len(names):
            raise ValueError(f"{field}: {a.shape[1]} columns, the schema has {len(names)} ({', '.join(names)})")
        cols.update({name: a[:, j] for j, name in enumerate(names)})
    for name, v in (covariates or {}).items():
        if find(name) is not None:
            raise ValueError(f"covariate {name!r} is a contract column ({find(name).key}); rename it")
        cols[name] = np.asarray(v)
    return cols
