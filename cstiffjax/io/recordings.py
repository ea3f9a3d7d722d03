"""Load the recordings CSV of ``formats.md`` §2 into a :class:`Recordings`, and write one.

The columns, their units and rules come from :mod:`cstiffjax.io.schema`. Column order is
free; unknown numeric columns are kept as covariates. Every error is
a :class:`~cstiffjax.core.errors.RecordingsError` naming the file, the line of the file
(the header is line 1 when the file starts with it; blank lines count) and the column.

The reader is strict so that no near-miss passes silently:

- the file must be UTF-8 (a leading byte-order mark is removed) and comma-separated;
- a header name that differs from a contract name only by case, separators or the
  cable index (``T_1``, ``t1``, ``Fz``, ``L0_1``, ``l0_0``, ``l0_01``, ``t_9`` on a
  6-cable robot), by one edit (``swivle_2``, ``tiem``) or is a long form (``tension_2``,
  ``length_1``: :mod:`cstiffjax.io.column_names`) is an error suggesting the intended name,
  never a covariate, unless its name starts with ``cov_`` (a declared covariate);
- a per-cable tension or swivel group with a hole (``swivel_1, swivel_3`` without
  ``swivel_2``) is an error; a cable without the sensor has its column with empty cells;
- numbers are plain decimals (``-1.25``, ``3e-4``): Python-only spellings such as
  ``4_605``, ``0x1p3``, ``inf`` or ``nan`` and non-ASCII digits are rejected;
- a quoted cell may not span lines (always an error, even with ``drop_invalid``, so
  no rows are swallowed into one cell); a cell has at most :data:`MAX_CELL_CHARS`
  characters;
- commanded lengths ``l0_i`` must be > 0; ``session`` ids are whole numbers;
- ``x y z``, ``rx ry rz`` and ``roll pitch yaw`` come all three or not at all, and a CDPR's
  file has at least one channel that constrains the pose (version 3: on-board sensors only,
  no ``x y z``, is allowed); a swivel column needs its cable's ``swivel_zero``;
- every recorded channel needs its ``[noise]`` sigma in the robot description
  (:func:`cstiffjax.io.sigmas.check_sigmas`; a channel without values needs none).
"""

import csv
import dataclasses
import io
import math
import re
from collections.abc import Mapping
from pathlib import Path

import equinox as eqx
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from cstiffjax.core.arrays import f64 as _f64
from cstiffjax.core.arrays import to_device
from cstiffjax.core.errors import RecordingsError
from cstiffjax.io import column_names, schema
from cstiffjax.io.sigmas import check_sigmas

MAX_CELL_CHARS = 200
"""Longest cell (characters, surrounding spaces excluded) the reader accepts."""

MAGNITUDES = {"l0": 1e7, "force": 1e12, "moment": 1e12, "position": 1e7, "tension": 1e12, "joint_moment": 1e12,
              "time": 1e11, "session": 2.0**31}
"""Largest magnitude a reading of each column group may have (its unit: m, N, N·m, s; far
beyond any robot's: a 1e308 N reading is a glitch, not a tension)."""

ANGLES = {"roll": math.pi, "pitch": math.pi / 2, "yaw": math.pi, "swivel": 2 * math.pi, "rotation": 2 * math.pi}
"""Largest magnitude of each angle column, rad (AHRS Z-Y-X angles: roll and yaw in [-pi, pi],
pitch in [-pi/2, pi/2]; a swivel angle or a rotation-vector component within one turn). A
value beyond is an error even with ``drop_invalid``: the column is in degrees, not rad."""

_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_CABLE = re.compile(rf"({'|'.join(map(re.escape, schema.cable_prefixes()))})[ _.\-]*([0-9]+)", re.IGNORECASE)
_BOM = b"\xef\xbb\xbf"


def _f64_or_none(x):
    return None if x is None else _f64(x)


def _device_or_none(x):
    return None if x is None else to_device(x)
_DELIMITERS = {";": "';'", "\t": "a tab", "|": "'|'"}


