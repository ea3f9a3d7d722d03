"""Read the public IRMA4U self-calibration recordings as a robot description and recordings.

IRMA4U (University of Bologna) is a suspended cable robot with 4 cables, swivel pulleys, load
cells, pulley swivel encoders and an AHRS on the platform, and no external pose measurement.
Its self-calibration experiments are published as MATLAB files in the GitHub repository
``fzoffoli/UACDPR_SelfCalibration``; :func:`read_irma4u` maps them onto formats.md §1/§2
(contract version 3: relative cable lengths, swivel angles, AHRS, sessions, no ``x y z``).
The repository has no licence file: the data stay with their authors (see ``irma4u.md``).

Files read, from a checkout of that repository (or a folder holding them side by side):

- ``libs/config/IRMA4U_Mar25.mat`` (or ``IRMA4U_Mar25.mat``): struct ``s``, the robot's
  nominal model. ``s.EndEffector.Platform``: ``m`` (kg), ``PtoG`` (centre of mass, platform
  frame, m), ``InertialMatrix`` (about the centre of mass, platform frame, kg m²), ``points``
  (4 attachment points, platform frame, m). ``s.Trasmission.Pulley{i}``: ``r`` (m),
  ``CableEnterPosition`` (m, base frame) and ``FixedFrame`` ``{x_i, y_i, z_i}`` (base frame).
- per run, ``<run>_parsed.mat`` (struct ``st``: the processed log) and a workspace file with
  ``meas_idx`` (1-based indices into ``st`` of the samples the authors picked as static), see
  :data:`RUNS`. A workspace file also holds a copy of ``st``, used when the log is absent.

The mapping (SI units; the repository's ``st`` already holds radians and metres):

- ``anchor`` = ``CableEnterPosition``, ``pulley_radius`` = ``r``, ``pulley_axis`` = ``z_i``
  (the source's swivel axis, along which the cable arrives), ``swivel_zero`` = ``x_i``: the
  source's swivel angle is ``atan2(y_i·(P-D), x_i·(P-D))``, the angle about ``z_i`` from ``x_i``
  (``x_i × y_i = z_i`` is checked), which is the contract's ``swivel_i``. The source's cable
  length ``r (pi - psi) + |P - T|`` is the contract's pulley path length.
- ``l0_i`` = ``st.cable_length``: the winch encoder relative to its mean over the homing
  log, plus the nominal length at the homing pose (``[sensors] lengths = "relative"``).
  ``swivel_i`` = ``st.swivel``, zeroed the same way at the nominal homing swivel angles.
- ``t_i`` = ``st.tensions`` (load cells, N); ``t_set_i`` = ``st.target_tensions`` (N).
- ``roll pitch yaw`` = ``st.epsilon``: the AHRS's Z-Y-X angles, yaw less its mean over the
  homing log (one yaw zero per session).
- ``session``: the run's index in :data:`RUNS`; ``time``: s since the run's first sample
  after homing; ``winch_speed`` (covariate, m/s): the largest ``|l0_i(t+0.5 s) - l0_i(t-0.5 s)|
  / 1 s``, which says whether the platform was still moving when the sample was taken.

What the files do not hold comes from the caller or from :data:`NOISE`, and every such value
is listed in :attr:`Irma4u.assumptions`.
"""

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from cstiffjax.core.errors import RecordingsError


class Irma4uError(RecordingsError):
    """An IRMA4U file that is missing or does not hold what the reader expects: the message
    names the file, the variable or field, the value and what was expected."""


class Run(NamedTuple):
    """One experiment of the repository: its name (``<name>_parsed.mat``) and the workspace
    file that holds its ``meas_idx``."""

    name: str
    workspace: str

    @property
    def log(self) -> str:
        return f"{self.name}_parsed.mat"


RUNS = (Run("sc_27_medium_a", "sc_27_medium_a_workspace.mat"),
        Run("sc_8_final", "ws_selfcalibration_8_final.mat"),
        Run("sc_27_final", "ws_selfcalibration_27_final.mat"))
