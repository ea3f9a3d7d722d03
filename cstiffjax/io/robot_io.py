"""Read and write the robot description TOML of ``cstiffjax/io/formats.md`` §1.

Every error is a :class:`~cstiffjax.core.errors.RobotFileError` that names the file, the key
(as a dotted path such as ``cables[3].EA``), the line where it can be found, the
offending value and what is allowed. Nothing is defaulted except the keys the format
marks optional (``platform.inertia``, ``platform.reference_pose`` (returned beside the robot by
:func:`load_description`), ``[limits]``, every ``[noise]`` sigma (``nan``: not stated; the
recordings say which they need, :mod:`cstiffjax.io.sigmas`), and the version-2
per-cable hardware ``pulley_radius`` (m), ``pulley_axis`` (unit vector, base frame),
``length_gain`` and ``tension_gain`` (dimensionless)). A ``kind = "csjm"`` description may
write those only at their defaults: its model has straight cables and reads no commanded
lengths or cable load cells, so a pulley or a gain other than 1 is an error, not ignored.
"""

import math
import re
import sys
import tomllib
from pathlib import Path

import numpy as np

from cstiffjax.core.errors import RobotFileError
from cstiffjax.io.robot import CableRobot, Noise, SphericalJointModule

_TOP = {"kind", "name", "gravity", "platform", "noise", "limits", "cables", "sensors"}
_PLATFORM = {"mass", "com", "inertia", "reference_pose"}
_NOISE = {"position", "rotation", "tension", "moment", "swivel", "ahrs"}
_SENSORS = {"lengths", "ahrs_mounting"}  # formats.md §1 version 3
LENGTHS = ("absolute", "relative")
_LIMITS = {"tension_min", "tension_max"}
_CABLE = {"anchor", "attachment", "EA", "mass_per_length"}
_CABLE_V2 = {"pulley_radius", "pulley_axis", "length_gain", "tension_gain"}  # formats.md §1 version 2
_CABLE_V3 = {"swivel_zero"}  # formats.md §1 version 3
AXIS_TOL = 1e-6  # |pulley_axis| must be 1 within this; swivel_zero normal to it within this (relative)
_KINDS = ("cdpr", "csjm")
_ZERO_OK = {"cables.mass_per_length", "cables.pulley_radius"}  # range keys whose value may be 0 (or absent)
RANGES = {
    "gravity": (0.0, 1e3, "m/s²"), "platform.mass": (1e-6, 1e9, "kg"), "platform.com": (0.0, 1e6, "m"),
    "platform.inertia": (0.0, 1e15, "kg m²"),
    "noise.position": (1e-12, 1e6, "m"), "noise.rotation": (1e-12, 1e3, "rad"), "noise.tension": (1e-9, 1e12, "N"),
    "noise.moment": (1e-12, 1e12, "N·m"), "noise.swivel": (1e-12, 1e3, "rad"), "noise.ahrs": (1e-12, 1e3, "rad"),
    "limits.tension_min": (0.0, 1e12, "N"), "limits.tension_max": (1e-9, 1e12, "N"),
    "cables.anchor": (0.0, 1e6, "m"), "cables.attachment": (0.0, 1e6, "m"), "cables.EA": (1e-3, 1e16, "N"),
    "cables.mass_per_length": (1e-12, 1e5, "kg/m"), "cables.pulley_radius": (1e-9, 1e3, "m"),
    "cables.length_gain": (1e-3, 1e3, ""), "cables.tension_gain": (1e-3, 1e3, ""),
}
"""Physical range ``(smallest non-zero magnitude, largest magnitude, unit)`` of each number of
the description (formats.md §1 "Ranges"): wide enough for a 1 cm and a 1 km robot and for EA
up to 1e16 N, narrow enough that no value overflows or underflows the float64 statics (EA =
1e308 N, a platform of 1e308 kg, 5e-324 N). A zero is allowed where the key allows one; a
``tension_max`` may be ``inf`` (no limit)."""