class Recordings(eqx.Module):
    """Static equilibrium samples, in the order they were taken (``n`` rows).

    **Inputs:** ``l0`` ``(n, m)`` commanded unstrained lengths, m (zeros for a CSJM);
    ``wrench`` ``(n, 6)`` external ``[fx, fy, fz, mx, my, mz]`` on the platform, base
    frame, about the reference point, N and N·m (weight excluded); ``time`` ``(n,)`` s
    (``nan`` when the file has no ``time`` column).

    **Measurements:** ``pose`` ``(n, 6)`` ``[x, y, z, rx, ry, rz]`` (m, rad; position is
    zero for a CSJM); ``tensions`` ``(n, m)`` N at the exit point with ``tension_mask``
    true where a value was recorded; ``moment`` ``(n, 3)`` CSJM moment about O in the
    platform frame, N·m (zeros for a CDPR).

    ``pose_mask`` ``(n, 6)`` is true where a pose component was measured (version 3: ``x y z``
    and, on a CDPR, ``rx ry rz`` are optional; unmeasured components hold 0).

    **On-board sensors** (contract version 3; all optional): ``swivel`` ``(n, m)`` measured
    pulley swivel angles, rad, with ``swivel_mask``; ``ahrs`` ``(n, 3)`` AHRS ``[roll, pitch,
    yaw]``, rad, with ``ahrs_mask``; ``session`` ``(n,)`` integer session ids (0 when the file
    has no ``session`` column). Left out at construction, they mean "not measured" (masks
    false; ``pose_mask`` all true; session 0).

    ``covariates`` ``(n, k)`` holds any other numeric column, named by the static
    ``covariate_names``. The columns of each field are those of
    :func:`cstiffjax.io.schema.field_columns`. ``source`` (static) names the file.
    ``rows`` (static) holds the file line number (header = line 1; blank lines count) of
    each sample, ``()`` when the samples did not come from a file. ``dropped_rows``
    (static) holds the file line numbers of the rows that ``drop_invalid`` dropped, and
    ``drop_reasons`` (static, same order) says why each was dropped.
    """

    l0: Float[Array, "n m"] = eqx.field(converter=_f64)
    wrench: Float[Array, "n 6"] = eqx.field(converter=_f64)
    pose: Float[Array, "n 6"] = eqx.field(converter=_f64)
    tensions: Float[Array, "n m"] = eqx.field(converter=_f64)
    tension_mask: Bool[Array, "n m"] = eqx.field(converter=to_device)
    moment: Float[Array, "n 3"] = eqx.field(converter=_f64)
    time: Float[Array, " n"] = eqx.field(converter=_f64)
    covariates: Float[Array, "n k"] = eqx.field(converter=_f64)
    pose_mask: Bool[Array, "n 6"] = eqx.field(converter=_device_or_none, default=None)
    swivel: Float[Array, "n m"] = eqx.field(converter=_f64_or_none, default=None)
    swivel_mask: Bool[Array, "n m"] = eqx.field(converter=_device_or_none, default=None)
    ahrs: Float[Array, "n 3"] = eqx.field(converter=_f64_or_none, default=None)
    ahrs_mask: Bool[Array, "n 3"] = eqx.field(converter=_device_or_none, default=None)
    session: Int[Array, " n"] = eqx.field(converter=_device_or_none, default=None)
    covariate_names: tuple[str, ...] = eqx.field(static=True, default=())
    kind: str = eqx.field(static=True, default="cdpr")
    source: str = eqx.field(static=True, default="<memory>")
    rows: tuple[int, ...] = eqx.field(static=True, default=())
    dropped_rows: tuple[int, ...] = eqx.field(static=True, default=())
    drop_reasons: tuple[str, ...] = eqx.field(static=True, default=())

    def __post_init__(self):
        n, m = np.shape(self.l0)
        for name, value in (("pose_mask", np.ones((n, 6), bool)), ("swivel", np.zeros((n, m))),
                            ("swivel_mask", np.zeros((n, m), bool)), ("ahrs", np.zeros((n, 3))),
                            ("ahrs_mask", np.zeros((n, 3), bool)), ("session", np.zeros(n, np.int64))):
            if getattr(self, name) is None:
                object.__setattr__(self, name, to_device(value))

    def __check_init__(self):
        n, m = self.l0.shape
        for name, shape in (("wrench", (n, 6)), ("pose", (n, 6)), ("tensions", (n, m)),
                            ("tension_mask", (n, m)), ("moment", (n, 3)), ("time", (n,)),
                            ("pose_mask", (n, 6)), ("swivel", (n, m)), ("swivel_mask", (n, m)),
                            ("ahrs", (n, 3)), ("ahrs_mask", (n, 3)), ("session", (n,))):
            if getattr(self, name).shape != shape:
                raise ValueError(f"Recordings.{name} must have shape {shape}, "
                                 f"got {getattr(self, name).shape}")
        if self.covariates.shape != (n, len(self.covariate_names)):
            raise ValueError("Recordings.covariates does not match covariate_names")
        if len(self.rows) not in (0, n):
            raise ValueError(f"Recordings.rows has {len(self.rows)} line numbers for {n} samples")
        if len(self.drop_reasons) not in (0, len(self.dropped_rows)):
            raise ValueError("Recordings.drop_reasons does not match dropped_rows")

    @property
    def num_samples(self) -> int:
        return self.l0.shape[0]

    @property
    def num_cables(self) -> int:
        return self.l0.shape[1]

    @property
    def has_tensions(self) -> bool:
        return bool(np.any(np.asarray(self.tension_mask)))

    @property
    def has_position(self) -> bool:
        """Whether any ``x y z`` was measured (version 3 makes them optional)."""
        return bool(np.any(np.asarray(self.pose_mask)[:, :3]))

    @property
    def has_swivel(self) -> bool:
        return bool(np.any(np.asarray(self.swivel_mask)))

    @property
    def has_ahrs(self) -> bool:
        return bool(np.any(np.asarray(self.ahrs_mask)))

    @property
    def sessions(self) -> tuple[int, ...]:
        """The session ids present, ascending."""
        return tuple(int(s) for s in np.unique(np.asarray(self.session)))

    def covariate(self, name: str) -> np.ndarray:
        """The covariate column ``name`` (``KeyError`` lists the available ones)."""
        if name not in self.covariate_names:
            raise KeyError(f"no covariate {name!r}; available: {list(self.covariate_names)}")
        return np.asarray(self.covariates[:, self.covariate_names.index(name)])

    def select(self, index) -> "Recordings":
        """A subset of the samples (boolean mask or integer indices), ``rows`` with them."""
        idx = np.asarray(index)
        fields = ("l0", "wrench", "pose", "tensions", "tension_mask", "moment", "time", "covariates",
                  "pose_mask", "swivel", "swivel_mask", "ahrs", "ahrs_mask", "session")
        out = eqx.tree_at(lambda r: [getattr(r, f) for f in fields], self,
                          [getattr(self, f)[idx] for f in fields])
        if not self.rows:
            return out
        return dataclasses.replace(out, rows=tuple(np.asarray(self.rows)[idx].tolist()))