"""The runs with hand-picked static samples (27 + 8 + 27 = 62), in the order of their
``session`` ids (the first was recorded days before the other two)."""

CONFIG = ("libs/config/IRMA4U_Mar25.mat", "IRMA4U_Mar25.mat")
"""Where the robot model is looked for, relative to the folder given."""

CABLES = 4
GRAVITY = (0.0, 0.0, -9.81)  # the source model's gravity wrench: -9.81 m/s^2 along base z
DEFAULT_EA = 1.0e5  # N; the source model's cables are inextensible: a placeholder
NOISE = {
    "position": 1e-3,   # m; no x y z columns: unused, required by the format
    "rotation": 1e-2,   # rad; no rx ry rz columns: unused, required by the format
    "tension": 1.0,     # N; load cells over +-0.5 s at the samples: 0.59-0.80 N median std
    "swivel": 2e-3,     # rad; swivel over +-0.5 s at the samples: 1.9-2.8e-3 rms std (still swinging)
    "ahrs": [5e-3, 5e-3, 1e-2],  # rad; AHRS over +-0.5 s: 2e-3 rms std, plus its unknown accuracy
}
"""Noise sigmas of the description (see ``irma4u.md`` for the measurements behind them)."""

_ST = ("t", "epsilon", "cable_length", "swivel", "tensions", "target_tensions")
_ROWS = {"t": 1, "epsilon": 3, "cable_length": CABLES, "swivel": CABLES, "tensions": CABLES,
         "target_tensions": CABLES}
SPEED_WINDOW = 0.5  # s each side of a sample for winch_speed


class Irma4u(NamedTuple):
    """The result of :func:`read_irma4u`.

    - ``robot``: the robot description as the tables of formats.md §1 (``robot_toml`` writes it).
    - ``columns``: recordings column name -> ``(n,)`` values, in file order.
    - ``runs``: the run name of each session id.
    - ``assumptions``: one line per value that did not come from the files.
    """

    robot: dict
    columns: dict
    runs: tuple[str, ...]
    assumptions: tuple[str, ...]


_CHILD = r"""
import pickle, sys, warnings
from scipy.io import loadmat
out = {}
for path, names in pickle.load(sys.stdin.buffer):
    print(path, file=sys.stderr, flush=True)
    try:
        got = loadmat(path, variable_names=list(names), struct_as_record=False)
        have = None
        if any(n not in got for n in names):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # MATLAB objects scipy cannot read: listed all the same
                have = sorted(k for k in loadmat(path) if not k.startswith("__"))
        out[path] = ("ok", {n: got[n] for n in names if n in got}, have)
    except Exception as e:  # a damaged file: any exception of the reader, named in the parent
        out[path] = ("v7.3" if isinstance(e, NotImplementedError) else "error", f"{type(e).__name__}: {e}", None)
sys.stdout.buffer.write(pickle.dumps(out))
"""
"""Reads MATLAB files in a child process: scipy's reader can crash the interpreter (a
segmentation fault or bus error) on a damaged file, which no ``except`` catches."""

CHILD_TIMEOUT = 300.0
"""Seconds the child reading the MATLAB files may take (the real files: about 1 s)."""