class _Lines:
    """Maps dotted key paths to 1-based line numbers of a simple TOML text."""

    def __init__(self, text: str):
        self.where: dict[str, int] = {}
        table, counts = "", {}
        for no, raw in enumerate(text.splitlines(), 1):
            line = raw.split("#", 1)[0].strip()
            if m := re.fullmatch(r"\[\[\s*([\w.]+)\s*\]\]", line):
                name = m.group(1)
                counts[name] = counts.get(name, 0) + 1
                table = f"{name}[{counts[name]}]"
                self.where.setdefault(table, no)
            elif m := re.fullmatch(r"\[\s*([\w.]+)\s*\]", line):
                table = m.group(1)
                self.where.setdefault(table, no)
            elif m := re.match(r"([\w\"'-]+)\s*=", line):
                key = m.group(1).strip("\"'")
                self.where.setdefault(f"{table}.{key}" if table else key, no)

    def line(self, path: str) -> str:
        no = self.where.get(path)
        if no is None and "." in path:
            no = self.where.get(path.rsplit(".", 1)[0])
        return f" (line {no})" if no else ""


class _Reader:
    def __init__(self, path: Path, text: str):
        self.path, self.lines = path, _Lines(text)

    def fail(self, key: str, msg: str):
        raise RobotFileError(f"{self.path}: key '{key}'{self.lines.line(key)}: {msg}")

    def unknown(self, table: dict, allowed: set, prefix: str):
        for k in table:
            if k not in allowed:
                key = f"{prefix}.{k}" if prefix else k
                self.fail(key, f"unknown key; allowed here: {', '.join(sorted(allowed))}")

    def get(self, table: dict, key: str, prefix: str, required=True):
        full = f"{prefix}.{key}" if prefix else key
        if key not in table:
            if required:
                where = f" in [{prefix}]" if prefix else ""
                raise RobotFileError(f"{self.path}: missing required key '{full}'{where}"
                                     f"{self.lines.line(prefix) if prefix else ''}")
            return None
        return table[key]

    def number(self, value, key, *, positive=False, nonneg=False):
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(key, f"expected a number, got {value!r}")
        v = self.as_float(value, key)
        if math.isnan(v):
            self.fail(key, "value is NaN; expected a finite number")
        if positive and not v > 0:
            self.fail(key, f"value {v!r} must be > 0")
        if nonneg and not v >= 0:
            self.fail(key, f"value {v!r} must be >= 0")
        if not math.isfinite(v) and not (key.endswith("tension_max") and v > 0):
            self.fail(key, f"value {v!r} must be finite")
        return self.in_range(key, v) if math.isfinite(v) else v

    def in_range(self, key: str, value):
        """``value`` (a number or array) when its non-zero magnitudes are within :data:`RANGES`."""
        generic = re.sub(r"\[\d+\]", "", key)
        lo, hi, unit = RANGES.get(generic, (0.0, math.inf, ""))
        a = np.abs(np.asarray(value, dtype=float))
        bad = (a > hi) | ((a > 0) & (a < lo))
        if np.any(bad):
            v = float(np.asarray(value, dtype=float).flat[int(np.argmax(bad.ravel()))])
            self.fail(key, f"value {v!r} {unit} is outside the physical range of this key: magnitudes "
                      f"{lo:g}..{hi:g} {unit}".rstrip() + (" (or 0)" if generic in _ZERO_OK else "")
                      + " (formats.md §1, Ranges); a unit slip?")
        return value

    def as_float(self, value, key) -> float:
        """``float(value)``; an integer beyond the float64 range is an error."""
        try:
            return float(value)
        except OverflowError:
            self.fail(key, f"integer {str(value)[:20]}... ({len(str(value))} digits) is too large "
                      f"for a float64 (at most about 1.8e308)")

    def numbers(self, value, key, shape, depth: int):
        """Nested lists ``depth`` levels deep holding only int/float (no booleans, strings)."""
        if depth == 0:
            if isinstance(value, bool) or not isinstance(value, int | float):
                self.fail(key, f"expected numbers of shape {shape}; got the element {value!r} "
                          f"({type(value).__name__})")
            return self.as_float(value, key)
        if not isinstance(value, list):
            self.fail(key, f"expected numbers of shape {shape}, got {value!r}")
        return [self.numbers(v, key, shape, depth - 1) for v in value]

    def vector(self, value, key, shape):
        arr = self.numbers(value, key, shape, len(shape))
        try:
            arr = np.array(arr, dtype=float)
        except (TypeError, ValueError):
            self.fail(key, f"expected numbers of shape {shape}, got {value!r}")
        if arr.shape != shape:
            self.fail(key, f"expected shape {shape} ({np.prod(shape)} numbers), got {arr.shape}: {value!r}")
        if not np.all(np.isfinite(arr)):
            self.fail(key, f"contains NaN or inf: {value!r}")
        return self.in_range(key, arr)


