"""Under-constrained robots (fewer than 6 cables): where gravity closes the equilibrium.

A platform on ``m < 6`` cables is not held in place by its cable lengths: it settles where
the cables' elastic energy plus its weight's potential is least (a cable camera, a
Hangprinter-like printer, a 4-cable suspended robot). Forward statics
(:func:`cstiffjax.statics.forward.forward_statics`) solves the same 6 equilibrium equations
in 6 pose unknowns as for any other robot; what changes is

- the start: the ideal-cable pose of ``l0`` is a whole family of poses, and a root finder
  started anywhere in it may land on an upside-down balance. :func:`energy_start` takes
  the pose of least potential energy of straight one-sided spring cables plus the weight
  (the external force's work included, its moment to first order) from there, a damped
  Newton descent on the energy (:func:`descend`);
- the verdict: an equilibrium of an under-constrained robot may be a saddle (the platform
  balanced above the point its cables pull at) or have a direction with no restoring force
  at all (every cable through one platform point: a free spin about the vertical).
  :func:`stiffness_at` is the equilibrium's stiffness ``K = -∂W/∂x`` of the law solved
  (the weight's term included: ``W`` is the net wrench), and :func:`is_stable` says whether
  its symmetric part is positive definite; :func:`cstiffjax.statics.forward.forward_statics`
  reports ``Status.unstable`` where it is not.

Every function here is written for one problem (``vmap`` for a batch) and carries no
derivative (the start and the verdict are not differentiated).
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from cstiffjax.cable.laws import CableLaw
from cstiffjax.core.linalg import solve
from cstiffjax.statics.geometry import apply_twist, cable_geometry, moved_frame
from cstiffjax.statics.residuals import ResidualArgs, residual_fn

FULL = 6  # cables from which the lengths alone hold a 6-DOF platform (below: gravity closes the equilibrium)
DESCENT_STEPS = 200  # most trial steps of the energy descent
STABLE_TOL = 1e-6  # least eigenvalue of the scaled stiffness, relative to the wrench scale / platform size


def under_constrained(robot) -> bool:
    """Whether ``robot`` has fewer than :data:`FULL` cables (known before tracing)."""
    return robot.anchors.shape[-2] < FULL


def potential_energy(robot, l0, external, pose0, twist) -> Float[Array, ""]:
    """Potential energy (J) at the base-frame ``twist`` (6) from ``pose0`` (6): straight
    one-sided spring cables ``Σ EA (l - l0)₊² / (2 l0)`` (their tension ``EA (l - l0)/l0`` is
    its derivative), the weight's ``-m g·(p + R com)`` and the external force's ``-f·p``,
    with the external moment's ``-M·δθ`` (exact to first order in the rotation: enough for a
    start).

    **Arguments:** ``robot``; ``l0`` (m,) m; ``external`` (6,) N / N·m; ``pose0`` (6,)
    m / rad; ``twist`` (6,) m / rad.

    **Returns:** the energy, J."""
    p, R = moved_frame(pose0, twist)
    g = cable_geometry(robot, p, R)
    stretch = jnp.maximum(g.length - l0, 0.0)
    cables = jnp.sum(robot.EA * stretch * stretch / (2.0 * l0))
    return cables - robot.weight @ (p + R @ robot.com) - external[:3] @ p - external[3:] @ twist[3:]


def descend(energy, z0, max_steps: int = DESCENT_STEPS):
    """A local minimum of ``energy(z)`` (a scalar of a small vector) from ``z0``, no gradients:
    damped Newton steps on the eigenvalues' magnitudes (a saddle's negative curvature is
    descended, not climbed: ``s = -V diag(1/(|e| + λ)) Vᵀ g``), ``λ`` relative to the
    largest ``|e|`` (from 1e-6; a step that does not lower the energy multiplies it by 8,
    one that does divides it by 3). Stops once an accepted step is below 1e-12 in every
    unknown, when ``λ`` exceeds 1e12, or after ``max_steps`` trials.

    **Returns:** ``(z, steps)``."""
    grad_hess = jax.jacfwd(jax.grad(energy), has_aux=False)

    def body(c):
        i, z, e, lam, _ = c
        g, H = jax.grad(energy)(z), grad_hess(z)
        ev, V = jnp.linalg.eigh(0.5 * (H + H.T))
        big = jnp.max(jnp.abs(ev)) + 1e-300
        step = -V @ ((V.T @ g) / (jnp.abs(ev) + lam * big))
        z_new = z + step
        e_new = energy(z_new)
        good = jnp.isfinite(e_new) & (e_new < e) & jnp.all(jnp.isfinite(step))
        small = jnp.max(jnp.abs(step)) <= 1e-12
        lam = jnp.where(good, lam / 3.0, lam * 8.0)
        done = (good & small) | (lam > 1e12) | ~jnp.isfinite(e)
        return i + 1, jnp.where(good, z_new, z), jnp.where(good, e_new, e), lam, done

    init = (jnp.zeros((), jnp.int32), z0, energy(z0), jnp.asarray(1e-6, z0.dtype), jnp.zeros((), bool))
    i, z, *_ = jax.lax.while_loop(lambda c: (c[0] < max_steps) & ~c[4], body, init)
    return jax.lax.stop_gradient(z), i


def energy_start(robot, l0, external, pose0) -> Float[Array, "6"]:
    """The pose (6,) m / rad of least :func:`potential_energy` found by :func:`descend` from
    ``pose0`` (e.g. an ideal-cable pose of ``l0``): where a suspended platform on straight
    spring cables hangs, the start of the forward statics of an under-constrained robot.

    **Arguments:** ``robot``; ``l0`` (m,) m; ``external`` (6,) N / N·m; ``pose0`` (6,).

    **Returns:** the pose, without derivative."""
    l0, external, pose0 = jax.lax.stop_gradient((l0, external, pose0))
    z, _ = descend(lambda z: potential_energy(robot, l0, external, pose0, z), jnp.zeros(6))
    return jax.lax.stop_gradient(apply_twist(pose0, z))


def stiffness_at(law: CableLaw, z: Float[Array, " k"], args: ResidualArgs) -> Float[Array, "6 6"]:
    """The stiffness ``K = -∂W/∂x`` (6x6; rows N, N·m; columns m, rad, base-frame twist at the
    solution) of the equilibrium ``z`` of ``law``'s residual (:func:`~cstiffjax.statics.residuals.residual_fn`:
    the net wrench, the weight included, divided by ``args.scale``). For the catenary the
    end forces ``z[6:]`` follow the pose (the span equations held: the Schur complement of the
    joint Jacobian). No derivative."""
    z, args = jax.lax.stop_gradient((z, args))
    at = ResidualArgs(args.robot, args.l0, args.external, args.tension, apply_twist(args.pose0, z[:6]), args.scale)
    y = jnp.concatenate([jnp.zeros(6), z[6:]])
    J = jax.jacfwd(lambda v: residual_fn(law)(v, at))(y)
    K = J[:6, :6]
    if y.shape[0] > 6:  # catenary: eliminate the end forces
        K = K - J[:6, 6:] @ solve(J[6:, 6:], J[6:, :6])
    return -K * args.scale


def platform_size(robot) -> Float[Array, ""]:
    """The platform's size (m): the farthest attachment or the com from the reference point,
    at least 1e-3 of the anchors' extent (a point platform has no size of its own)."""
    arm = jnp.maximum(jnp.max(jnp.linalg.norm(robot.attachments, axis=1)), jnp.linalg.norm(robot.com))
    return jnp.maximum(arm, 1e-3 * jnp.max(jnp.linalg.norm(robot.anchors - robot.anchors[0], axis=1)) + 1e-12)