def _read_mat_files(requests: list[tuple[Path, tuple[str, ...]]]) -> dict:
    """``{path: ("ok", {name: value}, all names or None) | ("error" | "v7.3", message, None)}``
    for the existing files of ``requests``, read in one child process.

    **Raises:** :class:`Irma4uError` naming the file the reader crashed on."""
    import pickle
    import subprocess
    import sys

    requests = [(str(p), names) for p, names in requests if p.is_file()]
    if not requests:
        return {}
    try:
        done = subprocess.run([sys.executable, "-c", _CHILD], input=pickle.dumps(requests), capture_output=True,
                              timeout=CHILD_TIMEOUT, check=False)
    except subprocess.TimeoutExpired:
        raise Irma4uError(f"{requests[-1][0]}: reading the MATLAB files took over {CHILD_TIMEOUT:g} s") from None
    if done.returncode != 0:
        lines = done.stderr.decode(errors="replace").strip().splitlines()
        last = next((ln for ln in reversed(lines) if ln in {p for p, _ in requests}), requests[0][0])
        why = f"signal {-done.returncode}" if done.returncode < 0 else lines[-1] if lines else "no message"
        raise Irma4uError(f"{last}: not a readable MATLAB .mat file: the reader (scipy.io.loadmat) crashed on it "
                          f"({why}); the file is damaged or truncated: fetch it again")
    return {Path(p): v for p, v in pickle.loads(done.stdout).items()}


def _loadmat(path: Path, what: str, cache: dict) -> dict:
    """The variables of the MATLAB file ``path`` (which holds ``what``) read into ``cache`` by
    :func:`_read_mat_files`."""
    if not path.is_file() or path not in cache:
        raise FileNotFoundError(f"{path}: no such file (expected: {what})")
    status, value, have = cache[path]
    if status == "v7.3":
        raise Irma4uError(f"{path}: MATLAB v7.3 (HDF5) files are not read ({value}); save it with -v7")
    if status != "ok":
        raise Irma4uError(f"{path}: not a readable MATLAB .mat file ({what}): {value}")
    return {**value, "__path__": path, "__have__": have}


def _var(mat: dict, name: str, what: str):
    """The variable ``name`` of a :func:`_loadmat` result; missing: an error listing the file's variables."""
    if name not in mat:
        have = mat["__have__"] or []
        raise Irma4uError(f"{mat['__path__']}: no variable '{name}' ({what}); variables in the file: "
                          f"{', '.join(have) or 'none'}")
    return mat[name]


def _struct(x, where: str):
    """The MATLAB struct in ``x`` (a 1x1 struct array)."""
    a = np.asarray(x, dtype=object)
    if a.size != 1 or not hasattr(a.flat[0], "_fieldnames"):
        raise Irma4uError(f"{where}: expected a 1x1 struct, got {type(x).__name__} of shape {np.shape(x)}")
    return a.flat[0]


def _field(s, name: str, where: str):
    if name not in s._fieldnames:
        raise Irma4uError(f"{where}: no field '{name}'; fields: {', '.join(s._fieldnames)}")
    return getattr(s, name)


def _numbers(x, size: int | None, where: str) -> np.ndarray:
    """``x`` as finite float64 values (flattened), ``size`` of them when given."""
    try:
        a = np.asarray(x, dtype=float).ravel()
    except (TypeError, ValueError):
        raise Irma4uError(f"{where}: expected numbers, got {type(x).__name__}") from None
    if size is not None and a.size != size:
        raise Irma4uError(f"{where}: expected {size} numbers, got {a.size} (shape {np.shape(x)})")
    if not np.all(np.isfinite(a)):
        raise Irma4uError(f"{where}: non-finite value(s) {a[~np.isfinite(a)][:3].tolist()}")
    return a


def _cells(x, size: int, where: str) -> list:
    a = np.asarray(x, dtype=object)
    if a.dtype != object or a.size != size:
        raise Irma4uError(f"{where}: expected a cell array of {size} entries, got shape {np.shape(x)}")
    return list(a.ravel(order="F"))


def _find_config(root: Path) -> Path:
    for rel in CONFIG:
        if (root / rel).is_file():
            return root / rel
    raise FileNotFoundError(f"{root}: no robot model {' or '.join(CONFIG)} (struct s of the IRMA4U geometry)")


