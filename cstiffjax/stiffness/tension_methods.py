"""Tension distribution methods of redundant CDPRs: CFM, improved CFM, Dykstra, QP.

Every method picks tensions ``t`` (N) with ``S t = -(W_g + W_ext)`` (Cui et al. 2019 eq. 3) and,
where it can, ``t_min <= t <= t_max``; all are written for one pose (jit and vmap them)
and return a :class:`TensionDistribution` with a :class:`~cstiffjax.core.status.Status`.
``t_m = (t_min + t_max)/2`` is the mid tension; ``t_p``, ``N`` the minimum-norm solution
and the orthonormal null basis (:func:`cstiffjax.stiffness.tensions.tension_space`).

- ``"cfm"``: Pott's closed-form method (Pott, Bruckmann & Mikelsons 2009):
  ``t = t_m - S⁺(W + S t_m) = t_p + N Nᵀ t_m``, the tensions closest to ``t_m`` in the
  2-norm, limits ignored; ``infeasible`` when they leave the limits.
- ``"icfm"``: improved closed-form method (Pott 2013, "An improved force distribution
  algorithm for over-constrained cable-driven parallel robots"): while some tension
  violates a limit, the cable with the largest violation is fixed at that limit and the
  CFM is repeated on the remaining cables (at most ``r = m - 6`` times; fewer than 6 free
  cables left means ``infeasible``). A heuristic: it can report ``infeasible`` where
  feasible tensions exist.
- ``"dykstra"``: Dykstra's alternating projection between the box of limits and the
  affine set of balancing tensions, started at ``t_m`` (Hassan & Khajepour 2011): it
  converges to the projection of ``t_m`` on their intersection, i.e. the 2-norm QP
  optimum; ``infeasible`` when the iterates stop moving with a gap between the sets,
  ``not_converged`` after ``max_steps``.
- ``"qp"``: objective ``"2-norm"`` (``min |t - t_m|²``, a convex QP solved by
  ``jaxopt.BoxOSQP``, ADMM) or ``"max"`` (``min max_i t_i``, an LP solved exactly by
  vertex enumeration in the null-space coordinates, :func:`min_max_tension`; ADMM does
  not converge on it).

Every answer is checked before it is called ``successful``: within the limits to
``1e-6`` N and balanced, ``|S t + W| <= 1e-6 (|W| + 1)``.

One answer whatever the method: without redundancy (``m = 6``) the balancing tensions are
unique and every method returns them (``infeasible`` when they leave the limits), whatever
``t_max`` (``inf`` allowed: ``t_m`` is not used). With redundancy, where the tensions
closest to ``t_m`` lie within the limits, ``cfm``, ``icfm``, ``dykstra`` and ``qp``
(``"2-norm"``) all return them; the methods then need a finite ``t_max`` (``t_m`` is their
target): with ``t_max = inf`` the result is ``invalid_input`` (:func:`needs_finite_max`).
``qp`` (``"2-norm"``) tells an infeasible pose from one ADMM did not finish by an exact
feasibility test when ADMM stops unsolved (vertex enumeration for ``r <= 2``, Dykstra's
gap otherwise): ``infeasible``, not ``not_converged``.
"""

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from cstiffjax.core.status import Status, raise_if_failed, solver_errors
from cstiffjax.statics.geometry import external_wrench, gravity_wrench, structure_matrix_closed_form
from cstiffjax.stiffness.tensions import tension_space

METHODS = ("cfm", "icfm", "dykstra", "qp")
OBJECTIVES = ("2-norm", "max")
_FEAS_TOL = 1e-6


class TensionDistribution(eqx.Module):
    """Tensions ``(m,)`` N, wrench residual ``S t + W`` ``(6,)``, ``result`` and ``num_steps``
    (iterations: 1 for CFM, fixings + 1 for ICFM, sweeps for Dykstra, ADMM steps for QP)."""

    tensions: Float[Array, " m"]
    residual: Float[Array, "6"]
    result: Status
    num_steps: Array


def _load(robot, pose, external):
    return structure_matrix_closed_form(robot, pose), gravity_wrench(robot, pose) + external_wrench(external)


def needs_finite_max(num_cables: int, method: str, objective: str = "2-norm") -> bool:
    """Whether ``method`` (``objective``) needs a finite ``tension_max``: a redundant robot
    (``num_cables > 6``) and a method whose target is the mid tension ``t_m`` (every one but
    ``qp`` with ``"max"``)."""
    return num_cables > 6 and not (method == "qp" and objective == "max")


