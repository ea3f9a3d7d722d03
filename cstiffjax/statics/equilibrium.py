"""Where a robot settles: its nominal gravity equilibrium, and the stiffness of an equilibrium.

A robot description states no unstrained lengths, so "where the platform hangs" needs
lengths. :func:`nominal_equilibrium` takes the cable paths' lengths at
:func:`hanging_guess` (above the anchors' centroid, half way between the floor and the highest
anchor: for a suspended robot, mid-way down its frame) and solves the
forward statics of those lengths with spring cables, cold start: for fewer than 6 cables the
pose of least potential energy (:func:`cstiffjax.statics.suspended.energy_start`) refined to
the equilibrium, for 6 or more the ideal-cable pose refined likewise. That is the solve the
fits start from where no position was recorded
(:func:`fitting.calibration.models.start_poses`): one solver, not a second one.

The floor is the plane through the base frame's origin normal to gravity (``z = 0`` with
``gravity = [0, 0, -g]``), or the lowest anchor where one is below it: what the pictures draw
(:mod:`cstiffjax.plots.scene`).

:func:`equilibrium_stiffness` is the stiffness ``K = -dW/dx`` of a solved equilibrium of
any law (the weight's term included: what forward statics judges the stability of a
suspended robot with, :func:`cstiffjax.statics.suspended.is_stable`).
"""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from cstiffjax.cable.laws import CableLaw
from cstiffjax.statics.forward import ForwardStatics, StaticsProblem, forward_statics, wrench_scale
from cstiffjax.statics.geometry import cable_lengths
from cstiffjax.statics.residuals import ResidualArgs
from cstiffjax.statics.suspended import stiffness_at


def up_direction(gravity) -> np.ndarray:
    """The unit vector against ``gravity`` (3,) (``+z`` without gravity)."""
    g = np.asarray(gravity, dtype=float)
    n = float(np.linalg.norm(g))
    return -g / n if n > 0 else np.array([0.0, 0.0, 1.0])


def floor_height(points, up) -> float:
    """The floor's height along ``up`` (m): 0 (the base frame's origin), or the lowest of
    ``points`` ``(k, 3)`` (e.g. the anchors) where it is lower."""
    return float(min(0.0, float(np.min(np.asarray(points, float) @ up))))


def hanging_guess(robot) -> np.ndarray:
    """The unrotated pose (6,) m / rad above the anchors' centroid (a symmetric robot hangs
    level there), at the height half way between the floor (:func:`floor_height`) and the
    highest anchor."""
    a = np.asarray(robot.anchors, dtype=float)
    up = up_direction(robot.gravity)
    centre = a.mean(0)
    mid = 0.5 * (floor_height(a, up) + float(np.max(a @ up)))
    return np.concatenate([centre + (mid - centre @ up) * up, np.zeros(3)])


def nominal_equilibrium(robot, l0=None, external=None) -> ForwardStatics:
    """Where the platform of ``robot`` settles on spring cables of unstrained lengths ``l0``
    (default: the cable paths' lengths at :func:`hanging_guess`) under its weight and ``external`` (6,) N / N·m (default
    none), from the forward statics' default cold start (fewer than 6 cables: the least-energy
    pose). One compiled program per robot shape (cable count, pulleys; not its name). Never
    raises: check ``result``."""
    robot = dataclasses.replace(robot, name="robot")  # static name: robots of one shape share the program
    l0 = None if l0 is None else jnp.asarray(l0, dtype=jnp.float64)
    ext = jnp.zeros(6) if external is None else jnp.asarray(external, dtype=jnp.float64)
    return _solve(robot, l0, jnp.asarray(hanging_guess(robot)), ext)


@eqx.filter_jit
def _solve(robot, l0, guess, ext) -> ForwardStatics:
    """:func:`nominal_equilibrium` in one program (``l0`` None: the lengths at ``guess``)."""
    l0 = cable_lengths(robot, guess) if l0 is None else l0
    return forward_statics(StaticsProblem(robot, l0, ext, CableLaw.spring), throw=False, derivatives=False)


def equilibrium_stiffness(problem: StaticsProblem, fs: ForwardStatics) -> Float[Array, "6 6"]:
    """The stiffness ``K = -dW/dx`` (6x6; rows N, N·m; columns m, rad of a base-frame twist)
    at the solution ``fs`` of ``problem`` (:func:`~cstiffjax.statics.forward.forward_statics`),
    the weight's term included; for the catenary the end forces follow the pose (the span
    equations held). No derivative."""
    ext = jnp.zeros(6) if problem.external is None else problem.external
    scale = wrench_scale(problem.robot, ext)
    args = ResidualArgs(problem.robot, problem.l0, ext, problem.tension, fs.pose, scale)
    z = jnp.zeros(6)
    if problem.law is CableLaw.catenary:
        z = jnp.concatenate([z, fs.forces.reshape(-1) / scale])
    return stiffness_at(problem.law, z, args)