def load_robot(path) -> CableRobot | SphericalJointModule:
    """Load a robot description from a TOML file.

    **Arguments:** ``path``: the ``robot.toml`` (formats.md §1).

    **Returns:** a :class:`CableRobot` (``kind = "cdpr"``) or
    :class:`SphericalJointModule` (``kind = "csjm"``).

    **Raises:** :class:`RobotFileError` naming file, key, line, value and what is allowed.
    """
    path = Path(path)
    text = _read_text(path)
    return robot_from_dict(_parse(path, text), path, text)


def load_description(path) -> tuple[CableRobot | SphericalJointModule, np.ndarray | None]:
    """Load a robot description and its optional stated pose (formats.md §1
    ``[platform] reference_pose``).

    The pose is returned beside the robot, not held in it: an array leaf of
    :class:`~cstiffjax.io.robot.CableRobot` would change the signature of every compiled
    program that takes a robot, and a static field would make the same robot with and
    without a stated pose (or with two poses) two compiled programs. A pose is where the
    description says to look at the robot, not part of its physics.

    **Returns:** ``(robot, pose)``: ``pose`` (6,) m / rad ``[x, y, z, rx, ry, rz]``, or
    ``None`` when the file states none.

    **Raises:** :class:`RobotFileError`, as :func:`load_robot`."""
    path = Path(path)
    text = _read_text(path)
    return _build(_parse(path, text), path, text)