def _mid(robot):
    """``(m,)`` target tensions ``t_m = (t_min + t_max)/2`` (N) of a redundant robot; zeros
    without redundancy (the balancing tensions are unique: no target, and ``t_max = inf`` is fine)."""
    m = robot.num_cables
    if m <= 6:
        return jnp.zeros(m)
    return 0.5 * (robot.tension_min + robot.tension_max) * jnp.ones(m)


def _checked(robot, S, W, t, status, steps, throw):
    """Final check of limits and balance; ``status`` is the method's own verdict."""
    res = S @ t + W
    ok = (jnp.all(t >= robot.tension_min - _FEAS_TOL) & jnp.all(t <= robot.tension_max + _FEAS_TOL)
          & (jnp.linalg.norm(res) <= _FEAS_TOL * (jnp.linalg.norm(W) + 1.0)) & jnp.all(jnp.isfinite(t)))
    result = Status.where(status != Status.successful, status,
                          Status.where(ok, Status.successful, Status.infeasible))
    out = TensionDistribution(jnp.where(jnp.isfinite(t), t, 0.0), res, result, jnp.asarray(steps))
    return raise_if_failed(result, out, throw)


def _space_status(space):
    return Status.where(space.result != Status.successful, space.result, Status.successful)


def cfm(robot, pose, external=None):
    """Closed-form method: ``(t, status, steps)`` (see the module docstring)."""
    space = tension_space(robot, pose, external)
    tm = _mid(robot)
    t = space.particular + space.null_basis @ (space.null_basis.T @ tm)
    return t, _space_status(space), 1


def _reduced_cfm(S, W, tm, fixed, t_fixed):
    """CFM on the free cables with the fixed ones held at ``t_fixed``: the tensions of the
    free cables closest to ``t_m`` that balance ``W + S_fixed t_fixed``."""
    free = ~fixed
    Sf = S * free[None]
    b = -(W + S @ jnp.where(fixed, t_fixed, 0.0))
    tf = jnp.where(free, tm, 0.0)
    t = tf + jnp.linalg.pinv(Sf) @ (b - Sf @ tf)
    return jnp.where(fixed, t_fixed, t)


def icfm(robot, pose, external=None):
    """Improved closed-form method: ``(t, status, steps)`` (see the module docstring)."""
    S, W = _load(robot, pose, external)
    m = robot.num_cables
    tmin, tmax = robot.tension_min, robot.tension_max
    tm = _mid(robot)

    def body(_, carry):
        fixed, t_fixed, t, done, steps = carry
        viol = jnp.where(fixed, 0.0, jnp.maximum(tmin - t, t - tmax))
        k = jnp.argmax(viol)
        feasible = viol[k] <= _FEAS_TOL
        can_fix = jnp.sum(~fixed) > 6
        fix = ~done & ~feasible & can_fix
        fixed = fixed.at[k].set(fixed[k] | fix)
        t_fixed = t_fixed.at[k].set(jnp.where(fix, jnp.where(t[k] < tmin, tmin, tmax), t_fixed[k]))
        t = jnp.where(fix, _reduced_cfm(S, W, tm, fixed, t_fixed), t)
        return fixed, t_fixed, t, done | ~fix, steps + fix

    t0 = _reduced_cfm(S, W, tm, jnp.zeros(m, bool), jnp.zeros(m))
    init = (jnp.zeros(m, bool), jnp.zeros(m), t0, jnp.array(False), jnp.array(1))
    _, _, t, _, steps = jax.lax.fori_loop(0, m - 6, body, init)
    space = tension_space(robot, pose, external)
    return t, _space_status(space), steps


def dykstra(robot, pose, external=None, *, max_steps: int = 20000, tol: float = 1e-10):
    """Dykstra's projection onto ``{S t = -W} ∩ [t_min, t_max]^m`` from ``t_m``:
    ``(t, status, steps)``; ``tol`` (N) on the change of the iterate per sweep."""
    space = tension_space(robot, pose, external)
    tp, N = space.particular, space.null_basis
    tmin, tmax = robot.tension_min, robot.tension_max
    x0 = _mid(robot)

    def aff(z):
        return tp + N @ (N.T @ z)

    def cond(c):
        return (c[4] < max_steps) & (c[5] > tol)

    def body(c):
        x, p, q, _, k, _ = c
        y = jnp.clip(x + p, tmin, tmax)
        p = x + p - y
        xn = aff(y + q)
        q = y + q - xn
        return xn, p, q, y, k + 1, jnp.max(jnp.abs(xn - x))

    z = jnp.zeros_like(x0)
    x, _, _, y, k, change = jax.lax.while_loop(cond, body, (aff(x0), z, z, x0, jnp.array(0), jnp.array(jnp.inf)))
    gap = jnp.max(jnp.abs(x - y))
    status = Status.where(change > tol, Status.not_converged,
                          Status.where(gap <= _FEAS_TOL, Status.successful, Status.infeasible))
    return x, Status.where(space.result != Status.successful, space.result, status), k


