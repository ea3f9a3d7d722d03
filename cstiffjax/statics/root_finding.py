"""The iterations of forward statics (:mod:`cstiffjax.statics.forward`), for small dense
systems ``fn(z) = 0``: forward-mode linearization, the warm start's clipped Newton steps
(with an optional chord exit), the cold start's dense Levenberg-Marquardt (or an
optimistix solver) and the implicit step that gives the solve its derivative.

None of them carries a gradient but :func:`implicit_step`: the solves run under
``stop_gradient`` and return the Jacobian at their solution (None from an optimistix
solver: the caller forms it), which the implicit step reuses.
"""

import jax
import jax.numpy as jnp

from cstiffjax.core.arrays import batched_like
from cstiffjax.core.linalg import solve

NEWTON_STOP = 1e-10  # a warm Newton step this small (m, rad; end forces / wrench scale) ends the iteration
CHORD_STEP = 1e-6  # values only (derivatives=False): after a step this small, one residual evaluation may end it


def linearize(fn, z):
    """``(f, J)``: ``fn(z)`` and its Jacobian (forward mode, one pass)."""
    J, f = jax.jacfwd(lambda y: (fn(y), fn(y)), has_aux=True)(z)
    return f, J


def newton(fn, z0, steps, max_step, chord: bool = False):
    """At most ``steps`` clipped Newton steps on ``fn(z) = 0`` (no gradients); returns
    ``(z, J, taken)`` with ``J = ∂fn/∂z`` *at the returned* ``z`` (the implicit step reuses
    it: no second linearization in the program or at run time).

    Every iteration linearizes at the current ``z`` and solves for the full step. Once
    that step is no larger than :data:`NEWTON_STOP` in every unknown (Newton converges
    quadratically: the steps after it would move ``z`` by rounding only), or after
    ``steps`` applied steps, the iteration ends *without* applying it, so ``J`` belongs
    to ``z``; the caller's implicit step then takes that last step with gradients. A
    non-finite step leaves ``z`` as it is and does not end the iteration. ``taken`` counts
    the applied steps plus the final converged one: the linearizations of a converged
    solve. Under ``vmap`` every sample keeps its own ``z`` and count.

    ``chord`` (values only, no derivative will be taken; for an ``fn`` whose Jacobian does
    not change by O(1) within a step of :data:`CHORD_STEP` near the solution): after
    applying a step no larger than :data:`CHORD_STEP`, the step from
    the new ``z`` with the *same* ``J`` (one residual evaluation, no linearization) is
    formed too; when it is within :data:`NEWTON_STOP` the iteration ends there and ``J`` is
    the one of the step before (off by ~``CHORD_STEP`` relative). Where ``fn`` stiffens
    between the two points (a kink) that step is not small and the iteration goes on as
    without ``chord``; where it *softens* (a cable going slack under the one-sided
    ``spring`` law) the old, stiffer ``J`` understates the step, so that law never
    uses it (:func:`cstiffjax.statics.forward._solve`). From a start whose first step is
    small enough (the posterior walkers' :func:`fitting.effects.model.chord_start`; a
    start 1e-8 away in the tests) this ends after one linearization instead of two
    (``taken`` 1 instead of 2).

    The loop's counters and Jacobian start batched as ``z0`` is
    (:func:`~cstiffjax.core.arrays.batched_like`): under ``vmap`` pass a ``z0`` batched as
    the problem is, or the body is traced up to three times."""
    def body(c):
        k, taken, z, _, _, _ = c
        f, J = linearize(fn, z)
        step = solve(J, f)
        size = jnp.max(jnp.abs(step))
        finite = jnp.all(jnp.isfinite(step))
        converged = finite & (size <= NEWTON_STOP)
        k = k + 1  # linearizations so far: at most steps + 1 (the last one only gives J)
        apply = finite & ~converged & (k <= steps)
        z = jnp.where(apply, z - step * jnp.minimum(1.0, max_step / (size + 1e-300)), z)
        done = converged | (k > steps)
        if chord:
            nxt = solve(J, fn(z))
            done = done | (apply & (size <= CHORD_STEP) & jnp.all(jnp.abs(nxt) <= NEWTON_STOP))
        return k, taken + apply.astype(k.dtype), z, J, done, converged

    zero = batched_like(jnp.zeros((), jnp.int32), z0)  # the carry batched as z0 is: one batching pass
    no = batched_like(jnp.zeros((), bool), z0)
    init = (zero, zero, z0, batched_like(jnp.zeros((z0.shape[0],) * 2, z0.dtype), z0), no, no)
    _, taken, z, J, _, converged = jax.lax.while_loop(lambda c: ~c[4], body, init)
    return jax.lax.stop_gradient(z), jax.lax.stop_gradient(J), taken + converged.astype(taken.dtype)


