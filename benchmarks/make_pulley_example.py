"""Regenerate the bundled example ``cstiffjax/examples/pulleys8/`` (robot.toml +
recordings.csv): the TCPR-8 (``cstiffjax/examples/tcpr8.toml``) with 2.5 cm swivel pulleys
at all eight anchors and stated winch/load-cell gains (formats.md §1 version 2).

    python benchmarks/make_pulley_example.py

Deterministic (seed ``SEED``; the same numbers on every run with the same JAX/numpy).

What the recordings hold: **nothing concealed**. The robot that made them is exactly the
description (pulleys, axes, gains, EA, mass); only the Gaussian noise of its ``[noise]``
table is added. A correct diagnosis of this example therefore reports no effect
(``effects: []``, explained); it is the false-alarm check of a description that states
pulleys and gains. The answer key says so (``benchmarks/pulleys8_key.json``, next to this
script, never in the example folder).

How each sample is made (the library's generator, :mod:`fitting.synth.generate`; no new physics
here, and nothing from the diagnosis's effect code :mod:`fitting.effects` /
:mod:`fitting.calibration.models`):

1. a random pose and load in the generator's TCPR-8 workspace and the commanded lengths
   that hold it with a centred tension distribution, over the pulley path
   (:func:`fitting.synth.generate._sample_inputs`, resampled until every tension >= 40 N);
2. the winch: true unstrained length ``l0_ref + length_gain (l0 - l0_ref)`` with ``l0_ref``
   the first commanded lengths (formats.md §1, written out below);
3. the true equilibrium by the cold start of
   :func:`cstiffjax.statics.forward.forward_statics` (spring law, over the pulleys), its wrench
   re-evaluated independently (:func:`fitting.synth.generate.settle_samples`, which raises on a
   residual above 1e-8 of the load or a slack cable);
4. the load cells read ``tension_gain`` x the true exit tension; pose and tensions get the
   ``[noise]`` sigmas (rotation noise composed on the left, as the generator does).
"""

import json
from pathlib import Path

import numpy as np

from cstiffjax.cable.laws import CableLaw
from cstiffjax.core import lie
from cstiffjax.examples import example_path
from cstiffjax.io import schema
from cstiffjax.io.recordings import write_recordings
from cstiffjax.io.robot_io import load_robot
from fitting.synth.generate import _sample_inputs, settle_samples

HERE = Path(__file__).parent
OUT = HERE.parent / "cstiffjax" / "examples" / "pulleys8"
KEY = HERE / "pulleys8_key.json"
SEED = 2027
SAMPLES = 80
RADIUS = 0.025  # m, every pulley
# stated (known, calibrated) gains; 1.0 written out for the others to show the fields
LENGTH_GAIN = (1.0, 1.0, 1.004, 1.0, 1.0, 0.997, 1.0, 1.0)
TENSION_GAIN = (1.0, 1.012, 1.0, 1.0, 1.0, 1.0, 0.988, 1.0)

HEADER = """\
# TCPR-8 with swivel pulleys (formats.md section 1, version 2): the geometry, cable, mass,
# noise and limits of the bundled tcpr8.toml (see its assumptions A1-A6), with a swivel
# pulley of radius 2.5 cm at every anchor and stated winch and load-cell gains.
# Written by benchmarks/make_pulley_example.py together with recordings.csv.
#
# Pulleys. `anchor` is where the cable enters its pulley, on the swivel axis.
# `pulley_axis` is the direction in which the cable travels as it arrives there:
#  - cables 1-4 (top corners, z = 1.78 m, above the workspace centre z ~ 0.83 m): the
#    cable comes UP the frame pillar from its winch, pulley_axis = [0, 0, 1]; the pulley
#    takes it over its top and down to the platform (wrap 2.2-2.7 rad in the recordings).
#  - cables 5-8 (bottom corners, z = 0, below the workspace centre): the cable comes DOWN
#    the pillar from its winch, pulley_axis = [0, 0, -1]; it turns under the pulley and up
#    to the platform (wrap 2.1-2.6 rad in the recordings).
# (The convention of cstiffjax.cable.path.vertical_axes: +z above the workspace centre, -z
# below.) `l0_i` in the recordings is the unstrained length of the whole path from the
# anchor over the pulley to the attachment.
#
# Gains (known from calibration, stated on every cable to show the fields):
#  length_gain  cable 3: 1.004, cable 6: 0.997 (winch drums); the others 1.0
#  tension_gain cable 2: 1.012, cable 7: 0.988 (load-cell certificates); the others 1.0
"""