def min_max_tension(space, tmin, tmax):
    """Tensions ``(m,)`` N minimizing ``max_i t_i`` among the balancing tensions within the
    limits, and whether any exist (``r = m - 6 <= 2``). The LP in ``z = (φ, s)``:
    ``N φ - s <= -t_p``, ``t_min - t_p <= N φ <= t_max - t_p`` is solved exactly by
    enumerating its vertices (every choice of ``r + 1`` of the ``3m`` constraints as
    equalities; ``C(24, 3) = 2024`` for 8 cables); among optimal vertices (``s`` within
    1e-9 relative of the minimum) the one closest to ``t_m`` is returned. ``tmax = inf`` is
    allowed (no upper limit).
    ``jaxopt.BoxOSQP`` (ADMM) did not converge on this LP in 5e4 steps (TCPR-8, tol 1e-6)."""
    N, tp = space.null_basis, space.particular
    m, r = N.shape
    # t_max = inf (no upper limit): a finite bound far above any tension of the problem, so the
    # vertex enumeration stays finite; it does not bind at the optimum (which minimizes max t)
    tmax = jnp.where(jnp.isfinite(tmax), tmax, 1e6 * (1.0 + jnp.max(jnp.abs(tp)) + jnp.abs(tmin)))
    if r == 0:
        ok = jnp.all(tp >= tmin - _FEAS_TOL) & jnp.all(tp <= tmax + _FEAS_TOL)
        return tp, ok
    if r > 2:
        raise ValueError(f"qp objective 'max': exact for up to 8 cables (r <= 2), got r = {r}")
    one = jnp.ones((m, 1))
    G = jnp.concatenate([jnp.concatenate([N, -one], 1), jnp.concatenate([N, 0 * one], 1),
                         jnp.concatenate([-N, 0 * one], 1)])
    h = jnp.concatenate([-tp, tmax - tp, tp - tmin])
    idx = np.array(list(itertools.combinations(range(3 * m), r + 1)))
    A, b = G[idx], h[idx]  # (C, r+1, r+1), (C, r+1)
    det = jnp.linalg.det(A)
    good = jnp.abs(det) > 1e-12
    z = jnp.linalg.solve(jnp.where(good[:, None, None], A, jnp.eye(r + 1)), b[..., None])[..., 0]
    scale = 1.0 + jnp.maximum(jnp.abs(tmax), jnp.max(jnp.abs(tp)))
    feas = good & jnp.all(z @ G.T <= h + 1e-9 * scale, axis=1)
    s = jnp.where(feas, z[:, r], jnp.inf)
    t = tp[None] + z[:, :r] @ N.T  # (C, m)
    best = feas & (s <= jnp.min(s) + 1e-9 * scale)
    dist = jnp.where(best, jnp.sum((t - 0.5 * (tmin + tmax)) ** 2, axis=1), jnp.inf)
    return t[jnp.argmin(dist)], jnp.any(feas)


def _feasible(robot, pose, external, space):
    """Whether any balancing tensions lie within the limits: exact for ``r <= 2``
    (:func:`min_max_tension`), else Dykstra's verdict (an iterate that stops with a gap)."""
    if space.null_basis.shape[1] <= 2:
        return min_max_tension(space, robot.tension_min, robot.tension_max)[1]
    _, status, _ = dykstra(robot, pose, external)
    return status != Status.infeasible


def _osqp(Q, c, A, lo, hi, tol, max_steps):
    import jaxopt  # lazily (it warns on import)

    qp = jaxopt.BoxOSQP(tol=tol, maxiter=max_steps, jit=True)
    sol = qp.run(params_obj=(Q, c), params_eq=A, params_ineq=(lo, hi))
    x = sol.params.primal[0]
    status = jnp.where(sol.state.status == jaxopt.BoxOSQP.PRIMAL_INFEASIBLE, 1,
                       jnp.where(sol.state.status == jaxopt.BoxOSQP.SOLVED, 0, 2))
    return x, status, sol.state.iter_num