# ------------------------------------------------------------------------ reading text
def _show(cell: str) -> str:
    return repr(cell) if len(cell) <= 40 else repr(cell[:37] + "...") + f" ({len(cell)} characters)"


def _read_text(path: Path) -> str:
    """The file as text: UTF-8 only, a leading byte-order mark removed."""
    try:
        data = path.read_bytes()
    except OSError as e:
        raise RecordingsError(f"{path}: cannot read recordings: {e.strerror}") from None
    data = data.removeprefix(_BOM)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[:e.start].count(b"\n") + 1
        raise RecordingsError(
            f"{path}: line {line}: byte {data[e.start:e.start + 1].hex(' ')!s} (file offset {e.start}) "
            f"is not UTF-8; save the file as UTF-8 (formats.md §2)"
        ) from None


def _read_rows(path: Path, text: str):
    """``[(line, cells or csv error message)]`` for every non-blank record.

    A record that spans several lines (a quoted cell with a line break, or a quote that
    is never closed) is always an error: it would merge rows into one cell.
    """
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    out, end = [], 0
    while True:
        start = end + 1
        try:
            cells = next(reader)
        except StopIteration:
            return out
        except csv.Error as e:
            if reader.line_num > start:
                _spanning(path, start, reader.line_num)
            out.append((start, f"not valid CSV ({e})"))
            end = reader.line_num
            continue
        end = reader.line_num
        if end > start:
            _spanning(path, start, end)
        if any(c.strip() for c in cells) or len(cells) > 1:
            out.append((start, cells))


