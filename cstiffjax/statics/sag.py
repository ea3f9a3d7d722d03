"""Static pose error of a CDPR with sagging cables (Yuan et al. 2015 Sections 3.2.1-3.2.2, 5).

Seed 003 defines the *static pose error* (Section 3.2.2, Fig. 4) in two steps:

1. Pick a reference pose ``x_ref``; the unstrained lengths are the ideal (straight,
   inextensible) ones: ``l0_i = |anchor_i - attachment_i(x_ref)|``.
2. Solve the direct kinematics (our :func:`cstiffjax.statics.forward.forward_statics`) with those
   ``l0`` and the load for each cable model. The ideal model returns ``x_ref`` itself;
   the spring model (massless, elastic) gives ``x_spring``; the sagging model (elastic
   catenary, :mod:`cstiffjax.cable.catenary`) gives ``x_catenary``.

The errors are differences from the ideal pose, position in m and orientation as the
rotation vector ``log(R_model R_refᵀ)`` (base frame, rad):

- ``error_catenary = x_catenary ⊖ x_ref``: the total error (Figs 11(a), 12(a));
- ``error_axial = x_spring ⊖ x_ref``: the part due to axial elasticity (Figs (c));
- ``error_sag = x_catenary ⊖ x_spring``: the sag-introduced part (Figs (b)); this is
  Yuan et al.'s "difference between the results obtained by sagging cable model and ...
  spring cable model". Positions add exactly: ``error_catenary = error_axial + error_sag``
  (rotations to first order).

Note the sign: with ``l0`` equal to the straight lengths, sag makes each chord *shorter*
than the cable, so sag alone lifts a suspended platform, while stretch lowers it.

Inverse statics with sagging cables (Section 3.2.1 a) is :func:`sagging_inverse_statics`:
the ``l0`` that hold a given pose under a given load with catenary cables.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from cstiffjax.cable.laws import CableLaw
from cstiffjax.core import lie
from cstiffjax.core.status import Status, raise_if_failed, solver_errors
from cstiffjax.statics.forward import StaticsProblem, forward_statics, wrench_scale
from cstiffjax.statics.geometry import (
    cable_lengths,
    elastic_cable_forces,
    elastic_wrench,
    frame,
    geometry_status,
    inverse_statics,
)


def ideal_lengths(robot, pose) -> Float[Array, " m"]:
    """Unstrained lengths of the ideal model at ``pose``: the straight lengths, m (step 1)."""
    return cable_lengths(robot, pose)


def pose_difference(pose, reference) -> Float[Array, "6"]:
    """``pose ⊖ reference``: ``[p - p_ref, log(R R_refᵀ)]`` (m, rad; base frame)."""
    p, R = frame(pose)
    q, Q = frame(reference)
    return jnp.concatenate([p - q, lie.log(R @ Q.T)])


class PoseError(eqx.Module):
    """Static pose error of Yuan et al. 2015 Section 3.2.2 at one reference pose (see module doc).

    ``l0`` (m,) ideal lengths, m; ``pose_ideal``/``pose_spring``/``pose_catenary`` (6,);
    ``error_catenary``, ``error_axial``, ``error_sag`` (6,) m / rad;
    ``tensions_spring``/``tensions_catenary`` (m,) N at the exit points;
    ``result_spring``/``result_catenary``: :class:`Status` of the two solves;
    ``converged``: both successful.
    """

    l0: Float[Array, " m"]
    pose_ideal: Float[Array, "6"]
    pose_spring: Float[Array, "6"]
    pose_catenary: Float[Array, "6"]
    error_catenary: Float[Array, "6"]
    error_axial: Float[Array, "6"]
    error_sag: Float[Array, "6"]
    tensions_spring: Float[Array, " m"]
    tensions_catenary: Float[Array, " m"]
    result_spring: Status
    result_catenary: Status
    converged: Bool[Array, ""]


def _pose_error(robot, pose, external, max_steps):
    pose = jnp.asarray(pose, dtype=jnp.float64)
    l0 = ideal_lengths(robot, pose)
    spring = forward_statics(StaticsProblem(robot, l0, external, CableLaw.spring), pose0=pose, max_steps=max_steps,
                             throw=False)
    # the catenary cold start begins with the (bilateral) spring equilibrium itself
    cat = forward_statics(StaticsProblem(robot, l0, external, CableLaw.catenary), pose0=pose, max_steps=max_steps,
                          throw=False)
    e_axial = pose_difference(spring.pose, pose)
    e_cat = pose_difference(cat.pose, pose)
    e_sag = pose_difference(cat.pose, spring.pose)
    # a non-finite pose or an attachment on its anchor: say so, not what the solves made of it
    geo = geometry_status(robot, pose, external)
    valid = geo == Status.successful
    spring_result, cat_result = Status.where(valid, spring.result, geo), Status.where(valid, cat.result, geo)
    ok = (spring_result == Status.successful) & (cat_result == Status.successful)
    return PoseError(l0, pose, spring.pose, cat.pose, e_cat, e_axial, e_sag, spring.tensions, cat.tensions,
                     spring_result, cat_result, ok)


@eqx.filter_jit
def pose_error(robot, pose, external=None, *, max_steps: int = 256, throw: bool = False) -> PoseError:
    """Static pose error of the spring and sagging models at ``pose`` (Yuan et al. 2015 §3.2.2).

    **Arguments:** ``robot``; ``pose`` (6,) reference pose; ``external`` (6,) wrench on
    the platform besides its weight (N, N·m) or None; ``max_steps`` per statics solve;
    ``throw``: raise if a solve fails (else check ``converged``).

    **Returns:** :class:`PoseError`.
    """
    out = _pose_error(robot, pose, external, max_steps)
    return raise_if_failed(Status.where(out.converged, Status.successful, Status.not_converged), out, throw)


@eqx.filter_jit
def pose_error_batch(robot, poses, externals, *, max_steps: int = 256) -> PoseError:
    """:func:`pose_error` vmapped over ``poses`` (n, 6) and ``externals`` (n, 6)."""
    poses = jnp.asarray(poses, dtype=jnp.float64)
    externals = jnp.asarray(externals, dtype=jnp.float64)
    return jax.vmap(lambda p, e: _pose_error(robot, p, e, max_steps))(poses, externals)


def workspace_grid(x, y, z, rotation=(0.0, 0.0, 0.0)) -> Float[Array, "ny nx 6"]:
    """Poses on the grid ``x × y`` at height ``z`` (Yuan et al. 2015 §5: |X|, |Y| ≤ 0.5 m, Z = 0.5 m)."""
    X, Y = jnp.meshgrid(jnp.asarray(x, dtype=jnp.float64), jnp.asarray(y, dtype=jnp.float64))
    rot = jnp.broadcast_to(jnp.asarray(rotation, dtype=jnp.float64), (*X.shape, 3))
    return jnp.concatenate([jnp.stack([X, Y, jnp.full_like(X, z)], -1), rot], -1)


def pose_error_map(robot, x, y, z, external=None, *, max_steps: int = 256) -> PoseError:
    """Pose errors over a workspace grid (Figs 11-12): a :class:`PoseError` of shape (ny, nx)."""
    grid = workspace_grid(x, y, z)
    flat = grid.reshape(-1, 6)
    ext = jnp.zeros(6) if external is None else jnp.asarray(external, dtype=jnp.float64)
    out = pose_error_batch(robot, flat, jnp.broadcast_to(ext, flat.shape), max_steps=max_steps)
    return jax.tree.map(lambda a: a.reshape(*grid.shape[:2], *a.shape[1:]), out)


def vertical_loads(robot, total_masses) -> Float[Array, "n 6"]:
    """External wrenches that make the suspended mass ``total_masses`` (kg; platform included).

    Seed 003 Fig. 7 loads the end-effector with dead weights (10 to 86 kg in all); the
    platform's own weight is already in the statics, so the external force is the rest,
    ``(M - platform_mass) g``, along gravity.
    """
    m = jnp.asarray(total_masses, dtype=jnp.float64)
    f = (m - robot.platform_mass)[:, None] * robot.gravity[None, :]
    return jnp.concatenate([f, jnp.zeros_like(f)], -1)


def load_sweep(robot, pose, total_masses, *, max_steps: int = 256) -> PoseError:
    """Pose error at ``pose`` against the suspended mass (Fig. 7): batch over ``total_masses``."""
    ext = vertical_loads(robot, total_masses)
    poses = jnp.broadcast_to(jnp.asarray(pose, dtype=jnp.float64), ext.shape)
    return pose_error_batch(robot, poses, ext, max_steps=max_steps)


# ------------------------------------------------------------- inverse statics
class SaggingInverse(eqx.Module):
    """Unstrained lengths and tensions that hold a pose with catenary cables.

    ``l0`` (m,) m; ``tensions`` (m,) N at the exit points; ``tensions_attachment`` (m,) N;
    ``l0_reference`` (m,) the spring-law lengths of the ideal tensions (the start and,
    for redundant robots, the point the solution is closest to); ``residual`` (6,) net
    wrench; ``result`` :class:`Status`; ``num_steps``.
    """

    l0: Float[Array, " m"]
    tensions: Float[Array, " m"]
    tensions_attachment: Float[Array, " m"]
    l0_reference: Float[Array, " m"]
    residual: Float[Array, "6"]
    result: Status
    num_steps: Array


def _gauss_newton_map(l0, args):
    robot, pose, external, l_ref, scale = args

    def wrench(l):
        return elastic_wrench(robot, pose, l, external, CableLaw.catenary) / scale

    W, J = wrench(l0), jax.jacfwd(wrench)(l0)
    # min-norm correction: the fixed point has W = 0 and l0 - l_ref in range(Jᵀ) (KKT)
    return l_ref + jnp.linalg.pinv(J) @ (J @ (l0 - l_ref) - W)


@solver_errors
@eqx.filter_jit
def sagging_inverse_statics(robot, pose, external=None, *, max_steps: int = 64, tol: float = 1e-9,
                            throw: bool = True) -> SaggingInverse:
    """Inverse statics with sagging cables (Yuan et al. 2015 §3.2.1 a): ``l0`` and tensions for a pose.

    Unknowns are the unstrained lengths ``l0``; each cable's end forces follow from its
    catenary (:func:`cstiffjax.cable.catenary.catenary_force`) and the platform must be in
    equilibrium (Yuan et al. 2015 eqs 23-26). The start is Yuan et al.'s step (5): ideal tensions
    (minimum norm, :func:`cstiffjax.statics.geometry.inverse_statics`) turned into spring-law
    lengths ``l_ref = l EA/(EA + t)``.

    **Rule** (any number of cables): the solution is the ``l0`` closest to ``l_ref`` in
    the 2-norm among those in equilibrium, i.e. the KKT point of
    ``min |l0 - l_ref|² s.t. W(l0) = 0``, found as the fixed point of the minimum-norm
    Gauss-Newton map ``l0 ← l_ref + J⁺ (J (l0 - l_ref) - W(l0))`` (``J = ∂W/∂l0``). For six
    cables ``J`` is square and the solution is unique (the rule picks nothing).

    **Arguments:** ``robot``, ``pose`` (6,), ``external`` (6,) or None; ``max_steps``;
    ``tol``: largest residual wrench relative to ``|weight| + |external| + 1``; ``throw``.

    **Returns:** :class:`SaggingInverse` (``invalid_input`` for a non-finite pose or wrench,
    ``zero_length`` for an attachment on its anchor, ``infeasible`` if a tension would be
    negative in the ideal start, ``not_converged`` if the fixed point is not reached).
    """
    pose = jnp.asarray(pose, dtype=jnp.float64)
    ideal = inverse_statics(robot, pose, external, throw=False)
    l = cable_lengths(robot, pose)
    l_ref = l * robot.EA / (robot.EA + ideal.tensions)
    scale = wrench_scale(robot, external)
    args = (robot, pose, external, l_ref, scale)
    import optimistix as optx  # optimistix only when traced (cstiffjax.cable.newton2's module doc)

    sol = optx.fixed_point(_gauss_newton_map, optx.FixedPointIteration(rtol=1e-12, atol=1e-12), l_ref,
                           args=args, max_steps=max_steps, throw=False)
    l0 = sol.value
    res = elastic_wrench(robot, pose, l0, external, CableLaw.catenary)
    cf = elastic_cable_forces(robot, pose, l0, CableLaw.catenary)
    ok = (sol.result == optx.RESULTS.successful) & (jnp.max(jnp.abs(res)) < tol * scale)
    ok = ok & jnp.all(jnp.isfinite(res))
    feasible = jnp.all(ideal.tensions > 0)
    result = Status.where(feasible, Status.where(ok, Status.successful, Status.not_converged), Status.infeasible)
    geo = geometry_status(robot, pose, external)  # invalid input wins over what the solve made of it
    result = Status.where(geo == Status.successful, result, geo)
    out = SaggingInverse(l0, cf.tension_anchor, cf.tension_attachment, l_ref, res, result, sol.stats["num_steps"])
    return raise_if_failed(result, out, throw)
