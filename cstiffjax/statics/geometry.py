"""CDPR statics: cable geometry, structure matrix, wrench balance, inverse and forward statics.

Pose and derivative conventions
-------------------------------
A pose is ``x = [x, y, z, rx, ry, rz]``: position of the platform reference point and
orientation as a rotation vector, base frame (m, rad). **All derivatives with respect
to the pose are taken in twist coordinates** ``δx = [δp, δθ]`` of the *base frame*:
the perturbed pose has position ``p + δp`` and orientation ``exp(hat(δθ)) R`` (a small
rotation ``δθ`` about base-frame axes through the platform reference point). This is
the convention of Yuan et al. 2015 eq. (29) (``A_i = [I, -hat(r_i)]``) and of Cui et al.'s
structure matrix; :func:`cstiffjax.stiffness.matrix.to_euler_coordinates` converts to
(x, y, z, α, β, γ).

The structure matrix ``S`` (6 x m) has columns ``[u_i; r_i × u_i]`` where ``u_i`` is the
unit vector from the attachment to the anchor (over a swivel pulley: to the tangent point
T, :mod:`cstiffjax.cable.path`, which is also minus the gradient of the path length) and
``r_i = R b_i``; it is computed by
autodiff as ``S = -(∂l/∂x)ᵀ`` (Cui et al. 2019 eq. 2). The wrench on the platform is
``S t + W_g + W_ext`` (Cui et al. 2019 eq. 3) with ``W_ext = [f, m]`` about the reference point.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from cstiffjax.cable.laws import CABLE_FORCE_LAWS, CableLaw, cable_force, check_law
from cstiffjax.cable.path import robot_paths
from cstiffjax.core import lie
from cstiffjax.core.status import Status, raise_if_failed, solver_errors

Pose = Float[Array, "6"]
BALANCE_TOL = 1e-6  # |S t + W| / (|W| + 1) of tensions that balance a pose (fewer than 6 cables: an equilibrium)


def balanced(unbalanced, load):
    """Whether a residual wrench of norm ``unbalanced`` (``|S t + W|``) balances a load of norm
    ``load`` (``|W|``), N / N·m: within :data:`BALANCE_TOL` ``(|W| + 1)``. numpy or JAX values."""
    return unbalanced <= BALANCE_TOL * (load + 1.0)


# --------------------------------------------------------------------------- geometry
def pose_vector(pose, who: str = "pose") -> Float[Array, "6"]:
    """``pose`` as a float64 array of shape (6,), or a ``ValueError`` naming ``who`` (the
    function called), the shape given and the one expected. A check of the traced shape:
    nothing runs on the device for it.

    **Arguments:** ``pose`` ``[x, y, z, rx, ry, rz]`` (m, rad); ``who`` the caller's name.

    **Returns:** the pose, float64."""
    pose = jnp.asarray(pose, dtype=jnp.float64)
    if pose.shape != (6,):
        raise ValueError(f"{who}: pose has shape {pose.shape}; one pose [x, y, z, rx, ry, rz] (m, rad) of shape "
                         f"(6,) is expected (vmap for a batch)")
    return pose


def frame(pose: Float[Array, "6"]):
    """``(p, R)`` of a pose vector (shape (6,), else a ``ValueError``: :func:`pose_vector`)."""
    pose = pose_vector(pose)
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


class CableGeometry(eqx.Module):
    """Path of every cable at one platform frame (base frame, batched over the ``m`` cables).

    ``offset`` (m, 3) ``R b_i``, m; ``attachment`` (m, 3) ``p + R b_i``, m; ``exit`` (m, 3)
    the point where the free span leaves the base (the anchor, or the tangent point T of
    its swivel pulley), m; ``vector`` (m, 3) attachment → exit, m; ``length`` (m,) path
    length (``r beta + |P - T|`` over a pulley), m; ``direction`` (m, 3) unit vector
    attachment → exit (the direction of the cable's pull on the platform); ``wrap``
    (m,) length ``r beta`` wrapped on the pulley, m (0 for a straight cable).
    """

    offset: Float[Array, "m 3"]
    attachment: Float[Array, "m 3"]
    exit: Float[Array, "m 3"]
    vector: Float[Array, "m 3"]
    length: Float[Array, " m"]
    direction: Float[Array, "m 3"]
    wrap: Float[Array, " m"]


def cable_geometry(robot, p: Float[Array, "3"], R: Float[Array, "3 3"]) -> CableGeometry:
    """Cable paths from the anchors (straight, or over swivel pulleys:
    :func:`cstiffjax.cable.path.cable_path`) to the attachments at the frame ``(p, R)``.

    The one place where the cable geometry is computed: lengths, the structure matrix,
    every cable law and both stages of :func:`cstiffjax.statics.forward.forward_statics` read
    it. Without pulleys its numbers are those of the straight-cable formulas, bit for bit.
    """
    offset = robot.attachments @ R.T
    attachment = p + offset
    path = robot_paths(robot, attachment)
    return CableGeometry(offset, attachment, path.tangent_point, path.tangent_point - attachment, path.length,
                         path.direction, robot.pulley_radius * path.wrap)


def attachment_points(robot, pose: Pose) -> Float[Array, "m 3"]:
    """Attachment points in the base frame, m."""
    return cable_geometry(robot, *frame(pose)).attachment


def cable_vectors(robot, pose: Pose) -> Float[Array, "m 3"]:
    """Vectors from each attachment to its anchor, base frame, m (Cui et al. 2019 eq. 1, negated)."""
    return cable_geometry(robot, *frame(pose)).vector


def lengths_at(robot, p, R):
    return cable_geometry(robot, p, R).length


def cable_lengths(robot, pose: Pose) -> Float[Array, " m"]:
    """Cable path lengths, m: ``|a_i - p - R b_i|`` for straight cables, ``r beta + |P - T|``
    over a swivel pulley (:func:`cstiffjax.cable.path.cable_path`). A ``pose`` of another
    shape than (6,) is a ``ValueError`` (:func:`pose_vector`)."""
    return lengths_at(robot, *frame(pose_vector(pose, "cable_lengths")))


def geometry_status(robot, pose: Pose, external=None) -> Status:
    """Whether the cable geometry is defined at ``pose``: ``invalid_input`` for a non-finite
    pose (or ``external`` wrench), ``zero_length`` when an attachment sits on its anchor (a
    free span ``|T - P|`` within 1e-12 of the frame size: no cable direction, no
    stiffness), else ``successful``. The lengths there are exactly 0 and their derivatives
    finite (:func:`cstiffjax.cable.path.norm_and_divisor`): this status is what says they
    mean nothing.

    **Arguments:** ``robot``; ``pose`` (6,) m / rad; ``external`` (6,) N / N·m or None.

    **Returns:** a :class:`~cstiffjax.core.status.Status`.
    """
    pose = jnp.asarray(pose, dtype=jnp.float64)
    finite = jnp.all(jnp.isfinite(pose)) & jnp.all(jnp.isfinite(external_wrench(external)))
    size = jnp.max(jnp.linalg.norm(robot.anchors, axis=1)) + jnp.max(jnp.linalg.norm(robot.attachments, axis=1))
    # free-span length |T - P| (the anchor for a straight cable), not the path length
    l = jnp.linalg.norm(cable_geometry(robot, *frame(jnp.where(finite, pose, 0.0))).vector, axis=-1)
    status = Status.where(jnp.min(l) > 1e-12 * (size + 1.0), Status.successful, Status.zero_length)
    return Status.where(finite, status, Status.invalid_input)


def structure_matrix(robot, pose: Pose) -> Float[Array, "6 m"]:
    """Structure matrix ``S = -(∂l/∂x)ᵀ`` by autodiff of the cable lengths (6 x m).

    NaN wherever the pose is not finite (never a finite made-up value; the cable lengths
    are NaN there too); a ``pose`` of another shape than (6,) is a ``ValueError``."""
    pose = pose_vector(pose, "structure_matrix")
    return -twist_jacobian(lambda p, R: lengths_at(robot, p, R), pose).T


def structure_matrix_closed_form(robot, pose: Pose) -> Float[Array, "6 m"]:
    """Closed form ``[u_i; (R b_i) × u_i]`` (Cui et al. 2019 below eq. 2), for checking."""
    g = cable_geometry(robot, *frame(pose))
    return jnp.concatenate([g.direction, jnp.cross(g.offset, g.direction)], axis=-1).T


def gravity_wrench(robot, pose: Pose) -> Float[Array, "6"]:
    """Weight of the platform as a wrench about the reference point, base frame."""
    _, R = frame(pose_vector(pose, "gravity_wrench"))
    f = robot.weight
    return jnp.concatenate([f, jnp.cross(R @ robot.com, f)])


def external_wrench(external) -> Float[Array, "6"]:
    """``external`` ``[f, m]`` (N, N·m) as a float64 (6,) array, zeros for None; another
    shape is a ``ValueError`` (a check of the traced shape)."""
    if external is None:
        return jnp.zeros(6)
    external = jnp.asarray(external, dtype=jnp.float64)
    if external.shape != (6,):
        raise ValueError(f"external wrench has shape {external.shape}; [fx, fy, fz, mx, my, mz] (N, N·m) of shape "
                         f"(6,) is expected, or None")
    return external


def wrench(robot, pose: Pose, tensions: Float[Array, " m"], external=None) -> Float[Array, "6"]:
    """Net wrench on the platform: ``S t + W_gravity + W_ext`` (zero at equilibrium).

    **Arguments:** ``tensions`` N (straight massless cables); ``external`` ``[f, m]``
    (N, N·m) about the reference point, base frame, weight excluded.
    """
    S = structure_matrix_closed_form(robot, pose)
    return S @ tensions + gravity_wrench(robot, pose) + external_wrench(external)


# --------------------------------------------------------------------- elastic cables
def _forces_at(robot, p, R, l0, law):
    att = p + robot.attachments @ R.T
    return jax.vmap(lambda a, b, l, ea, w, rad, ax: cable_force(law, a, b, l, ea, w, robot.gravity, rad, ax))(
        robot.anchors, att, l0, robot.EA, robot.mass_per_length, robot.pulley_radius, robot.pulley_axis
    )


def platform_wrench(robot, R, offset, forces, external) -> Float[Array, "6"]:
    """Net wrench on the platform (N, N·m about the reference point, base frame): cable
    ``forces`` (m, 3) acting at the ``offset`` (m, 3) ``R b_i``, the weight at ``R com``,
    and ``external`` (6,) or None."""
    w_g = robot.weight
    return jnp.concatenate([jnp.sum(forces, 0) + w_g, jnp.sum(jnp.cross(offset, forces), 0)
                            + jnp.cross(R @ robot.com, w_g)]) + external_wrench(external)


def elastic_wrench_at(robot, p, R, l0, external, law):
    cf = _forces_at(robot, p, R, l0, law)
    return platform_wrench(robot, R, cable_geometry(robot, p, R).offset, cf.on_platform, external)


def elastic_cable_forces(robot, pose: Pose, l0: Float[Array, " m"], law: CableLaw = CableLaw.spring):
    """Every cable's :class:`~cstiffjax.cable.force.CableForce` (batched over the cables) at
    ``pose`` for cables of unstrained lengths ``l0`` (m) under ``law``, one of
    :data:`~cstiffjax.cable.laws.CABLE_FORCE_LAWS` (the one-cable laws of
    :func:`~cstiffjax.cable.laws.cable_force`)."""
    law = check_law(law, CABLE_FORCE_LAWS, "elastic_cable_forces")
    return _forces_at(robot, *frame(pose), jnp.asarray(l0, dtype=jnp.float64), law)


def elastic_wrench(robot, pose: Pose, l0, external=None, law: CableLaw = CableLaw.spring) -> Float[Array, "6"]:
    """Net wrench on the platform for elastic cables of unstrained lengths ``l0`` under
    ``law`` (:data:`~cstiffjax.cable.laws.CABLE_FORCE_LAWS`), N, N·m."""
    law = check_law(law, CABLE_FORCE_LAWS, "elastic_wrench")
    return elastic_wrench_at(robot, *frame(pose), jnp.asarray(l0, dtype=jnp.float64), external, law)


# ---------------------------------------------------------------------- inverse statics
class InverseStatics(eqx.Module):
    """Tensions holding a pose. ``tensions`` N; ``result`` a :class:`Status`
    (``infeasible`` when outside ``[tension_min, tension_max]``, ``singular`` when S is
    rank deficient); ``residual`` the wrench left unbalanced, N / N·m."""

    tensions: Float[Array, " m"]
    residual: Float[Array, "6"]
    result: Status


@solver_errors
@eqx.filter_jit
def inverse_statics(robot, pose: Pose, external=None, *, throw: bool = True) -> InverseStatics:
    """Minimum-norm tensions with ``S t = -(W_g + W_ext)`` (Cui et al. 2019 eq. 20, particular part).

    For a 6-cable robot this is the unique solution. The status is ``invalid_input`` for a
    non-finite pose or wrench and ``zero_length`` for an attachment on its anchor
    (:func:`geometry_status`), else ``singular`` when ``S`` is rank deficient and
    ``infeasible`` when a tension leaves ``[tension_min, tension_max]``: for redundant
    robots use :func:`cstiffjax.stiffness.tensions.feasible_tensions` to search the null space.

    With fewer than 6 cables (an under-constrained robot, :mod:`cstiffjax.statics.suspended`)
    ``t`` is the least-squares answer: the unique balancing tensions where ``pose`` is an
    equilibrium under this load, else no tensions hold it; then the status is
    ``infeasible`` and ``residual`` says how far (``|S t + W| > 1e-6 (|W| + 1)``; the
    equilibrium for given lengths is :func:`cstiffjax.statics.forward.forward_statics`'s).
    ``singular`` then means fewer than ``m`` independent cable directions.

    A ``pose`` of another shape than (6,), or an ``external`` other than (6,) or None, is a
    ``ValueError`` when the call is traced (:func:`pose_vector`). With ``throw=True`` a
    failure raises :class:`~cstiffjax.core.errors.SolverError` with the status text
    (under your own ``jax.jit``: :mod:`cstiffjax.core.status`).
    """
    pose = pose_vector(pose, "inverse_statics")
    S = structure_matrix_closed_form(robot, pose)
    w = gravity_wrench(robot, pose) + external_wrench(external)
    inputs = geometry_status(robot, pose, external)
    t = -jnp.linalg.pinv(S) @ w
    res = S @ t + w
    sv = jnp.linalg.svd(S, compute_uv=False)
    singular = sv[-1] < 1e-9 * sv[0]
    feasible = jnp.all(t >= robot.tension_min - 1e-9) & jnp.all(t <= robot.tension_max + 1e-9)
    if S.shape[1] < 6:  # under-constrained: only an equilibrium pose has balancing tensions
        feasible = feasible & balanced(jnp.linalg.norm(res), jnp.linalg.norm(w))
    result = Status.where(singular, Status.singular, Status.where(feasible, Status.successful, Status.infeasible))
    result = Status.where(inputs == Status.successful, result, inputs)
    return raise_if_failed(result, InverseStatics(t, res, result), throw)


__all__ = ["CableGeometry", "InverseStatics", "apply_twist", "attachment_points",
           "cable_geometry", "cable_lengths", "cable_vectors", "elastic_cable_forces", "elastic_wrench",
           "frame", "geometry_status", "gravity_wrench", "inverse_statics", "moved_frame",
           "platform_wrench", "pose_vector", "structure_matrix", "structure_matrix_closed_form", "twist_jacobian",
           "wrench"]
