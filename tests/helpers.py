"""Shared test helpers: a small zoo of robots and numerical references."""

import jax.numpy as jnp
import numpy as np

from cstiffjax.examples import example_path
from cstiffjax.recordings import load_recordings
from cstiffjax.robot import CableRobot, Noise
from cstiffjax.robot_io import load_robot


def lab_robot(name="example02"):
    """The seed 003 prototype (8 mm cables) with recordings from the outside simulator."""
    robot = load_robot(example_path(f"{name}/robot.toml"))
    return robot, load_recordings(example_path(f"{name}/recordings.csv"), robot)


def eight_cable_robot(com=(0.0, 0.0, 0.0)):
    """An 8-cable box-frame robot: corners of a 4 x 4 x 3 m frame; lower attachments turned by 90 deg (full rank)."""
    a = np.array([[x, y, z] for z in (0.0, 3.0) for x, y in ((-2, -2), (2, -2), (2, 2), (-2, 2))], float)
    b = np.array([[x, y, z] for z in (-0.15, 0.15) for x, y in ((-0.2, -0.2), (0.2, -0.2), (0.2, 0.2), (-0.2, 0.2))])
    return CableRobot(
        anchors=a, attachments=b[[1, 2, 3, 0, 4, 5, 6, 7]], EA=np.full(8, 2e5), mass_per_length=np.zeros(8),
        platform_mass=20.0, com=np.asarray(com), inertia=np.eye(3), gravity=np.array([0, 0, -9.81]),
        noise=Noise(position=1e-5, rotation=1e-5, tension=0.1), name="box8",
    )


def central_difference(f, x, h=1e-6):
    """Jacobian of f at x by central differences (columns = inputs)."""
    x = np.asarray(x, float)
    cols = []
    for j in range(x.size):
        e = np.zeros_like(x)
        e[j] = h
        cols.append((np.asarray(f(jnp.asarray(x + e))) - np.asarray(f(jnp.asarray(x - e)))) / (2 * h))
    return np.stack(cols, -1)