def read_config(path, cache: dict | None = None) -> dict:
    """The robot model ``IRMA4U_Mar25.mat`` as formats.md §1 tables (cables without ``EA``).

    **Arguments:** ``path``: the .mat file; ``cache``: its :func:`_read_mat_files` result
    when already read.

    **Returns:** ``{"platform": {mass, com, inertia}, "cables": [{anchor, attachment,
    pulley_radius, pulley_axis, swivel_zero}, ...]}`` (m, kg, kg m², unit vectors).

    **Raises:** :class:`Irma4uError` naming the file and the struct field.
    """
    path = Path(path)
    what = "struct s of the IRMA4U geometry"
    cache = _read_mat_files([(path, ("s",))]) if cache is None else cache
    s = _struct(_var(_loadmat(path, what, cache), "s", "the robot model"), f"{path}: s")
    plat = _struct(_field(_struct(_field(s, "EndEffector", f"{path}: s"), f"{path}: s.EndEffector"), "Platform",
                          f"{path}: s.EndEffector"), f"{path}: s.EndEffector.Platform")
    w = f"{path}: s.EndEffector.Platform"
    mass = _numbers(_field(plat, "m", w), 1, f"{w}.m")[0]
    if mass <= 0:
        raise Irma4uError(f"{w}.m: value {mass!r}: the platform mass must be > 0 (kg)")
    inertia = _numbers(_field(plat, "InertialMatrix", w), 9, f"{w}.InertialMatrix").reshape(3, 3)
    points = [_numbers(p, 3, f"{w}.points{{{i}}}") for i, p in
              enumerate(_cells(_field(plat, "points", w), CABLES, f"{w}.points"), 1)]
    tr = _struct(_field(s, "Trasmission", f"{path}: s"), f"{path}: s.Trasmission")
    cables = []
    for i, pul in enumerate(_cells(_field(tr, "Pulley", f"{path}: s.Trasmission"), CABLES,
                                   f"{path}: s.Trasmission.Pulley"), 1):
        w = f"{path}: s.Trasmission.Pulley{{{i}}}"
        pul = _struct(pul, w)
        r = _numbers(_field(pul, "r", w), 1, f"{w}.r")[0]
        if r < 0:
            raise Irma4uError(f"{w}.r: value {r!r}: a pulley radius must be >= 0 (m)")
        x, y, z = (_numbers(v, 3, f"{w}.FixedFrame{{{j}}}") for j, v in
                   enumerate(_cells(_field(pul, "FixedFrame", w), 3, f"{w}.FixedFrame"), 1))
        frame = np.stack([x, y, z], 1)
        if not np.allclose(frame.T @ frame, np.eye(3), atol=1e-9) or np.linalg.det(frame) < 0:
            raise Irma4uError(f"{w}.FixedFrame: {frame.T.tolist()} is not a right-handed orthonormal frame "
                              f"(x_i, y_i, z_i with x_i × y_i = z_i): the swivel angle's sign would be undefined")
        cables.append({"anchor": _numbers(_field(pul, "CableEnterPosition", w), 3, f"{w}.CableEnterPosition"),
                       "attachment": points[i - 1], "pulley_radius": float(r), "pulley_axis": z, "swivel_zero": x})
    return {"platform": {"mass": float(mass), "com": _numbers(_field(plat, "PtoG", f"{path}: s.EndEffector.Platform"),
                                                               3, f"{path}: s.EndEffector.Platform.PtoG"),
                         "inertia": inertia},
            "cables": cables}


