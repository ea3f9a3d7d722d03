"""Synthetic recordings with effects that are in *no* vocabulary (the proof of the discovery).

Five kinds, each physically plausible and simulated here directly (numpy on the inputs
and readings, true equilibrium by :func:`fitting.synth.generate.settle_samples`, the independent
solver of :mod:`cstiffjax.statics.geometry`), never through :mod:`fitting.effects.grammar`:

========================  ===================================================================
``thermal_length``        steel cables expand with the lab temperature:
                          ``l0_true = l0 (1 + α (T - T̄))``, α = 2e-5 /K
``load_scale``            the external loads applied were larger than recorded (a mis-
                          calibrated load cell on the weights): ``w_true = 1.04 w``
``tracker_scale_z``       the pose tracker's z axis has a scale error: ``z_meas = z (1 + s)``
``length_hysteresis``     each winch has backlash: the true length depends on the direction
                          of the last move, ``l0_true = l0 + h_i dir_i`` (per cable)
``humidity_loadcell``     the load cells drift with humidity: ``t_meas = t + b (H - H̄)``
========================  ===================================================================

Every recording carries two covariates, ``temperature`` and ``humidity`` (independent
slow variations), so the driver has to be found, not guessed. ``cstiffjax generate --oov
--out DIR`` writes the cases like :mod:`fitting.synth.generate`.
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cstiffjax.cable.laws import CableLaw
from cstiffjax.core import lie
from cstiffjax.io import schema
from cstiffjax.io.recordings import write_recordings
from cstiffjax.io.robot_io import save_robot
from fitting.synth.generate import _jsonable, _renamed, _sample_inputs, nominal_robot, settle_samples

KINDS = ("thermal_length", "load_scale", "tracker_scale_z", "length_hysteresis", "humidity_loadcell")


@dataclass
class OOVCase:
    """One out-of-vocabulary data set: ``kind`` (one of :data:`KINDS` or ``clean``),
    ``truth`` parameters, and what a correct diagnosis finds: ``where`` (the
    ``acts_on``/grammar where) and ``driver`` (recorded column or ``dir_i``)."""

    name: str
    robot: str
    kind: str
    truth: dict = field(default_factory=dict)
    where: str | None = None
    driver: str | None = None


def oov_cases(rng=None) -> list[OOVCase]:
    """The five kinds and a clean set, on both robots (TCPR-8 sizes scaled to its noise)."""
    rng = np.random.default_rng(15) if rng is None else rng
    out = []
    for kind in ("proto", "tcpr8"):
        m = 6 if kind == "proto" else 8
        small = 0.1 if kind == "tcpr8" else 1.0
        h = rng.uniform(3e-4, 8e-4, m) * rng.choice([-1, 1], m) * small
        spec = {
            "thermal_length": ({"alpha": 2e-5}, "l0", "temperature"),
            "load_scale": ({"scale": 0.04}, "load", None),
            "tracker_scale_z": ({"scale": 4e-4 if kind == "proto" else 5e-5}, "pose[2]", None),
            "length_hysteresis": ({"step": h}, "l0", "dir_i"),
            "humidity_loadcell": ({"rate": 0.15 if kind == "proto" else 0.25}, "tension", "humidity"),
            "clean": ({}, None, None),
        }
        for k, (truth, where, driver) in spec.items():
            out.append(OOVCase(f"{kind}_{k}", kind, k, truth, where, driver))
    return out


def _covariates(time, rng):
    """Lab temperature (K-scale, °C) and relative humidity (%) along the session."""
    t = time - time[0]
    span = max(t[-1], 1.0)
    temp = 22.0 + 2.5 * np.sin(2 * np.pi * t / (0.9 * span) + rng.uniform(0, 2 * np.pi)) + np.cumsum(
        rng.normal(0, 0.03, len(t)))
    hum = 45.0 + 10.0 * np.sin(2 * np.pi * t / (0.45 * span) + rng.uniform(0, 2 * np.pi)) + np.cumsum(
        rng.normal(0, 0.2, len(t)))
    return np.round(temp, 3), np.round(hum, 2)


def simulate_oov(case: OOVCase, n: int = 90, seed: int = 0):
    """Recordings of ``case``: ``(nominal robot, columns dict)`` (formats.md §2 columns)."""
    rng = np.random.default_rng(seed)
    robot = nominal_robot(case.robot)
    m = robot.num_cables
    pose_cmd, ext, l0_cmd = _sample_inputs(robot, case.robot, n, rng)
    time = 100.0 + np.cumsum(rng.uniform(60.0, 150.0, n))
    temp, hum = _covariates(time, rng)
    direction = np.zeros_like(l0_cmd)
    direction[1:] = np.sign(np.diff(l0_cmd, axis=0))
    tr, l0_true, ext_true = case.truth, l0_cmd.copy(), ext.copy()
    if case.kind == "thermal_length":
        l0_true = l0_cmd * (1.0 + tr["alpha"] * (temp - temp.mean()))[:, None]
    if case.kind == "length_hysteresis":
        l0_true = l0_cmd + np.asarray(tr["step"]) * direction
    if case.kind == "load_scale":
        ext_true = ext * (1.0 + tr["scale"])
    pose, ten = settle_samples(robot, l0_true, ext_true, pose_cmd, CableLaw.spring, None, case.name)
    if case.kind == "tracker_scale_z":
        pose[:, 2] *= 1.0 + tr["scale"]
    if case.kind == "humidity_loadcell":
        ten = ten + tr["rate"] * (hum - hum.mean())[:, None]
    noise = robot.noise
    pos_m = pose[:, :3] + rng.normal(0, float(noise.position), (n, 3))
    rot_m = np.array([np.asarray(lie.log(lie.exp(rng.normal(0, float(noise.rotation), 3)) @ lie.exp(rv)))
                      for rv in pose[:, 3:]])
    ten_m = ten + rng.normal(0, float(noise.tension), ten.shape)
    cols = schema.to_columns(m, {"time": time, "l0": l0_cmd, "wrench": ext, "pose": np.hstack([pos_m, rot_m]),
                                 "tensions": ten_m}, {"temperature": temp, "humidity": hum})
    return robot, cols


def write_oov_case(case: OOVCase, out_dir, n: int = 90, seed: int = 0) -> dict:
    """Write ``out_dir/robot.toml`` (nominal) and ``out_dir/recordings.csv``; return the key."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    robot, cols = simulate_oov(case, n, seed)
    save_robot(_renamed(robot, case.name), out / "robot.toml")
    write_recordings(cols, out / "recordings.csv")
    return oov_key_entry(case, n, seed)


def oov_key_entry(case: OOVCase, n: int, seed: int) -> dict:
    """The answer-key entry of a written out-of-vocabulary case (``cstiffjax/io/outputs.md``,
    ``generate``): name, robot, kind, samples ``n``, ``seed`` and what a correct discovery finds."""
    return {"case": case.name, "robot": case.robot, "kind": case.kind, "samples": n, "seed": seed,
            "where": case.where, "driver": case.driver, "truth": _jsonable(case.truth)}