def scaled_stiffness(K: Float[Array, "6 6"], size) -> Float[Array, "6 6"]:
    """The symmetric part of ``D K D``, ``D = diag(1, 1, 1, 1/size × 3)``: the stiffness ``K``
    (twist coordinates) with rotations as displacements at the platform's ``size`` (m), every
    entry in N/m; its eigenvalues are what :func:`is_stable` judges."""
    d = jnp.concatenate([jnp.ones(3), jnp.full(3, 1.0 / size)])
    Ks = d[:, None] * K * d[None, :]
    return 0.5 * (Ks + Ks.T)


def is_stable(K: Float[Array, "6 6"], size, scale) -> Bool[Array, ""]:
    """Whether the stiffness ``K`` (6x6, twist coordinates) holds the platform: the least
    eigenvalue of the symmetric part of ``D K D``, ``D = diag(1, 1, 1, 1/size × 3)`` (rotations
    as displacements at the platform's ``size``, m: every entry in N/m), is above
    :data:`STABLE_TOL` ``× scale / size`` (``scale`` the wrench scale, N; a pendulum of length
    ``h`` has ``~ scale h / size²``, stable far below ``h = size``). False for a saddle, a
    neutral direction or a non-finite ``K``. The symmetric part is the covariant stiffness at
    an equilibrium (:mod:`cstiffjax.stiffness.matrix`)."""
    Ks = scaled_stiffness(K, size)
    finite = jnp.all(jnp.isfinite(Ks))
    ev = jnp.linalg.eigvalsh(jnp.where(finite, Ks, 0.0))
    return finite & (ev[0] > STABLE_TOL * scale / size)
