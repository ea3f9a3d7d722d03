"""CDPR statics: cable geometry, structure matrix, wrench balance, inverse and forward statics.

Pose and derivative conventions
-------------------------------
A pose is ``x = [x, y, z, rx, ry, rz]``: position of the platform reference point and
orientation as a rotation vector, base frame (m, rad). **All derivatives with respect
to the pose are taken in twist coordinates** ``δx = [δp, δθ]`` of the *base frame*:
the perturbed pose has position ``p + δp`` and orientation ``exp(hat(δθ)) R`` (a small
rotation ``δθ`` about base-frame axes through the platform reference point). This is
the convention of seed 003 eq. (29) (``A_i = [I, -hat(r_i)]``) and of seed 004's
structure matrix; :func:`cstiffjax.stiffness.to_euler_coordinates` converts to
(x, y, z, α, β, γ).

The structure matrix ``S`` (6 x m) has columns ``[u_i; r_i × u_i]`` where ``u_i`` is the
unit vector from the attachment to the anchor (over a swivel pulley: to the tangent point
T, :mod:`cstiffjax.pulley`, which is also minus the gradient of the path length) and
``r_i = R b_i``; it is computed by
autodiff as ``S = -(∂l/∂x)ᵀ`` (seed 004 eq. 2). The wrench on the platform is
``S t + W_g + W_ext`` (seed 004 eq. 3) with ``W_ext = [f, m]`` about the reference point.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float

from . import lie
from .cables import cable_force, check_law
from .pulley import robot_paths
from .status import Status, raise_if_failed

Pose = Float[Array, "6"]


# --------------------------------------------------------------------------- geometry
def frame(pose: Float[Array, "6"]):
    """``(p, R)`` of a pose vector."""
    pose = jnp.asarray(pose, dtype=jnp.float64)
    return pose[:3], lie.exp(pose[3:])


def moved_frame(pose, twist):
    """Frame after the base-frame twist ``[δp, δθ]``: ``(p + δp, exp(δθ) R)``."""
    p, R = frame(pose)
    return p + twist[:3], lie.exp(twist[3:]) @ R


def apply_twist(pose: Float[Array, "6"], twist: Float[Array, "6"]) -> Float[Array, "6"]:
    """Pose vector after the base-frame twist ``twist`` (see module docstring)."""
    p, R = moved_frame(pose, twist)
    return jnp.concatenate([p, lie.log(R)])


def twist_jacobian(fn, pose):
    """Jacobian of ``fn(p, R)`` with respect to the base-frame twist at ``pose`` (autodiff)."""
    return jax.jacfwd(lambda d: fn(*moved_frame(pose, d)))(jnp.zeros(6))


def _attachments_at(robot, p, R):
    return p + robot.attachments @ R.T


def attachment_points(robot, pose: Pose) -> Float[Array, "m 3"]:
    """Attachment points in the base frame, m."""
    return _attachments_at(robot, *frame(pose))


def cable_vectors(robot, pose: Pose) -> Float[Array, "m 3"]:
    """Vectors from each attachment to the start of its free span (the anchor, or the
    pulley's tangent point), base frame, m (seed 004 eq. 1, negated)."""
    att = attachment_points(robot, pose)
    return robot_paths(robot, att).tangent_point - att


def _lengths_at(robot, p, R):
    return robot_paths(robot, _attachments_at(robot, p, R)).length


def cable_lengths(robot, pose: Pose) -> Float[Array, " m"]:
    """Cable path lengths, m: ``|a_i - p - R b_i|`` for straight cables, ``r beta + |P - T|``
    over a swivel pulley (:func:`cstiffjax.pulley.cable_path`)."""
    return _lengths_at(robot, *frame(pose))


def structure_matrix(robot, pose: Pose) -> Float[Array, "6 m"]:
    """Structure matrix ``S = -(∂l/∂x)ᵀ`` by autodiff of the cable lengths (6 x m)."""
    return -twist_jacobian(lambda p, R: _lengths_at(robot, p, R), pose).T


def structure_matrix_closed_form(robot, pose: Pose) -> Float[Array, "6 m"]:
    """Closed form ``[u_i; (R b_i) × u_i]`` (seed 004 below eq. 2), ``u_i`` the unit vector
    from the attachment towards the anchor or the pulley's tangent point."""
    p, R = frame(pose)
    r = robot.attachments @ R.T
    u = robot_paths(robot, p + r).direction
    return jnp.concatenate([u, jnp.cross(r, u)], axis=-1).T


def gravity_wrench(robot, pose: Pose) -> Float[Array, "6"]:
    """Weight of the platform as a wrench about the reference point, base frame."""
    _, R = frame(pose)
    f = robot.weight
    return jnp.concatenate([f, jnp.cross(R @ robot.com, f)])


def _external(external):
    return jnp.zeros(6) if external is None else jnp.asarray(external, dtype=jnp.float64)


def wrench(robot, pose: Pose, tensions: Float[Array, " m"], external=None) -> Float[Array, "6"]:
    """Net wrench on the platform: ``S t + W_gravity + W_ext`` (zero at equilibrium).

    **Arguments:** ``tensions`` N (straight massless cables); ``external`` ``[f, m]``
    (N, N·m) about the reference point, base frame, weight excluded.
    """
    return structure_matrix_closed_form(robot, pose) @ tensions + gravity_wrench(robot, pose) + _external(external)


# --------------------------------------------------------------------- elastic cables
def _forces_at(robot, p, R, l0, law):
    att = _attachments_at(robot, p, R)
    return jax.vmap(lambda a, b, l, ea, w, rad, ax: cable_force(law, a, b, l, ea, w, robot.gravity, rad, ax))(
        robot.anchors, att, l0, robot.EA, robot.mass_per_length, robot.pulley_radius, robot.pulley_axis
    )


def _elastic_wrench_at(robot, p, R, l0, external, law):
    cf = _forces_at(robot, p, R, l0, law)
    r = robot.attachments @ R.T
    f = cf.on_platform
    w_c = jnp.concatenate([jnp.sum(f, 0), jnp.sum(jnp.cross(r, f), 0)])
    w_g = jnp.concatenate([robot.weight, jnp.cross(R @ robot.com, robot.weight)])
    return w_c + w_g + _external(external)


def cable_forces(robot, pose: Pose, l0: Float[Array, " m"], law: str = "spring"):
    """Per-cable :class:`~cstiffjax.cables.CableForce` (batched over cables) at ``pose``."""
    return _forces_at(robot, *frame(pose), jnp.asarray(l0, dtype=jnp.float64), check_law(law))


def elastic_wrench(robot, pose: Pose, l0, external=None, law: str = "spring") -> Float[Array, "6"]:
    """Net wrench on the platform for elastic cables of unstrained lengths ``l0`` (N, N·m)."""
    return _elastic_wrench_at(robot, *frame(pose), jnp.asarray(l0, dtype=jnp.float64),
                              external, check_law(law))


# ---------------------------------------------------------------------- inverse statics
class InverseStatics(eqx.Module):
    """Tensions holding a pose. ``tensions`` N; ``result`` a :class:`Status`
    (``infeasible`` when outside ``[tension_min, tension_max]``, ``singular`` when S is
    rank deficient); ``residual`` the wrench left unbalanced, N / N·m."""

    tensions: Float[Array, " m"]
    residual: Float[Array, "6"]
    result: Status


@eqx.filter_jit
def inverse_statics(robot, pose: Pose, external=None, *, throw: bool = True) -> InverseStatics:
    """Minimum-norm tensions with ``S t = -(W_g + W_ext)`` (seed 004 eq. 20, particular part).

    For a 6-cable robot this is the unique solution. The status is ``infeasible`` when a
    tension leaves ``[tension_min, tension_max]``: for redundant robots use
    :func:`cstiffjax.tensions.feasible_tensions` to search the null space.
    """
    S = structure_matrix_closed_form(robot, pose)
    w = gravity_wrench(robot, pose) + _external(external)
    t = -jnp.linalg.pinv(S) @ w
    res = S @ t + w
    sv = jnp.linalg.svd(S, compute_uv=False)
    singular = sv[-1] < 1e-9 * sv[0]
    feasible = jnp.all(t >= robot.tension_min - 1e-9) & jnp.all(t <= robot.tension_max + 1e-9)
    result = Status.where(singular, Status.singular, Status.where(feasible, Status.successful, Status.infeasible))
    return raise_if_failed(result, InverseStatics(t, res, result), throw)


# ---------------------------------------------------------------------- forward statics
class ForwardStatics(eqx.Module):
    """Equilibrium of the platform on elastic cables.

    ``pose`` (6,) m/rad; ``tensions`` (m,) N at the exit points; ``tensions_attachment``
    (m,) N at the platform; ``slack`` (m,) true for cables carrying no tension;
    ``residual`` net wrench at the solution; ``result`` a :class:`Status`;
    ``num_steps`` solver iterations.
    """

    pose: Float[Array, "6"]
    tensions: Float[Array, " m"]
    tensions_attachment: Float[Array, " m"]
    slack: Bool[Array, " m"]
    residual: Float[Array, "6"]
    result: Status
    num_steps: Array


def default_solver(rtol: float = 1e-10, atol: float = 1e-10):
    """Levenberg-Marquardt used by the statics solves (pass your own to override)."""
    return optx.LevenbergMarquardt(rtol=rtol, atol=atol)


def _wrench_scale(robot, external):
    return jnp.linalg.norm(robot.weight) + jnp.linalg.norm(_external(external)) + 1.0


def _kinematic_residual(twist, args):
    robot, pose0, l0 = args
    return _lengths_at(robot, *moved_frame(pose0, twist)) - l0


def _equilibrium_residual(twist, args):
    robot, pose0, l0, external, law, scale = args
    p, R = moved_frame(pose0, twist)
    return _elastic_wrench_at(robot, p, R, l0, external, law) / scale


def _initial_pose(robot):
    c = jnp.mean(robot.anchors, axis=0)
    return jnp.concatenate([c.at[2].set(jnp.min(robot.anchors[:, 2]) - 1.0), jnp.zeros(3)])


@eqx.filter_jit
def forward_kinematics(robot, l0, pose0=None, *, solver=None, max_steps: int = 256, throw: bool = True):
    """Pose whose straight-line cable lengths best match ``l0`` (least squares), m / rad.

    Returns ``(pose, result)``; ``result`` is ``not_converged`` if the lengths cannot be
    matched to 1e-9 m (over-constrained robots with inconsistent lengths).
    """
    l0 = jnp.asarray(l0, dtype=jnp.float64)
    pose0 = _initial_pose(robot) if pose0 is None else jnp.asarray(pose0, dtype=jnp.float64)
    sol = optx.least_squares(_kinematic_residual, solver or default_solver(1e-12, 1e-12),
                             jnp.zeros(6), args=(robot, pose0, l0), max_steps=max_steps, throw=False)
    err = jnp.max(jnp.abs(_kinematic_residual(sol.value, (robot, pose0, l0))))
    ok = (sol.result == optx.RESULTS.successful) & (err < 1e-9)
    result = Status.where(ok, Status.successful, Status.not_converged)
    pose = apply_twist(pose0, sol.value)
    return raise_if_failed(result, (pose, result), throw)


@eqx.filter_jit
def forward_statics(
    robot, l0, external=None, pose0=None, *, law: str = "spring", solver=None,
    max_steps: int = 256, tol: float = 1e-9, throw: bool = True,
) -> ForwardStatics:
    """Pose and tensions of the platform hanging on cables of unstrained lengths ``l0``.

    Seed 003 "direct kinematics". The equilibrium ``W(x) = 0`` is solved for the twist
    from ``pose0`` with Levenberg-Marquardt (optimistix), derivatives by autodiff, so
    the solution is differentiable (implicit function theorem) in ``l0``, ``external``
    and the robot's parameters.

    **Arguments:**

    - ``robot``: a :class:`~cstiffjax.robot.CableRobot`.
    - ``l0``: (m,) unstrained lengths, m. ``external``: (6,) wrench, N / N·m, or None.
    - ``pose0``: starting pose; default: the ideal-cable pose for ``l0``.
    - ``law``: ``"spring"`` or ``"catenary"`` (elastic), or ``"ideal"`` (inextensible:
      pose from the lengths, tensions by inverse statics).
    - ``solver``: an ``optx`` least-squares solver; ``max_steps``; ``tol``: largest
      allowed residual wrench relative to ``|weight| + |external| + 1``.
    - ``throw``: raise on failure (also under jit); else check ``result``.

    **Returns:** a :class:`ForwardStatics`.
    """
    check_law(law)
    l0 = jnp.asarray(l0, dtype=jnp.float64)
    if pose0 is None:
        pose0, _ = forward_kinematics(robot, l0, throw=False)
    pose0 = jnp.asarray(pose0, dtype=jnp.float64)
    if law == "ideal":
        pose, kin = forward_kinematics(robot, l0, pose0, solver=solver, max_steps=max_steps, throw=False)
        inv = inverse_statics(robot, pose, external, throw=False)
        t = inv.tensions
        res = Status.where(kin == Status.successful, inv.result, kin)
        out = ForwardStatics(pose, t, t, t <= 0, inv.residual, res, jnp.array(0))
        return raise_if_failed(res, out, throw)
    scale = _wrench_scale(robot, external)
    solver = solver or default_solver()
    # Stage 1: cables that may push (smooth, nearly linear) from the ideal pose, where
    # every cable sits exactly at l = l0 and the one-sided law has no gradient.
    start = optx.least_squares(_equilibrium_residual, solver, jnp.zeros(6),
                               args=(robot, pose0, l0, external, "bilateral", scale),
                               max_steps=max_steps, throw=False)
    start = jax.lax.stop_gradient(jnp.where(jnp.all(jnp.isfinite(start.value)), start.value, 0.0))
    # Stage 2: the real law (slack cables go slack; catenaries sag) from there.
    args = (robot, pose0, l0, external, law, scale)
    sol = optx.least_squares(_equilibrium_residual, solver, start,
                             args=args, max_steps=max_steps, throw=False)
    p, R = moved_frame(pose0, sol.value)
    resid = _elastic_wrench_at(robot, p, R, l0, external, law)
    cf = _forces_at(robot, p, R, l0, law)
    # The residual is the criterion: LM may stall at the rounding floor of nested (catenary)
    # solves and hit max_steps with an equilibrium that is already within tolerance.
    stopped = (sol.result == optx.RESULTS.successful) | (sol.result == optx.RESULTS.max_steps_reached)
    ok = stopped & (jnp.max(jnp.abs(resid)) < tol * scale)
    ok = ok & jnp.all(jnp.isfinite(resid))
    result = Status.where(ok, Status.successful, Status.not_converged)
    out = ForwardStatics(
        jnp.concatenate([p, lie.log(R)]), cf.tension_anchor, cf.tension_attachment, cf.slack,
        resid, result, sol.stats["num_steps"],
    )
    return raise_if_failed(result, out, throw)