def robot_text() -> str:
    """The robot.toml text: tcpr8.toml's tables (its own header comments dropped) with the
    pulley and gain fields appended to every ``[[cables]]`` table."""
    lines = example_path("tcpr8.toml").read_text().splitlines()
    body = lines[next(i for i, s in enumerate(lines) if s.startswith("kind")):]
    body = [s.replace('name = "tcpr8"', 'name = "pulleys8"') for s in body]
    out, cable = [], -1
    for s in [*body, "[[cables]]"]:  # a sentinel table flushes the last cable's fields
        if s.startswith("[[cables]]") and cable >= 0:
            while out and not out[-1].strip():
                out.pop()
            up = cable < 4
            out += [f"pulley_radius = {RADIUS!r}",
                    f"pulley_axis = [0.0, 0.0, {1.0 if up else -1.0}]   # cable comes {'up' if up else 'down'} "
                    f"to the {'top' if up else 'bottom'} pulley",
                    f"length_gain = {LENGTH_GAIN[cable]!r}", f"tension_gain = {TENSION_GAIN[cable]!r}", ""]
        if s.startswith("[[cables]]"):
            cable += 1
        out.append(s)
    return HEADER + "\n".join(out[:-1]).rstrip() + "\n"


def simulate(robot, n: int, seed: int) -> dict:
    """Columns (formats.md §2) of ``n`` samples of ``robot`` taken as the truth (module docstring)."""
    rng = np.random.default_rng(seed)
    pose_cmd, ext, l0_cmd = _sample_inputs(robot, "tcpr8", n, rng)
    time = np.cumsum(rng.uniform(60.0, 150.0, n))
    temperature = 21.0 + np.cumsum(rng.normal(0, 0.05, n))
    l0_true = l0_cmd[0] + np.asarray(robot.length_gain) * (l0_cmd - l0_cmd[0])  # winch, formats.md §1
    pose, ten = settle_samples(robot, l0_true, ext, pose_cmd, CableLaw.spring, None, "pulleys8")
    ten = np.asarray(robot.tension_gain) * ten  # load cells, formats.md §1
    noise = robot.noise
    pos = pose[:, :3] + rng.normal(0, float(noise.position), (n, 3))
    rot = np.array([np.asarray(lie.log(lie.exp(rng.normal(0, float(noise.rotation), 3)) @ lie.exp(rv)))
                    for rv in pose[:, 3:]])
    ten = ten + rng.normal(0, float(noise.tension), ten.shape)
    m = robot.num_cables
    return schema.to_columns(m, {"time": time, "l0": l0_cmd, "wrench": ext, "pose": np.hstack([pos, rot]),
                                 "tensions": ten}, {"temperature": np.round(temperature, 2)})


if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "robot.toml").write_text(robot_text())
    robot = load_robot(OUT / "robot.toml")  # the file as a user reads it: the truth
    write_recordings(simulate(robot, SAMPLES, SEED), OUT / "recordings.csv")
    key = {"case": "pulleys8", "robot": "tcpr8 with 2.5 cm swivel pulleys and stated gains", "samples": SAMPLES,
           "seed": SEED, "expected": [], "explained": True, "outliers": [], "truth": {},
           "note": "nothing concealed: the recordings were made by the robot exactly as described"}
    KEY.write_text(json.dumps(key, indent=1) + "\n")
    print(f"wrote {OUT.relative_to(HERE.parent)}/robot.toml, recordings.csv (key: {KEY.relative_to(HERE.parent)})")