def _run_signals(root: Path, run: Run, notes: list[str], cache: dict) -> tuple[dict, np.ndarray, Path]:
    """``st`` of ``run`` as ``{field: (rows, n)}`` and its picked 0-based sample indices.

    The log ``<run>_parsed.mat`` must be the run's own: when the workspace file holds a copy
    of ``st`` (the real repository's do), the log must equal it, or the log is refused."""
    ws_path, log_path = root / run.workspace, root / run.log
    ws = _loadmat(ws_path, f"meas_idx of run {run.name}", cache)
    idx = _var(ws, "meas_idx", f"the indices of the static samples of run {run.name}")
    copy = _signals(_struct(ws["st"], f"{ws_path}: st"), ws_path) if "st" in ws else None
    if log_path.is_file():
        st = _var(_loadmat(log_path, f"the log of run {run.name}", cache), "st", "the processed log")
        sig, src = _signals(_struct(st, f"{log_path}: st"), log_path), log_path
        if copy is not None:
            _same_run(sig, copy, log_path, ws_path, run)
        else:
            notes.append(f"run {run.name}: {run.workspace} holds no copy of st to confirm that {run.log} is "
                         f"this run's log")
    elif copy is not None:
        sig, src = copy, ws_path
        notes.append(f"run {run.name}: signals from the copy of st in {run.workspace} ({run.log} is absent)")
    else:
        raise FileNotFoundError(f"{log_path}: no such file (the processed log st of run {run.name}), and "
                                f"{ws_path} holds no copy of st")
    n = sig["t"].shape[1]
    where = f"{ws_path}: meas_idx"
    k = _numbers(idx, None, where) if np.size(idx) else np.zeros(0)
    if k.size == 0 or np.any(k != np.round(k)) or k.min() < 1 or k.max() > n:
        raise Irma4uError(f"{where}: values {k.tolist()[:5]}...: expected whole numbers in 1..{n} "
                          f"(MATLAB indices of the {n} samples of st in {src.name})")
    if np.any(np.diff(k) <= 0):
        raise Irma4uError(f"{where}: not increasing at position {int(np.argmax(np.diff(k) <= 0)) + 2} "
                          f"(the samples must be in the order they were taken)")
    return sig, k.astype(int) - 1, src


def _signals(st, src: Path) -> dict:
    """The fields :data:`_ST` of the struct ``st`` (read from ``src``) as float arrays ``(rows, n)``;
    ``st.t`` finite and increasing (the app's clock)."""
    sig = {}
    for name in _ST:
        where = f"{src}: st.{name}"
        value = _field(st, name, f"{src}: st")
        try:
            a = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            kind = {"U": "text", "O": "cells or structs"}.get(np.asarray(value).dtype.kind, type(value).__name__)
            raise Irma4uError(f"{where}: expected a numeric array, got {kind} of shape {np.shape(value)}") from None
        n = sig["t"].shape[1] if sig else (a.shape[-1] if a.ndim == 2 else -1)
        if a.shape != (_ROWS[name], n):
            raise Irma4uError(f"{src}: st.{name} has shape {a.shape}; expected ({_ROWS[name]}, "
                              f"{n if n >= 0 else 'n'}) (one column per sample of st.t)")
        sig[name] = a
    t = sig["t"][0]
    if t.size == 0 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        bad = int(np.argmax(~np.isfinite(t) | np.r_[False, np.diff(t) <= 0])) if t.size else 0
        raise Irma4uError(f"{src}: st.t(1, {bad + 1}) = {t[bad] if t.size else '(empty)'}: the log's clock must "
                          f"hold finite, increasing times (s); the log is damaged")
    return sig


def _same_run(log: dict, copy: dict, log_path: Path, ws_path: Path, run: Run) -> None:
    """Refuse a log that is not the copy of ``st`` its run's workspace file holds."""
    for name in _ST:
        a, b = log[name], copy[name]
        if a.shape != b.shape or not np.array_equal(a, b, equal_nan=True):
            said = (f"{a.shape[1]} samples from t = {log['t'][0, 0]:.6g} s, the workspace's copy {b.shape[1]} "
                    f"from t = {copy['t'][0, 0]:.6g} s" if name == "t" or a.shape != b.shape else
                    f"st.{name} differs (first at sample {int(np.argmax(np.any(a != b, axis=0))) + 1})")
            raise Irma4uError(f"{log_path}: not the log of run {run.name}: {run.workspace}, which holds the run's "
                              f"static sample indices, holds a copy of st that differs from it ({said}). Put the "
                              f"run's own {run.log} there, or remove it to read the workspace's copy")


