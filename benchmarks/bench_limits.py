"""The toolkit's limits: what works, and where it stops with a clear message (run:
``python benchmarks/bench_limits.py [--cases GROUP ...] [--out benchmarks/LIMITS.md]``).

Every case runs the command line (``python -m cstiffjax.commands.cli ...``) in its own
process under a watchdog (:func:`run_watched`): a wall-clock limit, and a *stall* check, a
process whose CPU time stops growing for ``--stall`` seconds is idle and will never return
(the jaxlib deadlock of :mod:`cstiffjax.core.linalg`). Each run is recorded as it ended
(wall time, peak resident memory of the process from ``os.wait4``'s ``getrusage`` record,
the line that states its outcome) and judged: ``works`` (exit 0 and the expected outcome),
``clear error`` (exit 1 or 2 with ``error:`` and the expected words), or a failure: ``hang``,
``timeout``, ``crash`` (a traceback or another exit code), ``unexpected`` (a run that ended
but not as expected: a wrong "ok" or a wrong error). The table goes to ``--out`` with the
machine and the date.

Groups (``--cases``): ``samples`` (1, 2, 6 000 and 20 000 samples: the bundled example02
tiled), ``cables`` (3 to 16 cables: 3-5 are checked as under-constrained, suspended robots;
the stiffness of a redundant ring also at its first recorded pose: no tensions hold its centre),
``stiffness`` (EA from 1e2 to 1e12 N), ``size`` (cables from 1 cm to 1 km), ``slack`` (near-
zero tensions), ``onepose`` (every sample at one pose), ``input`` (a NaN pose, an attachment
on its anchor), ``scale`` (6 000 distinct on-board samples, 100 000 rows, CASPR files of
40 000, 50 001 and 90 000 cables: ``limits_scale.py`` beside this file). The data of the groups
``cables``, ``stiffness``, ``size`` and ``slack`` are simulated here (:func:`simulate`):
consistent with the robot description, so a fit must reach chi2/dof ~ 1 and a diagnosis must
find nothing missing.
"""

import argparse
import dataclasses
import datetime
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "cstiffjax" / "examples" / "example02"
STALL_S = 90.0  # no CPU progress for this long: idle for good (a deadlock)
TIMEOUT_S = 3600.0


# ------------------------------------------------------------------------ watchdog
@dataclasses.dataclass
class Outcome:
    """How one process ended: ``how`` is ``"exit"``, ``"hang"`` (no CPU progress for the
    stall time: killed) or ``"timeout"`` (killed at the wall-clock limit); ``rc`` its exit
    code (None when killed); ``wall_s``, ``cpu_s`` seconds; ``peak_mb`` its peak resident
    memory (MiB); ``output`` stdout and stderr together."""

    how: str
    rc: int | None
    wall_s: float
    cpu_s: float
    peak_mb: float
    output: str


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far, s (Linux ``/proc``; 0 when gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_watched(argv, timeout_s: float = TIMEOUT_S, stall_s: float = STALL_S, env=None, cwd=None,
                poll_s: float = 0.5) -> Outcome:
    """Run ``argv`` and wait for it under a watchdog: killed when its CPU time grows by
    less than 1 % of ``stall_s`` over ``stall_s`` seconds (a process that is idle for that
    long is waiting on something that will not come: a deadlock, whatever the machine's
    load) or when it runs past ``timeout_s``.

    **Returns:** an :class:`Outcome` (peak memory and CPU time from ``os.wait4``).
    """
    with tempfile.TemporaryFile(mode="w+") as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=cwd)
        start = time.monotonic()
        history = [(start, 0.0)]  # (time, CPU seconds), from the last one older than the stall window on
        how = "exit"
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            now = time.monotonic()
            cpu = _cpu_seconds(proc.pid)
            history.append((now, cpu))
            old = [h for h in history if h[0] <= now - stall_s]
            history = history[max(len(old) - 1, 0):]
            if now - start > timeout_s:
                how = "timeout"
            elif old and cpu - old[-1][1] < 0.01 * stall_s:
                how = "hang"
            if how != "exit":
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(poll_s)
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait again
        out.seek(0)
        text = out.read()
    return Outcome(how, proc.returncode if how == "exit" else None, time.monotonic() - start,
                   usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0, text)


