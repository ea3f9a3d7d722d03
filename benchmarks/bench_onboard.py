"""Blind cases on a robot calibrated from its own sensors: the 4-cable pulley robot of
``cstiffjax/examples/onboard4/robot.toml`` recorded without x y z (relative winch lengths in 3
sessions, load cells, swivel encoders, an AHRS with an unknown yaw zero per session). Each case
hides one effect (or none) in the truth; the diagnosis sees only the description and the
recordings. Writes a Markdown table (``--out``, default ``benchmarks/ONBOARD.md``).

Optional: ``--irma4u PATH`` also times ``check``, ``fit`` and ``diagnose`` on the public IRMA4U
recordings (a checkout of github.com/fzoffoli/UACDPR_SelfCalibration), cold (a fresh program
cache) and warm."""

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import equinox as eqx
import numpy as np

from cstiffjax.io.robot_io import load_robot
from fitting.diagnosis.diagnose import diagnose
from fitting.synth.onboard import hanging_lengths, onboard_recordings

HERE = Path(__file__).resolve().parents[1]


def _cases(robot):
    a = np.asarray(robot.anchors)
    moved = a.copy()
    moved[1] += [-0.015, 0.02, -0.01]
    att = np.asarray(robot.attachments).copy()
    att[2] += [0.01, 0.012, 0.0]
    return {
        "clean": ([], robot),
        "platform 6 % heavier": (["platform_mass"], eqx.tree_at(lambda r: r.platform_mass, robot, 12.99 * 1.06)),
        "platform 5 % lighter": (["platform_mass"], eqx.tree_at(lambda r: r.platform_mass, robot, 12.99 * 0.95)),
        "load-cell gains": (["tension_sensor_gain"],
                            eqx.tree_at(lambda r: r.tension_gain, robot, np.array([1.04, 1.0, 0.97, 1.0]))),
        "moved anchor (2.7 cm)": (["anchor_offset"], eqx.tree_at(lambda r: r.anchors, robot, moved)),
        "moved attachment (1.6 cm)": (["attachment_offset"], eqx.tree_at(lambda r: r.attachments, robot, att)),
        "winch gains": (["length_gain"], eqx.tree_at(lambda r: r.length_gain, robot, np.array([1.02, 1.0, 1.0, 0.98]))),
        "pulley radius 4 cm, stated 3 cm": (["pulley_kinematics"],
                                            eqx.tree_at(lambda r: r.pulley_radius, robot, np.full(4, 0.04))),
    }


def blind(seed: int) -> list[str]:
    robot = load_robot(HERE / "cstiffjax/examples/onboard4/robot.toml")
    rng = np.random.default_rng(seed)
    positions = rng.uniform([-0.8, -0.6, 1.0], [0.8, 0.6, 2.0], (60, 3))
    rows = []
    for name, (want, truth) in _cases(robot).items():
        rec = onboard_recordings(truth, hanging_lengths(truth, positions), session=np.repeat([0, 1, 2], 20),
                                 length_zero=rng.normal(0, 0.003, (3, 4)), yaw_zero=rng.uniform(-3, 3, 3), seed=seed)
        t = time.perf_counter()
        d = diagnose(robot, rec, progress=False)
        ok = d.effects == want and d.explained
        rows.append(f"| {name} | {', '.join(want) or '[]'} | {', '.join(d.effects) or '[]'} | "
                    f"{'yes' if d.explained else 'no'} | {d.baseline['chi2_per_dof']:.3g} -> "
                    f"{d.final['chi2_per_dof']:.3g} | {time.perf_counter() - t:.0f} | {'right' if ok else 'WRONG'} |")
        print(rows[-1], flush=True)
    return rows


def _timed(args, env) -> float:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "cstiffjax.commands.cli", *args], check=False, env=env,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def irma4u(path: str) -> list[str]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "irma4u"
        env = {**os.environ, "CSTIFFJAX_CACHE_DIR": str(Path(tmp) / "cache")}
        _timed(["convert", "irma4u", path, "--out", str(out)], env)
        files = [str(out / "robot.toml"), str(out / "recordings.csv")]
        for label, args in (("check", ["check", *files]),
                            ("fit (platform_mass, anchors)", ["fit", *files, "--free", "platform_mass,anchors"]),
                            ("diagnose", ["diagnose", *files, "--report", str(Path(tmp) / "report")])):
            cold, warm = _timed(args, env), _timed(args, env)
            rows.append(f"| {label} | {cold:.1f} | {warm:.1f} |")
            print(rows[-1], flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--irma4u", metavar="PATH")
    ap.add_argument("--out", default=str(HERE / "benchmarks/ONBOARD.md"))
    args = ap.parse_args()
    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}"
    lines = ["# Diagnosis from on-board sensors only", "",
             f"`python benchmarks/bench_onboard.py --seed {args.seed}` on {machine} ({time.strftime('%Y-%m-%d')}).",
             "Robot: `cstiffjax/examples/onboard4/robot.toml`; 60 samples in 3 sessions, no x y z; every case draws "
             "its own length zeros and AHRS yaw zeros. Right = the named effects are the hidden ones and the verdict "
             "is explained.", "",
             "| hidden | truth | named | explained | χ²/dof | s | verdict |", "|---|---|---|---|---|---|---|",
             *blind(args.seed)]
    if args.irma4u:
        lines += ["", "## IRMA4U (public recordings, 62 samples)", "",
                  "Wall seconds of the command line, cold (an empty program cache) and warm.", "",
                  "| command | cold s | warm s |", "|---|---|---|", *irma4u(args.irma4u)]
    Path(args.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