def _spanning(path, start, end):
    raise RecordingsError(
        f"{path}: lines {start}-{end}: a quoted cell spans several lines (a line break inside "
        f"quotes, or a '\"' that is never closed); each row must be on one line. This is an "
        f"error even with drop_invalid, which would otherwise merge those rows into one cell"
    )


# ------------------------------------------------------------------------ header checks
_SETPOINT = re.compile(r"t[ _.\-]*set[ _.\-]*([0-9]+)", re.IGNORECASE)


def _near_miss(h: str, m: int, robot_name: str) -> str | None:
    """Why the header name ``h`` is a near-miss of a contract name (``None`` if it is not)."""
    if mt := _SETPOINT.fullmatch(h):
        idx = int(mt.group(1))
        name = schema.SETPOINT.replace(schema.CABLE, str(idx))
        if not 1 <= idx <= m:
            return (f"a tension set-point of cable {idx}, but the robot '{robot_name}' has cables 1..{m} "
                    f"(allowed: t_set_1..t_set_{m})")
        return None if h == name else f"did you mean '{name}'? (lower case, '_', no leading zeros)"
    if mt := _CABLE.fullmatch(h):
        prefix, idx = mt.group(1).lower(), int(mt.group(2))
        allowed = f"{schema.cable_column(prefix, 1)}..{schema.cable_column(prefix, m)}"
        if idx == 0:
            return f"cable indices start at 1 (allowed: {allowed})"
        if idx > m:
            return (f"refers to cable {idx} but the robot '{robot_name}' has {m} cables "
                    f"(allowed: {allowed})")
        if h != schema.cable_column(prefix, idx):
            return f"did you mean '{schema.cable_column(prefix, idx)}'? (lower case, '_', no leading zeros)"
        return None
    canon = re.sub(r"[^a-z0-9]", "", h.lower())
    for name in schema.fixed_names():
        if h != name and canon == name:
            return f"did you mean '{name}'? (contract names are lower case, without separators)"
    return None


def _check_header(path: Path, line: int, header: list[str], robot) -> None:
    where = f"{path}: line {line} (header)"
    if len(header) == 1:
        seen = [d for c, d in _DELIMITERS.items() if c in header[0]]
        if not seen and len(header[0].split()) > 1:
            seen = ["spaces"]
        why = f"; it seems to use {seen[0]} as delimiter" if seen else ""
        raise RecordingsError(f"{where}: read as a single column {_show(header[0])}{why}. "
                              f"The recordings must be comma-separated (formats.md §2)")
    if all(_NUMBER.fullmatch(h) for h in header):
        raise RecordingsError(f"{where}: looks like data (all numbers), not a header; the first "
                              f"non-blank line must name the columns (formats.md §2)")
    seen = set()
    for j, h in enumerate(header, 1):
        if h == "":
            raise RecordingsError(f"{where}: column {j} has no name; every column needs a name")
        if len(h) > MAX_CELL_CHARS or not h.isprintable():
            raise RecordingsError(f"{where}: column {j} name {_show(h)} is over {MAX_CELL_CHARS} "
                                  f"characters or contains invisible or control characters")
        for c, d in _DELIMITERS.items():
            if c in h:
                raise RecordingsError(f"{where}: column name {_show(h)} contains {d}; the "
                                      f"recordings must be comma-separated (formats.md §2)")
        if h in seen:
            raise RecordingsError(f"{where}: names column '{h}' twice")
        seen.add(h)
    problems = [f"'{h}': {why}" for h in header if (why := _near_miss(h, robot.num_cables, robot.name))]
    problems = problems or [f"'{h}': did you mean '{c}'? ('{c}' is {'also present' if c in seen else 'missing'})"
                            for h in header if (c := column_names.meant(h, robot.num_cables))]
    if problems:
        raise RecordingsError(
            f"{where}: column name(s) that are near-misses of the contract names of formats.md "
            f"§2 (they would otherwise be taken as covariates): " + "; ".join(problems)
            + f". Rename them; a column that is a covariate: prefix its name with '{column_names.COVARIATE_PREFIX}'"
        )