def _distinct_runs(firsts: dict) -> None:
    """Refuse two runs whose logs are one and the same (``firsts``: run -> (log path, st.t))."""
    runs = list(firsts)
    for i, r in enumerate(runs):
        for q in runs[i + 1:]:
            (pr, tr), (pq, tq) = firsts[r], firsts[q]
            if tr.shape == tq.shape and np.array_equal(tr, tq):
                raise Irma4uError(f"{pq}: the log of run {q} has the same {tq.size} sample times as {pr}, the log "
                                  f"of run {r}: one run's log copied under another run's name")


def _speed(t: np.ndarray, lengths: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Largest ``|l(t+w) - l(t-w)| / 2w`` over the cables at the samples ``idx`` (m/s), ``w`` =
    :data:`SPEED_WINDOW` clipped to the log."""
    w = SPEED_WINDOW + 1e-6  # a sample logged 0.5 s away, up to rounding, is in the window
    lo = np.searchsorted(t, t[idx] - w)
    hi = np.searchsorted(t, t[idx] + w, side="right") - 1
    dt = np.where(t[hi] > t[lo], t[hi] - t[lo], np.inf)
    return np.max(np.abs(lengths[:, hi] - lengths[:, lo]), axis=0) / dt


def read_irma4u(path, *, ea: float = DEFAULT_EA, mass_per_length: float = 0.0, name: str = "irma4u") -> Irma4u:
    """Read the IRMA4U model and the 62 picked samples of :data:`RUNS` (formats.md §1/§2, version 3).

    **Arguments:**

    - ``path``: a checkout of ``fzoffoli/UACDPR_SelfCalibration``, or a folder holding
      ``IRMA4U_Mar25.mat`` and the run files side by side.
    - ``ea``: axial stiffness E·A of every cable, N (the source's cables are inextensible).
    - ``mass_per_length``: kg/m of every cable (the source's cables are massless).
    - ``name``: the robot name.

    **Returns:** an :class:`Irma4u`.

    **Raises:** ``FileNotFoundError`` naming a missing file and what it should hold;
    :class:`Irma4uError` naming the file, variable or field and the value; ``ValueError`` for
    a bad argument.
    """
    if not (math.isfinite(ea) and ea > 0):
        raise ValueError(f"EA = {ea!r} must be a finite number > 0 (N)")
    if not (math.isfinite(mass_per_length) and mass_per_length >= 0):
        raise ValueError(f"mass_per_length = {mass_per_length!r} must be a finite number >= 0 (kg/m)")
    root = Path(path)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: not a folder (expected a checkout of fzoffoli/UACDPR_SelfCalibration)")
    config = _find_config(root)
    cache = _read_mat_files([(config, ("s",)), *((root / r.workspace, ("meas_idx", "st")) for r in RUNS),
                             *((root / r.log, ("st",)) for r in RUNS)])
    model = read_config(config, cache)
    notes = [f"EA = {ea:g} N for every cable" + (" (a placeholder: the source's cables are inextensible)"
                                                   if ea == DEFAULT_EA else " (given)"),
             f"mass_per_length = {mass_per_length:g} kg/m" + (" (the source's cables are massless)"
                                                              if mass_per_length == 0 else " (given)"),
             "gravity [0, 0, -9.81] m/s^2 (the source model's)",
             "noise sigmas " + ", ".join(f"{k} {v}" for k, v in NOISE.items())
             + " (m, rad, N; position and rotation unused: no pose columns)",
             "AHRS mounted aligned with the platform frame (ahrs_mounting = [0, 0, 0]; the source gives none)"]
    cols = {c: [] for c in ("session", "time", *_names("l0"), *_names("t"), *_names("swivel"),
                            "roll", "pitch", "yaw", *_names("t_set"), "winch_speed")}
    firsts = {}
    for session, run in enumerate(RUNS):
        sig, idx, src = _run_signals(root, run, notes, cache)
        t = firsts.setdefault(run.name, (src, sig["t"][0]))[1]
        for field in ("cable_length", "swivel", "tensions", "epsilon"):
            bad = ~np.isfinite(sig[field][:, idx])
            if bad.any():
                i, j = np.argwhere(bad)[0]
                raise Irma4uError(f"{src}: st.{field}({i + 1}, {idx[j] + 1}) = {sig[field][i, idx[j]]} at picked "
                                  f"sample {j + 1} of run {run.name}: not a number")
        if np.any(sig["cable_length"][:, idx] <= 0):
            i, j = np.argwhere(sig["cable_length"][:, idx] <= 0)[0]
            raise Irma4uError(f"{src}: st.cable_length({i + 1}, {idx[j] + 1}) = {sig['cable_length'][i, idx[j]]!r}: "
                              f"a cable length must be > 0 (m)")
        cols["session"].append(np.full(idx.size, float(session)))
        cols["time"].append(t[idx] - t[0])
        for prefix, field in (("l0", "cable_length"), ("t", "tensions"), ("swivel", "swivel"),
                              ("t_set", "target_tensions")):
            for i, c in enumerate(_names(prefix)):
                cols[c].append(sig[field][i, idx])
        for i, c in enumerate(("roll", "pitch", "yaw")):
            cols[c].append(sig["epsilon"][i, idx])
        cols["winch_speed"].append(_speed(t, sig["cable_length"], idx))
    _distinct_runs(firsts)
    columns = {c: np.concatenate(v) for c, v in cols.items()}
    cables = [{"anchor": c["anchor"], "attachment": c["attachment"], "EA": float(ea),
               "mass_per_length": float(mass_per_length), "pulley_radius": c["pulley_radius"],
               "pulley_axis": c["pulley_axis"], "swivel_zero": c["swivel_zero"]} for c in model["cables"]]
    robot = {"kind": "cdpr", "name": name, "gravity": list(GRAVITY), "platform": model["platform"],
             "noise": dict(NOISE), "sensors": {"lengths": "relative", "ahrs_mounting": [0.0, 0.0, 0.0]},
             "cables": cables}
    return Irma4u(robot, columns, tuple(r.name for r in RUNS), tuple(notes))


def _names(prefix: str) -> tuple[str, ...]:
    return tuple(f"{prefix}_{i}" for i in range(1, CABLES + 1))


def _toml_value(v) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    a = np.asarray(v, dtype=float)
    if a.ndim == 0:
        return repr(float(a))
    return "[" + ", ".join(_toml_value(x) for x in a) + "]"


def robot_toml(data: Irma4u) -> str:
    """The robot description of ``data`` as TOML text (formats.md §1, version 3), with comments
    saying where each value came from and which session id is which run."""
    r = data.robot
    head = ["# IRMA4U (University of Bologna), converted from the MATLAB model IRMA4U_Mar25.mat of",
            "# github.com/fzoffoli/UACDPR_SelfCalibration (no licence file: ask the authors before redistributing).",
            "# Recordings sessions: " + ", ".join(f"{i} = {n}" for i, n in enumerate(data.runs)) + ".",
            *(f"# assumed: {a}" for a in data.assumptions), ""]
    out = [*head, f"kind = {_toml_value(r['kind'])}", f"name = {_toml_value(r['name'])}",
           f"gravity = {_toml_value(r['gravity'])}", "", "[platform]"]
    out += [f"{k} = {_toml_value(v)}" for k, v in r["platform"].items()]
    out += ["", "[noise]"] + [f"{k} = {_toml_value(v)}" for k, v in r["noise"].items()]
    out += ["", "[sensors]"] + [f"{k} = {_toml_value(v)}" for k, v in r["sensors"].items()]
    for c in r["cables"]:
        out += ["", "[[cables]]"] + [f"{k} = {_toml_value(v)}" for k, v in c.items()]
    return "\n".join(out) + "\n"