def cli(*args) -> list[str]:
    """The command line ``cstiffjax ARGS`` as an argv (this interpreter)."""
    return [sys.executable, "-m", "cstiffjax.commands.cli", *map(str, args)]


def environment() -> dict:
    """The subprocesses' environment: this checkout first on ``PYTHONPATH``, caches off
    (every run compiles, as a first run does), no progress bars."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    env["CSTIFFJAX_CACHE_DIR"] = "off"
    return env


# ------------------------------------------------------------------------ data
def tiled_recordings(n: int, path, rows=None) -> Path:
    """example02's recordings tiled (or cut) to ``n`` samples, times increasing: ``rows``
    (0-based) picks which of its rows repeat (default all). Plain text, no JAX."""
    lines = (EXAMPLE / "recordings.csv").read_text().strip().splitlines()
    header, data = lines[0], lines[1:]
    data = [data[i] for i in rows] if rows is not None else data
    out = [header]
    for i in range(n):
        fields = data[i % len(data)].split(",")
        fields[0] = f"{100.0 + 60.0 * i:.3f}"
        out.append(",".join(fields))
    Path(path).write_text("\n".join(out) + "\n")
    return Path(path)


def ring_robot(m: int, *, ea: float = 1e6, scale: float = 1.0, mass: float = 30.0):
    """A robot of ``m`` cables (m >= 6) around a ring of radius 2 m: 6 cables from the top
    (a suspended robot); more cables alternate between the top (z = 3 m) and the floor,
    attachments on a 0.2 m platform turned by 60 degrees (and, beyond 6 cables, by a further
    0.3 rad on every second and third: the symmetric ring is singular at the centre). ``scale`` multiplies
    every length (anchors, attachments, the position noise); ``ea`` N, ``mass`` kg. Tensions
    within [0, 5 kN]: the simulated data stay within them, and the default tensions of ``stiffness``
    on a redundant ring lie mid-range."""
    import numpy as np

    from cstiffjax.io.robot import CableRobot, Noise

    k = np.arange(m)
    top = np.ones(m, bool) if m == 6 else (k % 2 == 0)
    th = 2 * np.pi * k / m
    anchors = np.stack([2.0 * np.cos(th), 2.0 * np.sin(th), np.where(top, 3.0, 0.0)], 1)
    ph = th + np.pi / 3 * np.where(k % 2 == 0, 1, -1) + (0.3 * (k % 3) if m > 6 else 0.0)
    attachments = np.stack([0.2 * np.cos(ph), 0.2 * np.sin(ph), np.where(top, 0.05, -0.05)], 1)
    return CableRobot(anchors=scale * anchors, attachments=scale * attachments, EA=np.full(m, ea),
                      mass_per_length=np.zeros(m), platform_mass=mass, com=np.zeros(3), inertia=np.eye(3),
                      gravity=np.array([0.0, 0.0, -9.81]), tension_min=0.0, tension_max=5e3,
                      noise=Noise(position=2e-5 * scale, rotation=5e-5, tension=0.3 * min(1.0, mass / 30.0)),
                      name=f"ring{m}")


def simulate(robot, n: int, folder, *, centre, half, pretension: float, seed: int = 0) -> None:
    """Write ``folder/robot.toml`` and ``folder/recordings.csv``: ``n`` samples at random
    poses within ``centre ± half`` (m; rotations within ±0.02 rad), no external load; the
    commanded lengths hold each pose with the tensions closest to ``pretension`` N
    (weight balanced); the platform then settles by cold-start forward statics (its status
    checked), and the robot's ``[noise]`` sigmas are added. Poses whose tensions would fall
    below a quarter of the smallest positive one, or rise above half of the robot's
    ``tension_max``, are drawn again (:func:`_tensions`)."""
    import jax
    import numpy as np

    from cstiffjax.core.status import to_codes
    from cstiffjax.io.robot_io import save_robot
    from cstiffjax.statics import forward, geometry
    from fitting.synth.generate import write_recordings

    rng = np.random.default_rng(seed)
    m = robot.num_cables
    poses, l0s = [], []
    floor = None
    tries = 0
    while len(poses) < n:
        tries += 1
        if tries > 200 * n:
            raise RuntimeError(f"{robot.name}: no pose with positive tensions in {tries - 1} random poses")
        pose = np.concatenate([np.asarray(centre) + rng.uniform(-1, 1, 3) * np.asarray(half),
                               rng.uniform(-0.02, 0.02, 3)])
        S = np.asarray(geometry.structure_matrix_closed_form(robot, pose))
        w = np.asarray(geometry.gravity_wrench(robot, pose))
        t = _tensions(S, w, pretension, float(robot.tension_max))
        if t is None:
            continue
        floor = 0.25 * t.min() if floor is None and t.min() > 0 else floor
        if floor is None or t.min() < floor:
            continue
        L = np.asarray(geometry.cable_lengths(robot, pose))
        poses.append(pose)
        l0s.append(L * np.asarray(robot.EA) / (np.asarray(robot.EA) + t))
    l0 = np.array(l0s)

    def settle(l, p):
        return forward.forward_statics(forward.StaticsProblem(robot, l, None), pose0=p, throw=False)

    fs = jax.jit(jax.vmap(settle))(l0, np.array(poses))
    failed = int(np.sum(np.asarray(to_codes(fs.result)) != 0))
    if failed:
        raise RuntimeError(f"forward statics failed on {failed} samples")
    pose = np.asarray(fs.pose) + np.concatenate([rng.normal(0, float(robot.noise.position), (n, 3)),
                                                 rng.normal(0, float(robot.noise.rotation), (n, 3))], 1)
    ten = np.asarray(fs.tensions) + rng.normal(0, float(robot.noise.tension), (n, m))
    cols = {"time": 100.0 + 60.0 * np.arange(n)}
    cols.update({f"l0_{i + 1}": l0[:, i] for i in range(m)})
    cols.update({c: np.zeros(n) for c in ("fx", "fy", "fz", "mx", "my", "mz")})
    cols.update({c: pose[:, j] for j, c in enumerate(("x", "y", "z", "rx", "ry", "rz"))})
    cols.update({f"t_{i + 1}": ten[:, i] for i in range(m)})
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    save_robot(robot, folder / "robot.toml")
    write_recordings(cols, folder / "recordings.csv")


def _tensions(S, w, pretension: float, tension_max: float):
    """Tensions ``t`` (m,) with ``S t + w = 0`` and none above half of ``tension_max`` (a
    margin: the recorded pose is not the commanded one): for 6 cables the one solution; with
    more, the one closest to ``pretension`` on every cable, or, when that has a cable below a
    quarter of ``pretension`` (or above the half), the least total tension with every cable
    within [a quarter of ``pretension``, half of ``tension_max``] (a
    linear program: the pretension's projection alone leaves some cable of a redundant ring
    slack at most poses, and rejection of those poses alone never ends). ``None`` when no
    such tensions exist."""
    import numpy as np
    from scipy.optimize import linprog

    m = S.shape[1]
    top = 0.5 * tension_max
    tc = np.full(m, pretension)
    t = tc - np.linalg.pinv(S) @ (S @ tc + w)
    if m == 6 or pretension <= 0 or (t.min() >= 0.25 * pretension and t.max() <= top):
        return t if t.max() <= top else None
    lp = linprog(np.ones(m), A_eq=S, b_eq=-w, bounds=[(0.25 * pretension, top)] * m, method="highs")
    return lp.x if lp.status == 0 else None


def _prepare(kind: str, value: float, folder: str) -> None:
    """The data of one case (run in its own watched process: ``--prepare KIND VALUE DIR``)."""
    import cstiffjax  # noqa: F401  (float64)

    if kind == "cables":
        m = int(value)
        simulate(ring_robot(m), 60, folder, centre=(0, 0, 1.5), half=(0.3, 0.3, 0.3), pretension=200.0)
    elif kind == "ea":
        simulate(ring_robot(6, ea=value), 60, folder, centre=(0, 0, 1.5), half=(0.3, 0.3, 0.3), pretension=0.0)
    elif kind == "size":
        simulate(ring_robot(8, scale=value), 60, folder, centre=(0, 0, 1.5 * value), half=(0.3 * value,) * 3,
                 pretension=200.0)
    elif kind in ("onboard", "caspr"):
        sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository, for `python benchmarks/...`
        from benchmarks import limits_scale

        (limits_scale.onboard_samples if kind == "onboard" else limits_scale.caspr_files)(int(value), folder)
    elif kind == "slack":  # a platform of 1 g and no pretension: tensions of a few mN
        simulate(ring_robot(6, mass=1e-3), 60, folder, centre=(0, 0, 1.5), half=(0.3, 0.3, 0.3), pretension=0.0)
    else:
        raise ValueError(f"unknown kind {kind!r}")


# ------------------------------------------------------------------------ cases
@dataclasses.dataclass
class Run:
    """One command of a case: ``expect`` ``"ok"`` (exit 0, and ``check`` found in the
    output when given), ``"error"`` (exit 1 or 2, ``check`` found in the error message) or
    ``"either"`` (one of the two: a case at the edge of what the data can support)."""

    group: str
    case: str
    command: str
    argv: list | Callable[[], list]  # a callable: the argv depends on data a preparation run writes
    expect: str = "ok"
    check: str | None = None
    outcome: Outcome | None = None

    def verdict(self) -> str:
        o = self.outcome
        if o is None:
            return "not run"
        if o.how != "exit":
            return o.how
        if "Traceback (most recent call last)" in o.output:
            return "crash"
        found = self.check is None or re.search(self.check, o.output) is not None
        if self.expect in ("ok", "either") and o.rc == 0 and found:
            return "works"
        if self.expect in ("error", "either") and o.rc in (1, 2) and "error:" in o.output and found:
            return "clear error"
        return "unexpected"

    def line(self) -> str:
        """The output line that states the outcome (an error, a verdict, chi2/dof)."""
        text = self.outcome.output if self.outcome else ""
        for pattern in (r"^.*error:.*$", r"^effects: .*$", r"^chi2/dof = .*$", r"^\s*sagging\s+\(total\).*$",
                        r"^translation eigen-stiffnesses.*\n.*$", r"^.*status: .*$", r"^tensions.*$"):
            hits = re.findall(pattern, text, flags=re.M)
            if hits:
                return " ".join(hits[-1].split())[:150]
        tail = [s for s in text.strip().splitlines() if s.strip()]
        return " ".join(tail[-1].split())[:150] if tail else ""


PREPARE = ("simulate", "generate")  # runs that write a case's data
CONSISTENT_FIT = r"chi2/dof = (0\.[5-9]|1\.[0-4])"  # consistent data: explained down to the noise
NOTHING_MISSING = r"effects: none; explained: true"


def cases(groups, work: Path) -> list[Run]:
    """The runs of ``groups`` with their data folders under ``work`` (data made by ``prepare``
    runs listed first; a failed preparation skips its case's commands)."""
    runs = []
    robot = EXAMPLE / "robot.toml"
    if "samples" in groups:
        for n in (1, 2, 6000, 20000):
            rec = tiled_recordings(n, work / f"samples{n}.csv")
            few = "either" if n <= 2 else "ok"
            runs.append(Run("samples", f"{n} samples", "fit", cli("fit", robot, rec, "--quiet"), expect=few,
                            check=CONSISTENT_FIT if n > 2 else None))
            runs.append(Run("samples", f"{n} samples", "diagnose", cli("diagnose", robot, rec, "--quiet"),
                            expect=few, check=NOTHING_MISSING if n > 2 else None))
        gen = work / "distinct20000"  # 20 000 distinct samples: clean data from the generator
        case = "20 000 distinct samples (generated, proto_clean)"
        runs.append(Run("samples", case, "generate", cli("generate", "--out", gen, "--samples", 20000, "--cases",
                                                         "proto_clean", "--quiet")))
        for cmd in ("fit", "diagnose"):
            runs.append(Run("samples", case, cmd, cli(cmd, gen / "proto_clean" / "robot.toml",
                                                      gen / "proto_clean" / "recordings.csv", "--quiet"),
                            check=CONSISTENT_FIT if cmd == "fit" else NOTHING_MISSING))
    if "onepose" in groups:
        rec = tiled_recordings(90, work / "onepose.csv", rows=[0])
        runs.append(Run("onepose", "90 samples at one pose", "fit", cli("fit", robot, rec, "--quiet"),
                        expect="either"))
        runs.append(Run("onepose", "90 samples at one pose", "diagnose", cli("diagnose", robot, rec, "--quiet"),
                        expect="either"))
    if "cables" in groups:
        for m in (3, 4, 5):
            path = work / f"cables{m}.toml"
            text = robot.read_text().split("[[cables]]")
            path.write_text(text[0] + "[[cables]]" + "[[cables]]".join(text[1:m + 1]))
            runs.append(Run("cables", f"{m} cables", "check", cli("check", path), expect="ok",
                            check="under-constrained, the platform's weight closes the equilibrium"))
        for m in (6, 7, 8, 12, 16):
            runs += _simulated("cables", f"{m} cables", work / f"cables{m}", "cables", m, (0, 0, 1.5))
    if "stiffness" in groups:
        for ea in (1e2, 1e4, 1e6, 1e8, 1e10, 1e12):
            runs += _simulated("stiffness", f"EA = {ea:.0e} N", work / f"ea{ea:.0e}", "ea", ea, (0, 0, 1.5),
                               diagnose=True)
    if "size" in groups:
        for s in (0.005, 0.1, 1.0, 10.0, 400.0):
            runs += _simulated("size", f"cables ~{2.5 * s:g} m", work / f"size{s:g}", "size", s, (0, 0, 1.5 * s))
    if "slack" in groups:
        runs += _simulated("slack", "1 g platform (tensions ~ mN)", work / "slack", "slack", 0, (0, 0, 1.5))
    if "scale" in groups:
        runs += _scale(work, robot)
    if "input" in groups:
        nan_pose = ("--pose", "nan", "0", "0.5", "0", "0", "0")
        for cmd in ("sag", "stiffness"):
            runs.append(Run("input", "NaN pose", cmd, cli(cmd, robot, *nan_pose), expect="error",
                            check="not a finite number"))
        for cmd in ("sag", "stiffness", "frf"):
            runs.append(Run("input", "attachment on its anchor", cmd, cli(cmd, robot, "--pose", *_on_anchor_pose()),
                            expect="error", check="zero length"))
    return runs


def _scale(work: Path, robot: Path) -> list[Run]:
    """6 000 distinct on-board samples of onboard4 (fit, diagnose: the load cells' gain found),
    100 000 rows (example02 tiled: check, fit) and CASPR files of 40 000 cables (converted), 50 001
    cables (refused at :data:`cstiffjax.io.caspr.MAX_CABLES`) and 90 000 cables (35 MB: refused
    before it is read, :data:`cstiffjax.io.caspr.MAX_FILE_BYTES`)."""
    me = [sys.executable, str(Path(__file__).resolve()), "--prepare"]
    ob, case = work / "onboard6000", "6 000 distinct on-board samples (onboard4)"
    runs = [Run("scale", case, "generate", [*me, "onboard", "6000", str(ob)])]
    for cmd, check in (("fit", r"chi2/dof = "), ("diagnose", r"effects: \['tension_sensor_gain'\]; explained: true")):
        runs.append(Run("scale", case, cmd, cli(cmd, ob / "robot.toml", ob / "recordings.csv", "--quiet"),
                        check=check))
    rec = tiled_recordings(100_000, work / "rows100000.csv")
    runs += [Run("scale", "100 000 rows (example02 tiled)", "check", cli("check", robot, rec, "--quiet")),
             Run("scale", "100 000 rows (example02 tiled)", "fit", cli("fit", robot, rec, "--quiet"),
                 check=CONSISTENT_FIT)]
    for n, expect, check in ((40_000, "ok", r"wrote "), (50_001, "error", r"more than 50000 cables"),
                             (90_000, "error", r"larger than the reader's limit")):
        folder, case = work / f"caspr{n}", f"CASPR cables file of {n:,} cables".replace(",", " ")
        runs += [Run("scale", case, "generate", [*me, "caspr", str(n), str(folder)]),
                 Run("scale", case, "convert", cli("convert", folder / "big_bodies.xml", folder / "big_cables.xml",
                                                   "--ea", "1e6", "--out", folder / "robot.toml"),
                     expect=expect, check=check)]
    return runs


def _on_anchor_pose() -> list[str]:
    """A pose (no rotation) that puts example02's attachment 1 exactly on its anchor."""
    import tomllib

    cable = tomllib.loads((EXAMPLE / "robot.toml").read_text())["cables"][0]
    return [f"{a - b:.6g}" for a, b in zip(cable["anchor"], cable["attachment"])] + ["0", "0", "0"]


def _simulated(group, case, folder: Path, kind, value, centre, diagnose=False) -> list[Run]:
    """A preparation run, then fit (consistent data: chi2/dof ~ 1), stiffness and sag at
    the workspace centre (and, on a ring of more than 6 cables, which no tensions hold at its
    centre, also at the first recorded pose, where the data's tensions are at least 50 N)
    and, with ``diagnose``, a diagnosis (nothing missing)."""
    prep = [sys.executable, str(Path(__file__).resolve()), "--prepare", kind, str(value), str(folder)]
    robot, rec = folder / "robot.toml", folder / "recordings.csv"
    pose = ["--pose", *(f"{c:g}" for c in centre), "0", "0", "0"]
    runs = [Run(group, case, "simulate", prep),
            Run(group, case, "fit", cli("fit", robot, rec, "--quiet"), check=CONSISTENT_FIT),
            # the stiffness needs tensions within the limits at that pose: a ring of more than 6
            # cables has none at its centre, which the command must say (a clear error)
            Run(group, case, "stiffness", cli("stiffness", robot, *pose), expect="either",
                check=r"translation eigen-stiffnesses|no feasible tensions at pose"),
            Run(group, case, "sag", cli("sag", robot, *pose), expect="either",
                check=r"exit-point tensions|no cable tensions >= \S+ N hold this pose")]
    if (kind == "cables" and value > 6) or kind == "size":  # the size group's rings have 8 cables
        runs += [Run(group, case, "stiffness at sample 1", lambda: cli("stiffness", robot, "--pose", *_first_pose(rec)),
                     check="translation eigen-stiffnesses"),
                 Run(group, case, "sag at sample 1", lambda: cli("sag", robot, "--pose", *_first_pose(rec)))]
    if diagnose:
        runs.append(Run(group, case, "diagnose", cli("diagnose", robot, rec, "--quiet"), check=NOTHING_MISSING))
    return runs


def _first_pose(rec: Path) -> list[str]:
    """The measured pose (x y z m, rx ry rz rad) of the first sample of recordings ``rec``."""
    header, first = rec.read_text().splitlines()[:2]
    row = dict(zip(header.split(","), first.split(","), strict=True))
    return [row[c] for c in ("x", "y", "z", "rx", "ry", "rz")]


# ------------------------------------------------------------------------ report
def table(runs) -> str:
    rows = ["| group | case | command | outcome | wall s | peak MiB | what it said |", "|---|---|---|---|---|---|---|"]
    for r in runs:
        o = r.outcome
        wall = f"{o.wall_s:.0f}" if o else ""
        mem = f"{o.peak_mb:.0f}" if o else ""
        rows.append(f"| {r.group} | {r.case} | {r.command} | {r.verdict()} | {wall} | {mem} | "
                    f"{r.line().replace('|', '/')} |")
    return "\n".join(rows)


def machine() -> str:
    from importlib import metadata

    import jax

    cpus = os.cpu_count()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{platform.processor() or platform.machine()}, {cpus} CPU cores (load average {load:.1f} at the end), "
            f"Python {platform.python_version()}, jax {jax.__version__}, jaxlib {metadata.version('jaxlib')}, "
            f"{platform.system()} {platform.release()}")


