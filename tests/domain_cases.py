"""Recordings for the physical-domain tests, simulated here independently of the effect code:
a platform heavier or lighter than described (the proto robot of :mod:`fitting.synth.generate`
and the bundled swivel-pulley robot), and cables whose stiffness follows the lab temperature.
Each true equilibrium comes from :func:`fitting.synth.generate.settle_samples` (forward statics
checked by an independent wrench evaluation); noise as the description's ``[noise]`` sigmas."""

import dataclasses
import tempfile
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from cstiffjax import load_recordings, load_robot
from cstiffjax.cable.laws import CableLaw
from cstiffjax.core import lie
from cstiffjax.examples import example_path
from cstiffjax.io import schema
from cstiffjax.io.recordings import write_recordings
from fitting.synth.generate import Case, settle_samples, simulate


def recordings_from_columns(cols, robot):
    """The recordings of ``cols`` (formats.md §2 columns) as the loader reads them from a CSV."""
    path = Path(tempfile.mkdtemp(prefix="domain-case-")) / "recordings.csv"
    write_recordings(cols, path)
    return load_recordings(path, robot)


def _noisy(robot, pose, ten, rng):
    n = len(pose)
    pos = pose[:, :3] + rng.normal(0, float(robot.noise.position), (n, 3))
    rot = np.array([np.asarray(lie.log(lie.exp(rng.normal(0, float(robot.noise.rotation), 3)) @ lie.exp(rv)))
                    for rv in pose[:, 3:]])
    return np.hstack([pos, rot]), ten + rng.normal(0, float(robot.noise.tension), ten.shape)


def proto_mass(change: float, n: int = 60, seed: int = 3):
    """``(nominal robot, recordings)``: the proto platform ``change`` kg heavier, com unchanged."""
    case = Case("proto_mass", "proto", {"platform_mass": {"mass_change": change, "com_change": [0.0, 0.0, 0.0]}},
                0, ["platform_mass"])
    robot, cols, _ = simulate(case, n, seed)
    return robot, recordings_from_columns(cols, robot)


def pulleys8_mass(factor: float, seed: int = 5):
    """``(nominal robot, recordings)``: the bundled pulley robot's platform ``factor`` times
    its described mass (com unchanged), on the bundled recordings' commanded lengths and loads."""
    robot = load_robot(example_path("pulleys8/robot.toml"))
    rec = load_recordings(example_path("pulleys8/recordings.csv"), robot)
    true = eqx.tree_at(lambda r: r.platform_mass, robot, robot.platform_mass * factor)
    l0, ext = np.asarray(rec.l0), np.asarray(rec.wrench)
    l0_true = l0[0] + np.asarray(robot.length_gain) * (l0 - l0[0])  # the stated winch gains (formats.md §1 v2)
    pose, ten = settle_samples(true, l0_true, ext, np.asarray(rec.pose), CableLaw.spring, None, "pulleys8_mass")
    ten = ten * np.asarray(robot.tension_gain)  # the stated load-cell gains
    pose_m, ten_m = _noisy(robot, pose, ten, np.random.default_rng(seed))
    cols = schema.to_columns(robot.num_cables, {"time": np.asarray(rec.time), "l0": l0, "wrench": ext,
                                                "pose": pose_m, "tensions": ten_m})
    return robot, recordings_from_columns(cols, robot)


def stiffness_temperature(beta: float = -4e-3, n: int = 80, seed: int = 9):
    """``(nominal robot, recordings)``: the tcpr8 cables' ``EA`` follows the lab temperature,
    ``EA (1 + beta (T - mean T))`` (``beta`` 1/K; a polymer cable softens as it warms), with
    the temperature swinging a few kelvin over the recordings."""
    rng = np.random.default_rng(seed)
    base = Case("stiff", "tcpr8", {}, 0, [])
    robot, cols, _ = simulate(base, n, seed)  # inputs, time and a temperature column
    temperature = 21.0 + 3.0 * np.sin(np.linspace(0, 3 * np.pi, n)) + rng.normal(0, 0.1, n)
    temperature = np.round(temperature, 2)
    m = robot.num_cables
    l0 = np.stack([cols[schema.cable_column("l0", i + 1)] for i in range(m)], axis=1)
    ext = np.stack([cols[c] for c in schema.field_columns("wrench", 0)], axis=1)
    pose0 = np.stack([cols[c] for c in schema.field_columns("pose", 0)], axis=1)
    pose, ten = np.zeros_like(pose0), np.zeros_like(l0)
    for k in range(n):  # one true robot per sample: its EA at that sample's temperature
        ea = robot.EA * (1.0 + beta * (temperature[k] - temperature.mean()))
        true = eqx.tree_at(lambda r: r.EA, robot, jnp.asarray(ea))
        p, t = settle_samples(true, l0[k:k + 1], ext[k:k + 1], pose0[k:k + 1], CableLaw.spring, None, "stiff")
        pose[k], ten[k] = p[0], t[0]
    pose_m, ten_m = _noisy(robot, pose, ten, rng)
    cols = schema.to_columns(m, {"time": cols["time"], "l0": l0, "wrench": ext, "pose": pose_m,
                                 "tensions": ten_m}, {"temperature": temperature})
    return dataclasses.replace(robot, name="stiffness_temperature"), recordings_from_columns(cols, robot)