def _check_sensors(where: str, header: list[str], robot) -> None:
    """The version-3 rules of the header: groups that come all together or not at all, a
    channel that constrains a CDPR's pose, the swivel zeros swivel columns need and the
    gravity an AHRS needs."""
    m, present = robot.num_cables, set(header)
    for g in schema.GROUPS:
        cols = g.columns(m)
        have = [c for c in cols if c in present]
        if g.together and have and len(have) < len(cols):
            lacking = ", ".join(c for c in cols if c not in present)
            raise RecordingsError(f"{where}: has {', '.join(have)} but not {lacking}: the {g.quantity} columns "
                                  f"{' '.join(cols)} come all together or not at all")
    for quantity, have, gaps in column_names.holes(header, m):
        raise RecordingsError(f"{where}: has {', '.join(have)} but not {', '.join(gaps)}: a misspelt or missing "
                              f"{quantity} column? A cable without this sensor needs its column with empty cells "
                              f"(not recorded)")
    if robot.kind != "cdpr":
        return
    groups = {g: [c for c in schema.group(g).columns(m) if c in present] for g in schema.POSE_CHANNELS}
    if not any(groups.values()):
        raise RecordingsError(f"{where}: no measured channel constrains the platform's pose; a {m}-cable cdpr's "
                              f"recordings need at least one of: x y z, rx ry rz, t_1..t_{m}, swivel_1..swivel_{m}, "
                              f"roll pitch yaw (formats.md §2)")
    for c in groups["swivel"]:
        i = int(c.rpartition("_")[2])
        if not np.any(np.asarray(robot.swivel_zero[i - 1]) != 0):
            raise RecordingsError(f"{where}: column '{c}' needs cables[{i}].swivel_zero (and pulley_axis) in the robot "
                                  f"description '{robot.name}': the direction where the swivel encoder reads 0")
    if groups["ahrs"]:
        g = np.asarray(robot.gravity, dtype=float)
        if not (g[2] < 0 and np.allclose(g[:2], 0.0, atol=1e-9 * abs(g[2]))):
            raise RecordingsError(f"{where}: roll pitch yaw (an AHRS) are measured against gravity, which must then "
                                  f"point along -z of the base frame; the robot '{robot.name}' has gravity = "
                                  f"{g.tolist()}")


# ------------------------------------------------------------------------ cells
def _role(name: str, m: int, kind: str) -> tuple[str, bool, schema.Group | None, float, bool]:
    """How the cells of column ``name`` are read on a ``kind`` robot with ``m`` cables:
    ``(empty, positive, group, largest, angle)`` with ``empty`` what an empty cell is
    (``"unrecorded"``: a value not recorded, masked out; ``"required"`` or ``"optional"``: a
    missing value in such a column, an error), ``positive`` whether values must be > 0, the
    schema group (``None``: a covariate, an optional column), the largest magnitude allowed
    (:data:`MAGNITUDES`, :data:`ANGLES`) and whether the column is an angle."""
    g = schema.find(name, m)
    if g is None:
        return "optional", False, None, math.inf, False
    empty = "unrecorded" if g.empty_ok else "required" if kind in g.required else "optional"
    angle = ANGLES.get(name, ANGLES.get(g.key))
    largest = angle if angle is not None else MAGNITUDES.get(g.key, math.inf)
    return empty, g.positive and kind in g.used, g, largest, angle is not None


def _cell(text: str, role: tuple[str, bool, schema.Group | None, float, bool]):
    """``(value, None)`` or ``(None, reason)`` for one cell read by its column's :func:`_role`;
    ``nan`` is an empty cell of a value not recorded. An optional column has no default once
    it is in the file: an empty cell there is a missing value."""
    empty, positive, g, largest, angle = role
    s = text.strip()
    if s == "":
        if empty == "unrecorded":
            return np.nan, None  # not recorded: masked out
        what = "an optional column (no default once the column is present)" if empty == "optional" \
            else "a required column"
        return None, f"value is missing (empty cell) in {what}"
    if len(s) > MAX_CELL_CHARS:
        return None, f"cell is {len(s)} characters long (at most {MAX_CELL_CHARS})"
    if not _NUMBER.fullmatch(s):
        return None, (f"value {_show(s)} is not a finite decimal number (allowed: digits with an "
                      f"optional sign, '.' and exponent, e.g. -1.25e-3; not '_', hex, inf or nan)")
    v = float(s)
    if not math.isfinite(v):
        return None, f"value {_show(s)} is not a finite number (overflows float64)"
    if positive and v <= 0:
        return None, f"value {_show(s)} must be > 0 (a {g.quantity}, {g.unit})"
    if abs(v) > largest:
        if angle:
            return None, (f"value {_show(s)} is outside [-{largest:.6g}, {largest:.6g}] rad, the range "
                          f"of its {g.quantity}: the column is in degrees? Angles are in rad (formats.md §2)")
        return None, f"value {_show(s)} is implausibly large ({g.quantity}: |value| <= {largest:g} {g.unit})"
    if g is not None and g.integer and (v != int(v) or abs(v) > 2**31):
        return None, f"value {_show(s)} must be a whole number (a {g.quantity} id, e.g. 0, 1, 2)"
    return v, None