def _load(path) -> dict:
    """Recorded outcomes ``{"group/case/command": Outcome fields}`` of ``--results``."""
    if path is None or not Path(path).exists():
        return {}
    return json.loads(Path(path).read_text())


def _killed_from_outside(o: Outcome) -> bool:
    """Ended by a signal this script did not send (another user's clean-up): run it again."""
    return o.how == "exit" and o.rc is not None and o.rc < 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", nargs="+", default=["input", "cables", "samples", "onepose", "stiffness", "size",
                                                  "slack", "scale"],
                   help="groups to run (default all)")
    p.add_argument("--skip", nargs="*", default=[], help="'group/case/command' runs to leave out")
    p.add_argument("--out", default=None, help="write the table (markdown) here")
    p.add_argument("--results", default=None,
                   help="JSON file of outcomes: runs recorded there are not run again (resume an interrupted run; "
                        "delete the file to start over), new ones are added as they end")
    p.add_argument("--work", default=None, help="folder for the data (kept; default a temporary one, removed)")
    p.add_argument("--timeout", type=float, default=TIMEOUT_S, help="wall-clock limit per run, s")
    p.add_argument("--stall", type=float, default=STALL_S, help="no CPU progress for this long: a hang, s")
    p.add_argument("--prepare", nargs=3, metavar=("KIND", "VALUE", "DIR"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.prepare:
        _prepare(args.prepare[0], float(args.prepare[1]), args.prepare[2])
        return 0
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="bench_limits_"))
    work.mkdir(parents=True, exist_ok=True)
    env = environment()
    runs = [r for r in cases(set(args.cases), work) if f"{r.group}/{r.case}/{r.command}" not in args.skip]
    recorded = _load(args.results)
    failed_prep = set()
    try:
        for r in runs:
            key = f"{r.group}/{r.case}/{r.command}"
            if (r.group, r.case) in failed_prep:
                continue
            done = recorded.get(key)
            pending = any(f"{q.group}/{q.case}/{q.command}" not in recorded for q in runs
                          if (q.group, q.case) == (r.group, r.case) and q is not r)
            if done is not None and not (r.command in PREPARE and pending):  # data needed again: re-simulate
                r.outcome = Outcome(**done)
            else:
                argv = r.argv() if callable(r.argv) else r.argv
                r.outcome = run_watched(argv, args.timeout, args.stall, env=env, cwd=work)
                if _killed_from_outside(r.outcome):
                    print(f"{key}: killed from outside (exit {r.outcome.rc}); not recorded", flush=True)
                    r.outcome = None
                    continue
                recorded[key] = dataclasses.asdict(r.outcome) | {"output": r.outcome.output[-6000:]}
                if args.results:
                    Path(args.results).write_text(json.dumps(recorded, indent=1))
            if r.command in PREPARE and r.verdict() != "works":
                failed_prep.add((r.group, r.case))
            print(f"{r.group:9s} {r.case:28s} {r.command:9s} {r.verdict():11s} {r.outcome.wall_s:7.1f} s "
                  f"{r.outcome.peak_mb:7.0f} MiB  {r.line()}", flush=True)
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)
    text = (f"Machine: {machine()}.\nDate: {datetime.date.today().isoformat()}. Command: "
            f"`python benchmarks/bench_limits.py --cases {' '.join(args.cases)}` (timeout {args.timeout:g} s, "
            f"stall {args.stall:g} s).\n\n{table(runs)}\n")
    if args.out:
        Path(args.out).write_text(text)
    bad = [r for r in runs if r.outcome is None or r.verdict() not in ("works", "clear error")]
    print(f"{len(runs) - len(bad)} of {len(runs)} runs as expected")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