def dense_lm(fn, z0, max_steps, rtol=1e-10, atol=1e-10):
    """Levenberg-Marquardt on ``fn(z) = 0`` for the small dense systems of the cold start
    (6 or ``6 + 2m`` unknowns; no gradients): ``(z, J, ok, num_steps)``, ``J`` the
    Jacobian at the returned ``z`` (carried by the iteration, reused by the implicit step).

    Damped Gauss-Newton steps ``(JᵀJ + λ I) s = -Jᵀf`` with the exact Jacobian (forward
    mode) and the classical trust-region control of ``λ = 1/radius`` that optimistix's
    ``LevenbergMarquardt`` uses (start ``λ = 1``; a trial is accepted when the gain ratio
    ``ρ`` (actual over predicted decrease of ``|f|²``) is at least 0.01; ``ρ > 0.99``
    divides ``λ`` by 3.5, a rejection multiplies it by 4). It stops once an accepted step
    is within ``atol + rtol max|z|`` in every unknown, when ``|f|`` reaches 1e-15, when
    ``λ`` exceeds 1e16 (no further decrease) or after ``max_steps`` trials. ``ok`` is
    false only when ``z`` is not finite: the caller checks the residual. Same steps as
    optimistix's solver (``solver=`` still selects it), written as one small
    ``while_loop``: it compiles in about half the time (the cold start is part of most
    programs of the toolkit and of its tests).
    """
    def lin(z):
        return linearize(fn, z)

    def body(c):
        i, z, f, J, lam, _ = c
        A, g = J.T @ J, J.T @ f
        step = -solve(A + lam * jnp.eye(z.shape[0], dtype=z.dtype), g)
        z_new = z + step
        f_new, J_new = lin(z_new)
        cost, cost_new = f @ f, f_new @ f_new
        pred = cost - jnp.sum((f + J @ step) ** 2)
        rho = (cost - cost_new) / jnp.where(pred > 0, pred, jnp.inf)
        good = jnp.all(jnp.isfinite(step)) & jnp.isfinite(cost_new) & (rho >= 0.01)
        lam = jnp.where(good, jnp.where(rho > 0.99, lam / 3.5, lam), lam * 4.0)
        small = jnp.max(jnp.abs(step)) <= atol + rtol * jnp.max(jnp.abs(z_new))
        pick = lambda a, b: jnp.where(good, a, b)  # noqa: E731
        f, z = pick(f_new, f), pick(z_new, z)
        done = (good & small) | (jnp.max(jnp.abs(f)) <= 1e-15) | (lam > 1e16)
        return i + 1, z, f, pick(J_new, J), lam, done

    f0, J0 = lin(z0)
    like = lambda v: batched_like(v, f0)  # noqa: E731  (the carry batched as f0 is: one batching pass)
    init = (like(jnp.zeros((), jnp.int32)), like(z0), f0, like(J0), like(jnp.asarray(1.0, z0.dtype)),
            jnp.max(jnp.abs(f0)) <= 1e-15)
    i, z, _, J, *_ = jax.lax.while_loop(lambda c: (c[0] < max_steps) & ~c[5], body, init)
    return jax.lax.stop_gradient(z), jax.lax.stop_gradient(J), jnp.all(jnp.isfinite(z)), i


def least_squares_root(fn, z0, args, solver, max_steps):
    """A root of ``fn(z, args)`` by least squares (Levenberg-Marquardt; no gradients): ``(z, J, ok, num_steps)``
    (``J`` the Jacobian at ``z``; None from an optimistix solver, the caller forms it);
    ``ok`` false on a solver failure other than running out of steps (the residual is
    checked afterwards). ``solver`` None: :func:`dense_lm`; else an optimistix
    least-squares solver (LM may stall at the rounding floor of an equilibrium that is
    within tolerance; optimistix reports that as ``nonlinear_max_steps_reached``,
    ``max_steps_reached`` is lineax's code)."""
    if solver is None:
        return dense_lm(lambda z: fn(z, args), z0, max_steps)
    import optimistix as optx  # optimistix only when traced (cstiffjax.cable.newton2's module doc)

    sol = optx.least_squares(fn, solver, z0, args=args, max_steps=max_steps, throw=False)
    z = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, z0)
    ok = (sol.result == optx.RESULTS.successful) | (sol.result == optx.RESULTS.nonlinear_max_steps_reached)
    return jax.lax.stop_gradient(z), None, ok, sol.stats["num_steps"]


def implicit_step(fn, z, J, live):
    """One Newton step whose derivative is the implicit-function derivative ``-J⁻¹ ∂F/∂θ``."""
    return z - solve(J, fn(z, live))
