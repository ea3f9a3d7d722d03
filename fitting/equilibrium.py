"""Fast, differentiable forward statics by a fixed number of Newton steps (seed 003
"direct kinematics"), shared by the calibration (:mod:`fitting.least_squares`), the
posterior sampler and the mismatch diagnosis (:mod:`fitting.effects.model`).

:func:`cstiffjax.statics.forward_statics` solves the equilibrium with optimistix
Levenberg-Marquardt from any start; fits and samplers need thousands of cheap,
differentiable solves from a start that is already close (the measured pose, or the
pose predicted at a nearby parameter point). Here the equilibrium ``W(pose) = 0`` is
solved by ``steps`` clipped Newton steps in base-frame twist coordinates (Jacobian by
forward-mode autodiff, no gradients: ``stop_gradient``), then one more Newton step
*with* gradients, whose derivative is exactly the implicit-function derivative
``-J⁻¹ ∂W/∂θ`` at convergence. With the catenary law the pose and every cable's end
forces ``(H, V_B)`` are solved together (``6 + 2m`` unknowns; the span equations are
the closed form :func:`cstiffjax.catenary.end_point`, seed 003 eqs 23-24), so no root
find is nested inside another and the compiled graph stays small. A sample whose
residual does not vanish is reported through ``ok`` (never silent NaN).

The spring law is used *bilateral* (a cable shorter than ``l0`` would push):
recordings of a CDPR are taken with taut cables, and the smooth law keeps the fits away
from the slack kink, where a misfitted intermediate model would otherwise stall the
least squares; a prediction with a negative tension simply misfits the measured one
(with all cables taut it is the same equilibrium as ``forward_statics``'s one-sided
law; the tests check the agreement).
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from cstiffjax import lie
from cstiffjax.catenary import end_point, free_span
from cstiffjax.pulley import robot_paths
from cstiffjax.statics import moved_frame

NEWTON_STEPS = 12
NEWTON_TOL = 1e-7  # largest residual wrench relative to |weight| + |external| + 1


def _tension_fn(effects, plist):
    def fn(t):
        for e, p in zip(effects, plist):
            t = e.tension(t, p)
        return t
    return fn


def _wrench(robot, p, R, l0, ext, tension):
    """Net wrench (6,) on the platform and exit tensions (m,) of spring cables (straight or
    over swivel pulleys: :func:`cstiffjax.pulley.cable_path`)."""
    r = robot.attachments @ R.T
    path = robot_paths(robot, p + r)
    t = tension(robot.EA * (path.length - l0) / l0)  # bilateral: smooth for the fits (see module doc)
    f = t[:, None] * path.direction
    wg = robot.platform_mass * robot.gravity
    W = jnp.concatenate([jnp.sum(f, 0) + wg + ext[:3],
                         jnp.sum(jnp.cross(r, f), 0) + jnp.cross(R @ robot.com, wg) + ext[3:]])
    return W, t


def _spring_newton(robot, l0, ext, pose_start, effects, plist, scale, steps):
    """Twist solving the spring-law equilibrium (no gradients), and its wrench function."""
    def F(tw, rb, l, w, pl):
        return _wrench(rb, *moved_frame(pose_start, tw), l, w, _tension_fn(effects, pl))[0] / scale

    frozen = jax.lax.stop_gradient((robot, l0, ext, plist))
    tw, J = _newton(lambda z: F(z, *frozen), jnp.zeros(6), steps)
    return tw, J, F


def _newton(fn, z0, steps, max_step=0.05):
    """``steps`` clipped Newton steps on ``fn(z) = 0`` (no gradients); returns ``(z, J)``
    with ``J`` the Jacobian at the last iterate but one (used for the implicit step)."""
    def body(_, carry):
        z, _ = carry
        J, f = jax.jacfwd(lambda y: (fn(y), fn(y)), has_aux=True)(z)
        step = jnp.linalg.solve(J, f)
        step = step * jnp.minimum(1.0, max_step / (jnp.max(jnp.abs(step)) + 1e-300))
        return jnp.where(jnp.all(jnp.isfinite(step)), z - step, z), J

    n = z0.shape[0]
    return jax.lax.stop_gradient(jax.lax.fori_loop(0, steps, body, (z0, jnp.eye(n))))


def _implicit_step(F, z, J, live):
    """One Newton step whose derivative is the implicit-function derivative ``-J⁻¹ ∂F/∂θ``."""
    return z - jnp.linalg.solve(J, F(z, *live))


def _catenary_residual(z, robot, l0, ext, pose_start, scale):
    """Joint residual of the pose twist and each cable's end forces ``(H, V_B)/scale``:
    platform wrench balance (6) and the catenary span equations (2m), seed 003 eqs 23-24."""
    m = l0.shape[0]
    p, R = moved_frame(pose_start, z[:6])
    r = robot.attachments @ R.T
    up = -robot.gravity / jnp.linalg.norm(robot.gravity)
    start, l0 = _free_spans(robot, p + r, l0)
    d = p + r - start  # free span start (A: anchor or pulley tangent point) -> attachment (B)
    sz = d @ up
    hvec = d - sz[:, None] * up
    sx = jnp.sqrt(jnp.sum(hvec * hvec, axis=-1))
    ex = hvec / sx[:, None]
    H, VB = z[6:6 + m] * scale, z[6 + m:] * scale
    w = robot.mass_per_length * jnp.linalg.norm(robot.gravity)
    x_c, z_c = end_point(H, VB, l0, robot.EA, w)
    f = -H[:, None] * ex - VB[:, None] * up
    wg = robot.platform_mass * robot.gravity
    W = jnp.concatenate([jnp.sum(f, 0) + wg + ext[:3],
                         jnp.sum(jnp.cross(r, f), 0) + jnp.cross(R @ robot.com, wg) + ext[3:]])
    return jnp.concatenate([W / scale, (x_c - sx) / l0, (z_c - sz) / l0]), jnp.hypot(H, VB - w * l0)


def _free_spans(robot, att, l0):
    """Start points (m, 3) and unstrained lengths (m,) of the free spans
    (:func:`cstiffjax.catenary.free_span`, vmapped)."""
    return jax.vmap(free_span)(robot.anchors, att, l0, robot.EA, robot.pulley_radius, robot.pulley_axis)


def _straight_end_forces(robot, p, R, l0, floor):
    """``(H, V_B)`` (m,) each of spring cables at the attachments, tensions floored at
    ``floor`` N (a positive floor starts the catenary solve taut)."""
    path = robot_paths(robot, p + robot.attachments @ R.T)
    t = jnp.maximum(robot.EA * (path.length - l0) / l0, floor)
    up = -robot.gravity / jnp.linalg.norm(robot.gravity)
    vb = -t * (path.direction @ up)
    return jnp.sqrt(jnp.maximum(t * t - vb * vb, 0.0)), vb


def equilibrium(robot, l0: Float[Array, " m"], ext: Float[Array, "6"], pose_start: Float[Array, "6"],
                law: str = "spring", effects=(), plist=(), steps: int = NEWTON_STEPS):
    """Pose, exit-point tensions and convergence flag of one sample (module docstring).

    **Arguments:**

    - ``robot``: a :class:`~cstiffjax.robot.CableRobot` (any leaf may carry gradients).
    - ``l0`` ``(m,)`` unstrained lengths, m; ``ext`` ``(6,)`` external wrench, N / N·m.
    - ``pose_start`` ``(6,)``: where the Newton steps start (a measured or previously
      predicted pose; it only has to be within the basin of the clipped Newton steps).
    - ``law``: ``"spring"`` (bilateral) or ``"catenary"`` (pose and every cable's end
      forces ``(H, V_B)`` solved together, ``6 + 2m`` unknowns, closed-form
      :func:`cstiffjax.catenary.end_point`, started from the spring solution, so no
      solver is nested inside another).
    - ``effects``, ``plist``: :class:`fitting.effects.Effect` instances and their
      physical parameter dicts whose ``tension`` hooks modify the spring law
      (default none).
    - ``steps``: Newton steps without gradients before the implicit step (per stage).

    **Returns:** ``(pose (6,), exit tensions (m,) N, ok)``; ``ok`` is true when the
    wrench residual (and, for catenaries, the span residuals) is below
    :data:`NEWTON_TOL` relative to ``|weight| + |external| + 1`` and everything is finite.
    """
    return equilibrium_state(robot, l0, ext, pose_start, law, effects, plist, steps)[:3]


def equilibrium_state(robot, l0: Float[Array, " m"], ext: Float[Array, "6"], pose_start: Float[Array, "6"],
                      law: str = "spring", effects=(), plist=(), steps: int = NEWTON_STEPS,
                      forces_start: Float[Array, "2 m"] | None = None):
    """:func:`equilibrium` plus the cables' end forces, with an optional warm start.

    **Arguments:** as :func:`equilibrium`, and ``forces_start`` ``(2, m)``: ``(H, V_B)``
    of every cable (N; horizontal force and vertical force at the attachment, as
    returned here) to start the catenary solve from, together with ``pose_start``,
    skipping the spring stage (warm start from a nearby solution; ignored by the
    spring law).

    **Returns:** ``(pose (6,), exit tensions (m,) N, ok, forces (2, m))``, ``forces`` the
    ``(H, V_B)`` at the solution, N (straight-cable components for the spring law).
    """
    scale = jnp.linalg.norm(robot.platform_mass * robot.gravity) + jnp.linalg.norm(ext) + 1.0
    if law == "catenary" and forces_start is not None:
        tw = jnp.zeros(6)
        h, vb = forces_start[0], forces_start[1]
    else:
        tw, J, F = _spring_newton(robot, l0, ext, pose_start, effects, plist, scale, steps)
    if law == "spring":
        tw = _implicit_step(F, tw, J, (robot, l0, ext, plist))
        p, R = moved_frame(pose_start, tw)
        W, t_exit = _wrench(robot, p, R, l0, ext, _tension_fn(effects, plist))
        res = W / scale
        forces = jnp.stack(_straight_end_forces(robot, p, R, l0, -jnp.inf))
    else:
        if forces_start is None:
            h, vb = _straight_end_forces(robot, *moved_frame(pose_start, tw), l0, 1e-3 * scale)
        z0 = jnp.concatenate([tw, h / scale, vb / scale])

        def G(z, rb, l, w):
            return _catenary_residual(z, rb, l, w, pose_start, scale)[0]

        frozen = jax.lax.stop_gradient((robot, l0, ext))
        z, J = _newton(lambda z: G(z, *frozen), z0, steps, max_step=0.5)
        z = _implicit_step(G, z, J, (robot, l0, ext))
        res, t_exit = _catenary_residual(z, robot, l0, ext, pose_start, scale)
        p, R = moved_frame(pose_start, z[:6])
        forces = z[6:].reshape(2, -1) * scale
    pose = jnp.concatenate([p, lie.log(R)])
    ok = jnp.all(jnp.isfinite(res)) & (jnp.max(jnp.abs(res)) < NEWTON_TOL) & jnp.all(jnp.isfinite(t_exit))
    return pose, t_exit, ok, forces