def _row(header, cells, roles):
    """Parsed values of one row, or ``(None, column, reason)`` for its first bad cell."""
    vals = []
    for h, c in zip(header, cells, strict=True):
        v, why = _cell(c, roles[h])
        if why:
            return None, h, why
        vals.append(v)
    return vals, None, None


# ------------------------------------------------------------------------ loader
def _data(path, rows, roles, drop_invalid):
    """``(columns, kept lines, dropped lines, reasons)`` from the data rows (``rows[1:]``);
    ``roles`` maps the (stripped) header names, in file order, to their :func:`_role`."""
    header_line, header = rows[0][0], list(roles)
    cols = {h: [] for h in header}
    kept, dropped, reasons = [], [], []
    for line, cells in rows[1:]:
        if isinstance(cells, str):
            where, why = "", cells
        elif len(cells) != len(header):
            where, why = "", f"has {len(cells)} cells, the header (line {header_line}) has {len(header)}"
        else:
            vals, col, why = _row(header, cells, roles)
            where = f", column '{col}'" if col else ""
        if why and where and roles[col][4] and "degrees" in why:
            raise RecordingsError(f"{path}: line {line}{where}: {why}. This is an error even with drop_invalid: "
                                  f"the whole column would be in the wrong unit")
        if why:
            if not drop_invalid:
                raise RecordingsError(f"{path}: line {line}{where}: {why}; pass drop_invalid=True "
                                      f"(--drop-invalid) to drop such rows")
            dropped.append(line)
            reasons.append(f"{where.removeprefix(', ')}: {why}" if where else why)
            continue
        kept.append(line)
        for h, v in zip(header, vals, strict=True):
            cols[h].append(v)
    return cols, kept, dropped, reasons


def load_recordings(path, robot, *, drop_invalid: bool = False) -> Recordings:
    """Load a recordings CSV for ``robot``.

    **Arguments:**

    - ``path``: the CSV file (formats.md §2; UTF-8, comma-separated; the columns of
      :mod:`cstiffjax.io.schema`).
    - ``robot``: the :class:`~cstiffjax.io.robot.CableRobot` or
      :class:`~cstiffjax.io.robot.SphericalJointModule` it was recorded on (fixes ``m``).
    - ``drop_invalid``: drop rows with a bad cell instead of raising: a missing or
      non-numeric value in a required column, an empty or non-numeric optional cell
      (an empty ``t_i`` is never dropped: it is a tension not recorded, masked out), a
      non-positive ``l0_i``, an over-long cell, a row with the wrong number of cells.
      The returned ``dropped_rows`` lists their file line numbers and ``drop_reasons``
      why. Problems of the file as a whole (encoding, header, a quoted cell spanning
      lines) are errors either way.

    **Returns:** a :class:`Recordings`; its ``rows`` are the file line numbers of the samples.

    **Raises:** :class:`RecordingsError` naming the file, the line and the column; or the
    file, the columns and the ``[noise]`` key when a recorded channel has no sigma in the
    robot description.
    """
    path = Path(path)
    m, kind = robot.num_cables, robot.kind
    rows = _read_rows(path, _read_text(path))
    if not rows:
        raise RecordingsError(f"{path}: empty file; expected a header row and data rows")
    header_line, header = rows[0]
    if isinstance(header, str):
        raise RecordingsError(f"{path}: line {header_line} (header): {header}")
    header = [h.strip() for h in header]
    _check_header(path, header_line, header, robot)
    missing = [c for c in schema.required_columns(kind, m) if c not in header]
    if missing:
        raise RecordingsError(f"{path}: line {header_line} (header): required column(s) missing for a "
                              f"{kind} with {m} cables: {', '.join(missing)}")
    _check_sensors(f"{path}: line {header_line} (header)", header, robot)
    known = set(schema.column_names(m))
    cov_names = tuple(h for h in header if h not in known)
    roles = {h: _role(h, m, kind) for h in header}
    cols, kept, dropped, reasons = _data(path, rows, roles, drop_invalid)
    n = len(kept)
    if n == 0:
        shown = ", ".join(map(str, dropped[:10])) + (", ..." if len(dropped) > 10 else "")
        first = f"; line {dropped[0]}: {reasons[0]}" if dropped else ""
        raise RecordingsError(f"{path}: no valid data rows (dropped {len(dropped)}: lines {shown}{first})"
                              if dropped else f"{path}: no data rows after the header")
    rec = Recordings(**_fields(cols, n, m, kind), covariates=_stack(cols, cov_names, n), covariate_names=cov_names,
                     kind=kind, source=str(path), rows=tuple(kept), dropped_rows=tuple(dropped),
                     drop_reasons=tuple(reasons))
    check_sigmas(robot, rec)  # the [noise] sigma of every recorded channel
    return rec