def _parse(path: Path, text: str) -> dict:
    """The TOML mapping of ``text`` (errors name ``path``)."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise RobotFileError(f"{path}: not valid TOML: {e}") from None
    except RecursionError:
        raise RobotFileError(f"{path}: not valid TOML: arrays or tables nested too deep") from None
    except ValueError:  # Python refuses to parse an integer of more than 4300 digits
        raise RobotFileError(f"{path}: an integer has more than {sys.get_int_max_str_digits()} digits "
                             f"(far too large for a float64)") from None


def _read_text(path: Path) -> str:
    """The file as text: UTF-8 only (TOML's encoding), a leading byte-order mark removed."""
    try:
        data = path.read_bytes()
    except OSError as e:
        raise RobotFileError(f"{path}: cannot read robot description: {e.strerror}") from None
    data = data.removeprefix(b"\xef\xbb\xbf")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[:e.start].count(b"\n") + 1
        raise RobotFileError(f"{path}: line {line}: byte {data[e.start:e.start + 1].hex()} (file "
                             f"offset {e.start}) is not UTF-8; TOML files must be UTF-8") from None


def robot_from_dict(data: dict, path="<dict>", text: str = ""):
    """Build a robot from the parsed TOML mapping (same checks as :func:`load_robot`)."""
    return _build(data, path, text)[0]


def _build(data: dict, path, text: str):
    """``(robot, reference_pose or None)`` of the parsed TOML mapping (:func:`load_description`)."""
    r = _Reader(Path(path), text)
    r.unknown(data, _TOP, "")
    kind = r.get(data, "kind", "")
    if kind not in _KINDS:
        r.fail("kind", f"value {kind!r} is not allowed; allowed: {', '.join(map(repr, _KINDS))}")
    name = r.get(data, "name", "")
    if not isinstance(name, str) or not name:
        r.fail("name", f"expected a non-empty string, got {name!r}")
    gravity = r.vector(r.get(data, "gravity", ""), "gravity", (3,))

    platform = r.get(data, "platform", "")
    if not isinstance(platform, dict):
        r.fail("platform", "expected a table [platform]")
    r.unknown(platform, _PLATFORM, "platform")
    mass = r.number(r.get(platform, "mass", "platform"), "platform.mass", positive=True)
    com = r.vector(r.get(platform, "com", "platform"), "platform.com", (3,))
    inertia_raw = r.get(platform, "inertia", "platform", required=False)
    if inertia_raw is None:
        inertia = np.full((3, 3), np.nan)  # optional: unknown, only dynamics needs it
    else:
        inertia = r.vector(inertia_raw, "platform.inertia", (3, 3))
        if not np.allclose(inertia, inertia.T) or np.linalg.eigvalsh(inertia).min() <= 0:
            r.fail("platform.inertia", f"must be symmetric positive definite, got {inertia.tolist()}")
    pose = _reference_pose(r, platform, kind)

    noise_t = data.get("noise", {})  # every sigma optional: the recordings say which are needed (io.sigmas)
    if not isinstance(noise_t, dict):
        r.fail("noise", "expected a table [noise]")
    r.unknown(noise_t, _NOISE, "noise")
    sig = {}
    for k in ("position", "rotation", "tension", "moment", "swivel"):
        if k in noise_t:
            sig[k] = r.number(noise_t[k], f"noise.{k}", positive=True)
    if "ahrs" in noise_t:
        sig["ahrs"] = r.vector(noise_t["ahrs"], "noise.ahrs", (3,))
        if np.any(sig["ahrs"] <= 0):
            r.fail("noise.ahrs", f"value {sig['ahrs'].tolist()}: the roll, pitch and yaw sigmas must be > 0 (rad)")
    noise = Noise(**sig)
    sensors = _sensors(r, data, kind)

    limits = data.get("limits", {})
    if not isinstance(limits, dict):
        r.fail("limits", "expected a table [limits]")
    r.unknown(limits, _LIMITS, "limits")
    tmin = r.number(limits.get("tension_min", 0.0), "limits.tension_min", nonneg=True)
    tmax = r.number(limits.get("tension_max", float("inf")), "limits.tension_max", positive=True)
    if tmax <= tmin:
        r.fail("limits.tension_max", f"value {tmax!r} must exceed tension_min = {tmin!r}")

    cables = r.get(data, "cables", "")
    if not isinstance(cables, list) or not cables or not all(isinstance(c, dict) for c in cables):
        r.fail("cables", "expected one or more [[cables]] tables")
    anchors, attach, EA, w, hardware = [], [], [], [], []
    for i, c in enumerate(cables, 1):
        p = f"cables[{i}]"
        r.unknown(c, _CABLE | _CABLE_V2 | _CABLE_V3, p)
        anchors.append(r.vector(r.get(c, "anchor", p), f"{p}.anchor", (3,)))
        attach.append(r.vector(r.get(c, "attachment", p), f"{p}.attachment", (3,)))
        EA.append(r.number(r.get(c, "EA", p), f"{p}.EA", positive=True))
        w.append(r.number(r.get(c, "mass_per_length", p), f"{p}.mass_per_length", nonneg=True))
        hardware.append(_hardware_fields(r, c, p))
        hardware[-1]["swivel_zero"] = _swivel_zero(r, c, p, hardware[-1]["pulley_axis"], kind)
        if kind == "csjm":
            _csjm_hardware(r, hardware[-1], p)
    m = len(cables)
    if kind == "csjm" and m < 3:
        r.fail("cables", f"a spherical joint module needs at least 3 cables, got {m}")
    cls = CableRobot if kind == "cdpr" else SphericalJointModule
    robot = cls(
        anchors=np.array(anchors), attachments=np.array(attach), EA=np.array(EA),
        mass_per_length=np.array(w), platform_mass=mass, com=com, inertia=inertia,
        gravity=gravity, noise=noise, tension_min=tmin, tension_max=tmax, name=name,
        **{k: np.array([h[k] for h in hardware]) for k in _CABLE_V2 | _CABLE_V3}, **sensors,
    )
    return robot, pose


def _reference_pose(r: _Reader, platform: dict, kind: str):
    """The optional ``[platform] reference_pose`` (6,) m / rad, or ``None``: a CDPR's pose
    ``[x, y, z, rx, ry, rz]`` (position, then rotation vector, base frame)."""
    if "reference_pose" not in platform:
        return None
    if kind != "cdpr":
        r.fail("platform.reference_pose", "a stated pose is read for kind = 'cdpr' only (a 'csjm' pose is a "
               "rotation about its joint); remove the key")
    pose = r.vector(platform["reference_pose"], "platform.reference_pose", (6,))
    if float(np.linalg.norm(pose[3:])) > 4 * math.pi:
        r.fail("platform.reference_pose", f"value {pose.tolist()}: the rotation vector [rx, ry, rz] is "
               f"{float(np.linalg.norm(pose[3:])):.6g} rad long; expected at most 4 pi (radians, not degrees)")
    return pose


def _sensors(r: _Reader, data: dict, kind: str) -> dict:
    """The optional version-3 ``[sensors]`` table: ``lengths`` ("absolute" or "relative") and
    ``ahrs_mounting`` (rotation vector, rad), as :class:`CableRobot` fields."""
    t = data.get("sensors", {})
    if not isinstance(t, dict):
        r.fail("sensors", "expected a table [sensors]")
    r.unknown(t, _SENSORS, "sensors")
    lengths = t.get("lengths", "absolute")
    if lengths not in LENGTHS:
        r.fail("sensors.lengths", f"value {lengths!r} is not allowed; allowed: {', '.join(map(repr, LENGTHS))}")
    mounting = r.vector(t.get("ahrs_mounting", [0.0, 0.0, 0.0]), "sensors.ahrs_mounting", (3,))
    if kind == "csjm" and (lengths == "relative" or "ahrs_mounting" in t):
        key = "sensors.lengths" if lengths == "relative" else "sensors.ahrs_mounting"
        r.fail(key, "on-board sensor settings are modelled for kind = 'cdpr' only (a 'csjm' model reads no "
               "commanded lengths and no AHRS); remove the key")
    return {"relative_lengths": lengths == "relative", "ahrs_mounting": mounting}


def _swivel_zero(r: _Reader, c: dict, p: str, axis, kind: str):
    """Cable ``p``'s optional version-3 ``swivel_zero`` (base frame, normal to its
    ``pulley_axis``; returned as a unit vector), zeros when not stated."""
    if "swivel_zero" not in c:
        return np.zeros(3)
    key = f"{p}.swivel_zero"
    z = r.vector(c["swivel_zero"], key, (3,))
    if kind == "csjm":
        r.fail(key, "swivel encoders are modelled for kind = 'cdpr' only; remove the key")
    if not np.any(axis != 0):
        raise RobotFileError(f"{r.path}: missing required key '{p}.pulley_axis' in [{p}]{r.lines.line(p)}: "
                             f"required with swivel_zero (the swivel angle is measured about the pulley axis)")
    scale = float(np.abs(z).max())  # any length: scaled first, so no square under- or overflows
    unit = z / scale if scale > 0 else z
    norm = float(np.linalg.norm(unit))
    if scale == 0.0:
        r.fail(key, f"value {z.tolist()} is the zero vector; it must be a non-zero vector normal to pulley_axis")
    if abs(float(unit @ axis)) > AXIS_TOL * norm:
        r.fail(key, f"value {z.tolist()} must be a non-zero vector normal to pulley_axis = {np.asarray(axis).tolist()} "
               f"(the cosine of their angle is {float(unit @ axis) / norm!r}, allowed at most {AXIS_TOL:g})")
    return unit / norm


def _hardware_fields(r: _Reader, c: dict, p: str) -> dict:
    """The optional version-2 per-cable fields of one ``[[cables]]`` table (formats.md §1)."""
    radius = r.number(c.get("pulley_radius", 0.0), f"{p}.pulley_radius", nonneg=True)
    if "pulley_axis" in c:
        axis = r.vector(c["pulley_axis"], f"{p}.pulley_axis", (3,))
        norm = float(np.linalg.norm(axis))
        if abs(norm - 1.0) > AXIS_TOL:
            r.fail(f"{p}.pulley_axis", f"must be a unit vector (|axis| = 1 within {AXIS_TOL:g}), "
                   f"got {axis.tolist()} of length {norm!r}")
    elif radius > 0:
        raise RobotFileError(f"{r.path}: missing required key '{p}.pulley_axis' in [{p}]"
                             f"{r.lines.line(p)}: required when pulley_radius = {radius!r} > 0")
    else:
        axis = np.zeros(3)
    gains = {k: r.number(c.get(k, 1.0), f"{p}.{k}", positive=True) for k in ("length_gain", "tension_gain")}
    return {"pulley_radius": radius, "pulley_axis": axis, **gains}


def _csjm_hardware(r: _Reader, hw: dict, p: str) -> None:
    """A CSJM's cables run straight from the base hole and its model reads no commanded
    lengths or load cells: a swivel pulley or a gain other than 1 would be ignored, so it
    is an error naming the key and the value (the defaults, written out, are accepted)."""
    if hw["pulley_radius"] > 0:
        r.fail(f"{p}.pulley_radius", f"value {hw['pulley_radius']!r}: swivel pulleys are modelled for kind = "
               f"'cdpr' only; a 'csjm' cable runs straight from its base hole (remove the key or set it to 0)")
    for k in ("length_gain", "tension_gain"):
        if hw[k] != 1.0:
            r.fail(f"{p}.{k}", f"value {hw[k]!r}: gains are modelled for kind = 'cdpr' only (a 'csjm' model reads "
                   f"no commanded lengths or cable load cells); remove the key or set it to 1")


def _hardware_lines(cables: dict, i: int) -> list[str]:
    """TOML lines of cable ``i``'s version-2 fields, only those that are not the default
    (``cables``: the per-cable arrays of :data:`_PER_CABLE` as numpy arrays)."""
    out = []
    radius, axis = float(cables["pulley_radius"][i]), cables["pulley_axis"][i]
    if radius != 0.0:
        out.append(f"pulley_radius = {radius!r}")
    if np.any(axis != 0.0):
        out.append(f"pulley_axis = {_fmt(axis)}")
    for k in ("length_gain", "tension_gain"):
        if float(cables[k][i]) != 1.0:
            out.append(f"{k} = {float(cables[k][i])!r}")
    if np.any(cables["swivel_zero"][i] != 0.0):
        out.append(f"swivel_zero = {_fmt(cables['swivel_zero'][i])}")
    return out


# converted to numpy once per robot: indexing a JAX array costs ~0.1 ms a time, which made 40 000
# cables take minutes to write
_PER_CABLE = ("anchors", "attachments", "EA", "mass_per_length", "pulley_radius", "pulley_axis", "length_gain",
              "tension_gain", "swivel_zero")


def _fmt(x) -> str:
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        return repr(float(a))
    return "[" + ", ".join(_fmt(v) for v in a) + "]"


def robot_to_toml(robot, reference_pose=None) -> str:
    """The TOML text of ``robot`` (round-trips through :func:`load_robot`), with the stated
    pose ``reference_pose`` (6,) m / rad when given (read back by :func:`load_description`)."""
    out = [f'kind = "{robot.kind}"', f"name = {_toml_string(robot.name)}", f"gravity = {_fmt(robot.gravity)}", ""]
    out += ["[platform]", f"mass = {_fmt(robot.platform_mass)}", f"com = {_fmt(robot.com)}"]
    if np.all(np.isfinite(robot.inertia)):
        out.append(f"inertia = {_fmt(robot.inertia)}")
    if reference_pose is not None:
        out.append(f"reference_pose = {_fmt(np.reshape(np.asarray(reference_pose, dtype=float), 6))}")
    n = robot.noise
    out += ["", "[noise]"]
    for k in ("position", "rotation", "tension", "moment", "swivel"):
        if np.isfinite(getattr(n, k)):
            out.append(f"{k} = {_fmt(getattr(n, k))}")
    if np.all(np.isfinite(n.ahrs)):
        out.append(f"ahrs = {_fmt(n.ahrs)}")
    if robot.relative_lengths or np.any(np.asarray(robot.ahrs_mounting) != 0):
        out += ["", "[sensors]", f'lengths = "{LENGTHS[int(robot.relative_lengths)]}"',
                f"ahrs_mounting = {_fmt(robot.ahrs_mounting)}"]
    tmin, tmax = float(robot.tension_min), float(robot.tension_max)
    if tmin != 0.0 or math.isfinite(tmax):
        out += ["", "[limits]", f"tension_min = {tmin!r}"]
        if math.isfinite(tmax):
            out.append(f"tension_max = {tmax!r}")
    cables = {k: np.asarray(getattr(robot, k)) for k in _PER_CABLE}
    for i in range(robot.num_cables):
        out += ["", "[[cables]]", f"anchor = {_fmt(cables['anchors'][i])}",
                f"attachment = {_fmt(cables['attachments'][i])}", f"EA = {_fmt(cables['EA'][i])}",
                f"mass_per_length = {_fmt(cables['mass_per_length'][i])}"]
        out += _hardware_lines(cables, i)
    return "\n".join(out) + "\n"


def _toml_string(s: str) -> str:
    """``s`` as a TOML basic string: quotes, backslashes and control characters escaped."""
    out = []
    for ch in s:
        o = ord(ch)
        if 0xD800 <= o <= 0xDFFF:
            raise ValueError(f"robot name {s!r} holds a lone surrogate, which TOML cannot store")
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif o < 0x20 or o == 0x7F:
            out.append(f"\\u{o:04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f",
            "\r": "\\r"}


def save_robot(robot, path, reference_pose=None) -> None:
    """Write ``robot`` (and its stated pose ``reference_pose``, when given) as a UTF-8 TOML file
    that :func:`load_description` reads back unchanged."""
    Path(path).write_text(robot_to_toml(robot, reference_pose), encoding="utf-8")