def qp(robot, pose, external=None, *, objective: str = "2-norm", max_steps: int = 20000, tol: float = 1e-9):
    """QP with ``objective`` ``"2-norm"`` (``jaxopt.BoxOSQP``) or ``"max"`` (exact LP,
    :func:`min_max_tension`): ``(t, status, steps)``."""
    if objective not in OBJECTIVES:
        raise ValueError(f"qp: objective = {objective!r}; allowed: {', '.join(OBJECTIVES)}")
    space = tension_space(robot, pose, external)
    tmin, tmax = robot.tension_min, robot.tension_max
    r = space.null_basis.shape[1]
    if objective == "max" or r == 0:  # r = 0: the unique balancing tensions, whatever the objective
        t, ok = min_max_tension(space, tmin, tmax)
        status, steps = Status.where(ok, Status.successful, Status.infeasible), 1
    else:
        S, W = _load(robot, pose, external)
        m = robot.num_cables
        A = jnp.concatenate([S, jnp.eye(m)])
        lo = jnp.concatenate([-W, jnp.full(m, tmin)])
        hi = jnp.concatenate([-W, jnp.full(m, tmax)])
        t, code, steps = _osqp(jnp.eye(m), -_mid(robot), A, lo, hi, tol, max_steps)
        feasible = jax.lax.cond(code == 0, lambda: jnp.array(True), lambda: _feasible(robot, pose, external, space))
        status = Status.where(code == 0, Status.successful,
                              Status.where((code == 1) | ~feasible, Status.infeasible, Status.not_converged))
    return t, Status.where(space.result != Status.successful, space.result, status), steps


@solver_errors
@eqx.filter_jit
def distribute_tensions(robot, pose, external=None, *, method: str = "icfm", objective: str = "2-norm",
                        max_steps: int = 20000, tol: float | None = None,
                        throw: bool = True) -> TensionDistribution:
    """Tensions holding ``pose`` under ``external`` (+ the platform weight) by ``method``.

    **Arguments:**

    - ``robot``: a :class:`~cstiffjax.io.robot.CableRobot` (with fewer than 6 cables every
      method gives the least-squares tensions of :func:`~cstiffjax.stiffness.tensions.tension_space`,
      the unique balancing ones at an equilibrium pose and ``infeasible`` elsewhere; a redundant one
      needs a finite ``tension_max`` for every method but ``qp``/``"max"``,
      :func:`needs_finite_max`, else the result is ``invalid_input``); ``pose`` ``(6,)`` m /
      rad; ``external`` ``(6,)`` N / N·m about the reference point, base frame, or None.
    - ``method``: ``"cfm"``, ``"icfm"``, ``"dykstra"`` or ``"qp"`` (module docstring);
      ``objective``: ``"2-norm"`` or ``"max"`` (``"qp"`` only).
    - ``max_steps``: iterations of Dykstra / ADMM; ``tol``: Dykstra's change per sweep (N,
      default 1e-10) or the ADMM tolerance (default 1e-9).
    - ``throw``: raise when not successful (also under jit); else read ``result``.

    **Returns:** a :class:`TensionDistribution`.
    """
    if method not in METHODS:
        raise ValueError(f"distribute_tensions: method = {method!r}; allowed: {', '.join(METHODS)}")
    if objective != "2-norm" and method != "qp":
        raise ValueError(f"distribute_tensions: objective = {objective!r} needs method = 'qp'")
    pose = jnp.asarray(pose, dtype=jnp.float64)
    if robot.num_cables < 6:  # no tensions to choose: the least-squares answer, balanced only at an equilibrium
        space = tension_space(robot, pose, external)
        t, status, steps = space.particular, _space_status(space), 1
    elif method == "cfm":
        t, status, steps = cfm(robot, pose, external)
    elif method == "icfm":
        t, status, steps = icfm(robot, pose, external)
    elif method == "dykstra":
        t, status, steps = dykstra(robot, pose, external, max_steps=max_steps, tol=1e-10 if tol is None else tol)
    else:
        t, status, steps = qp(robot, pose, external, objective=objective, max_steps=max_steps,
                              tol=1e-9 if tol is None else tol)
    if needs_finite_max(robot.num_cables, method, objective):  # t_m = inf: no target (module docstring)
        status = Status.where(jnp.isfinite(robot.tension_max), status, Status.invalid_input)
    S, W = _load(robot, pose, external)
    return _checked(robot, S, W, t, status, steps, throw)