def _stack(cols, names, n) -> np.ndarray:
    """The columns ``names`` of ``cols`` side by side, ``(n, len(names))``."""
    return np.stack([np.asarray(cols[c], dtype=float) for c in names], 1) if names else np.zeros((n, 0))


def _fields(cols, n, m, kind) -> dict:
    """The Recordings fields of the schema's columns: a column the file lacks holds its
    group's ``absent`` value, a group not used by ``kind`` holds zeros; ``tension_mask``
    is true where a tension was recorded."""
    parts = {field: [] for field in schema.FIELDS}
    for g in schema.GROUPS:
        for c in g.columns(m):
            if kind not in g.used:
                parts[g.field].append(np.zeros(n))
            else:
                parts[g.field].append(np.asarray(cols[c], dtype=float) if c in cols else np.full(n, g.absent))
    out = {field: np.stack(p, 1) for field, p in parts.items()}
    out["time"] = out["time"][:, 0]
    out["session"] = out["session"][:, 0].astype(np.int64)
    for field, mask in (("tensions", "tension_mask"), ("pose", "pose_mask"), ("swivel", "swivel_mask"),
                        ("ahrs", "ahrs_mask")):
        out[mask] = ~np.isnan(out[field])
        out[field] = np.where(out[mask], out[field], 0.0)
    if kind not in schema.group("position").used:
        out["pose_mask"][:, :3] = True  # a CSJM's position is the joint centre, not a measurement
    return out


# ------------------------------------------------------------------------ writing
def write_recordings(columns: Mapping[str, np.ndarray], path) -> None:
    """Write a recordings CSV (formats.md §2) at ``path``.

    **Arguments:**

    - ``columns``: column name -> ``(n,)`` values, in file order (e.g.
      :func:`cstiffjax.io.schema.to_columns`).
    - ``path``: the file to write.

    The file has a header row, then one row per sample with 12 significant digits
    (``%.12g``); a ``nan`` is written as an empty cell (a value not recorded).

    **Raises:** ``ValueError`` naming a column name that the reader would not take back
    (empty, with a comma, quote, line break or surrounding spaces) or columns of unequal length.
    """
    names = list(columns)
    for name in names:
        if not name or name != name.strip() or any(c in name for c in ',"\r\n'):
            raise ValueError(f"{path}: column name {name!r} cannot be written (empty, or with a comma, quote, "
                             f"line break or surrounding spaces)")
    values = [np.asarray(columns[c], dtype=float) for c in names]
    for name, v in zip(names, values, strict=True):
        if v.shape != values[0].shape or v.ndim != 1:
            raise ValueError(f"{path}: column {name!r} has shape {v.shape}, column {names[0]!r} {values[0].shape}; "
                             f"every column needs one value per sample")
    values = np.stack(values, 1)
    lines = [",".join(names)] + [",".join("" if math.isnan(v) else f"{v:.12g}" for v in row) for row in values]
    Path(path).write_text("\n".join(lines) + "\n")
