"""Tension distribution of redundant CDPRs: null space, CTFR polygon, feasible tensions.

Seed 004 (``004_b946b1caf1c3d79b.txt``, Cui et al. 2019) eqs (20)-(21): with ``S`` of full
rank 6, every tension vector balancing the load is

    T = t_p + N φ,   t_p = S⁺(-W) (minimum norm),   N = null(S) (m x r, orthonormal),

and the cable tension feasible region (CTFR) is ``{φ : t_min - t_p <= N φ <= t_max - t_p}``,
an intersection of ``2m`` half-planes when the degree of redundancy ``r = m - 6`` is 2.

Everything is written for one pose with fixed-size arrays, so it jits and vmaps:

- :func:`tension_space` -- ``t_p``, ``N`` and a :class:`~cstiffjax.core.status.Status`
  (``singular`` when ``S`` is rank deficient).
- :func:`ctfr` (``r = 2``) -- the CTFR as an exact convex polygon, built by clipping a box
  that strictly contains it with the ``2m`` half-planes of eq. (21) (Sutherland-Hodgman
  on a convex polygon; exact up to rounding). The polygon has at most ``2m`` vertices
  (each cable adds two parallel lines) and is stored in ``2m + 4`` slots with a mask.
  Its area (N², intrinsic because ``N`` is orthonormal) and centroid are closed-form
  (shoelace); the tensions at the centroid are Cui et al.'s Table 3 choice.
- :func:`feasible_tensions` -- any redundancy: ``r = 0`` the unique solution, ``r = 1``
  the midpoint of the feasible interval (exact), ``r = 2`` the CTFR centroid (exact),
  ``r >= 3`` the tensions closest to the midpoint of the limits, a small convex QP
  solved with ``jaxopt.BoxOSQP`` (ADMM; exact methods do not scale with ``r`` and this QP
  has a unique solution; the answer is re-checked against the limits and the wrench
  balance so an inaccurate ADMM exit shows as a status, never as a wrong "feasible").
- :func:`local_stability` -- Cui et al. 2019 eq. (25a) with the midpoint of the limits (see there).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from cstiffjax.core.status import Status, raise_if_failed, solver_errors
from cstiffjax.statics.geometry import (
    external_wrench,
    geometry_status,
    gravity_wrench,
    structure_matrix_closed_form,
)
from cstiffjax.stiffness import kernel as css_kernel


class TensionSpace(eqx.Module):
    """All balancing tensions ``T = particular + null_basis @ φ`` (Cui et al. 2019 eq. 20).

    ``particular`` (m,) N; ``null_basis`` (m, r) orthonormal; ``result``: ``singular`` when
    ``S`` has rank < 6 (then ``particular`` is the least-squares solution).
    """

    particular: Float[Array, " m"]
    null_basis: Float[Array, "m r"]
    result: Status


@eqx.filter_jit
def tension_space(robot, pose, external=None) -> TensionSpace:
    """Minimum-norm solution and orthonormal null-space basis of ``S T = -W``.

    With fewer than 6 cables there is no null space (``null_basis`` is ``(m, 0)``): ``particular``
    is the least-squares answer of ``S T = -W`` (the unique balancing tensions where the pose
    is an equilibrium; whether it is, is the callers' check of ``S T + W``), ``singular``
    when ``S`` has fewer than ``m`` independent columns (``min σ <= 1e-9 max σ``).

    **Arguments:** ``robot`` (any number of cables), ``pose`` ``[x, y, z, rx, ry, rz]`` (m, rad),
    ``external`` wrench ``[f, m]`` (N, N·m) or None (the platform weight is always added).

    **Returns:** a :class:`TensionSpace`. Computed by an unrolled Householder QR of ``Sᵀ``
    (6 reflections; under ``vmap`` this is ~3x faster on CPU than a batched LAPACK SVD):
    ``Sᵀ = Q R``, ``N = Q[:, 6:]``, ``t_p = Q[:, :6] R⁻ᵀ (-W)``. ``S`` is reported
    ``singular`` when ``min |R_kk| <= 1e-9 max |R_kk|`` (``det R = Π R_kk``). ``N`` is
    rotated to a canonical basis: ``n1`` is the projection of ``(1, ..., 1)`` (a uniform
    pretension) onto the null space, ``n2`` completes it with ``Σ n2_i³ >= 0``; both are
    invariant under relabelling the cables, so choices made in φ coordinates (the CSS
    tensions) respect the robot's symmetries (r <= 2; the SVD-like basis when ``(1, ..., 1)``
    is orthogonal to the null space). Shared with the pose-minor CSS kernel
    (:func:`cstiffjax.stiffness.kernel.null_space`).
    """
    pose = jnp.asarray(pose, dtype=jnp.float64)
    if robot.num_cables < 6:
        return _least_squares_space(robot, pose, external)
    R, r, u, _ = css_kernel.geometry(robot, pose, 0)
    tp, N, singular = css_kernel.null_space(css_kernel.structure_rows(r, u),
                                            css_kernel.load_wrench(robot, R, external, 0))
    result = Status.where(singular, Status.singular, Status.successful)
    inputs = geometry_status(robot, pose, external)  # a NaN pose is invalid input, not a rank-deficient S
    return TensionSpace(tp, N, Status.where(inputs == Status.successful, result, inputs))


def _least_squares_space(robot, pose, external) -> TensionSpace:
    """:func:`tension_space` of a robot with fewer than 6 cables (see there)."""
    S = structure_matrix_closed_form(robot, pose)
    w = gravity_wrench(robot, pose) + external_wrench(external)
    sv = jnp.linalg.svd(S, compute_uv=False)
    singular = ~(sv[-1] > 1e-9 * sv[0])
    tp = -jnp.linalg.pinv(S) @ w
    result = Status.where(singular, Status.singular, Status.successful)
    inputs = geometry_status(robot, pose, external)
    return TensionSpace(tp, jnp.zeros((S.shape[1], 0)), Status.where(inputs == Status.successful, result, inputs))


def tension_midpoint(robot) -> Float[Array, ""]:
    """``t̄ = (t_max + t_min)/2``, the midpoint of the tension limits, N.

    Seed 004 (below eq. 25b) writes ``t̄ = (t_max - t_min)/2`` and calls it "the median of
    the cable tension limiting values". That is the half-range, not the median/midpoint:
    with it, a tension at ``t̄`` is *not* the one farthest from both limits, and
    ``μ <= 1`` (claimed right after eq. 25b) fails near ``t_max`` (``|400 - 195|/195 >
    1``). The midpoint makes ``μ = 0`` exactly at equal distance from both limits and
    ``μ <= (t_max - t_min)/(t_max + t_min) < 1`` for feasible tensions, as the paper says.
    """
    return 0.5 * (robot.tension_max + robot.tension_min)


def local_stability(robot, tensions: Float[Array, " m"]) -> Float[Array, ""]:
    """Local stability factor ``μ = (1/m) Σ |t_k - t̄| / t̄`` (Cui et al. 2019 eq. 25a), dimensionless.

    ``t̄`` is the midpoint of the limits (:func:`tension_midpoint`; the paper's
    ``(t_max - t_min)/2`` is a typo). Smaller is farther from the limits (more stable).
    """
    tbar = tension_midpoint(robot)
    return jnp.mean(jnp.abs(tensions - tbar)) / tbar


# ------------------------------------------------------------------------ polygons
class Polygon(eqx.Module):
    """Convex polygon in fixed-size storage: valid vertices in ``vertices[:n]``
    (counter-clockwise), ``mask[k]`` true for ``k < n``; the rest is padding."""

    vertices: Float[Array, "V 2"]
    mask: Bool[Array, " V"]

    @property
    def count(self):
        return jnp.sum(self.mask)


def box_polygon(half_width, slots: int) -> Polygon:
    """The square ``[-h, h]²`` stored in ``slots`` (>= 4) slots."""
    h = half_width
    v = jnp.zeros((slots, 2)).at[:4].set(jnp.array([[-h, -h], [h, -h], [h, h], [-h, h]]))
    return Polygon(v, jnp.arange(slots) < 4)


def clip_polygon(poly: Polygon, a: Float[Array, "2"], b) -> Polygon:
    """Intersection of a convex polygon with the half-plane ``a·φ <= b`` (same storage).

    One Sutherland-Hodgman step: each edge emits its start vertex if inside (``<= 0``) and
    the crossing point if its ends lie strictly on opposite sides; the emitted points are
    compacted in order (a vertex on the line is kept once, not duplicated).
    A convex polygon gains at most one vertex per clip; the caller provides enough slots
    (points beyond the last slot would be dropped, so size ``slots >= 4 + #clips``).
    """
    V = poly.vertices.shape[0]
    n = poly.count
    v = poly.vertices
    nxt = jnp.where(jnp.arange(V) + 1 < n, jnp.arange(V) + 1, 0)
    w = v[nxt]
    s0 = v @ a - b
    s1 = w @ a - b
    inside = (s0 <= 0) & poly.mask
    cross = (((s0 < 0) & (s1 > 0)) | ((s0 > 0) & (s1 < 0))) & poly.mask  # strict: no duplicates
    lam = s0 / jnp.where(cross, s0 - s1, 1.0)
    x = v + lam[:, None] * (w - v)
    pts = jnp.stack([v, x], axis=1).reshape(2 * V, 2)
    keep = jnp.stack([inside, cross], axis=1).reshape(2 * V)
    pos = jnp.where(keep, jnp.cumsum(keep) - 1, 2 * V)
    out = jnp.zeros((V, 2)).at[pos].set(pts, mode="drop")
    return Polygon(out, jnp.arange(V) < jnp.sum(keep))


def polygon_area_centroid(poly: Polygon):
    """Area (>= 0 for counter-clockwise order) and centroid of a polygon (shoelace)."""
    V = poly.vertices.shape[0]
    n = poly.count
    v = jnp.where(poly.mask[:, None], poly.vertices, 0.0)
    w = v[jnp.where(jnp.arange(V) + 1 < n, jnp.arange(V) + 1, 0)]
    cr = jnp.where(poly.mask, v[:, 0] * w[:, 1] - w[:, 0] * v[:, 1], 0.0)
    area = 0.5 * jnp.sum(cr)
    safe = jnp.where(area > 0, area, 1.0)
    c = jnp.sum((v + w) * cr[:, None], axis=0) / (6.0 * safe)
    return area, jnp.where(area > 0, c, jnp.mean(v, axis=0))


# --------------------------------------------------------------------------- CTFR
class CTFR(eqx.Module):
    """Cable tension feasible region of a 2-DOR robot at one pose (Cui et al. 2019 eq. 21, Fig. 4).

    ``polygon`` in φ coordinates (N); ``area`` N²; ``centroid`` φ (2,) N; ``tensions`` (m,) N
    at the centroid (Table 3); ``space`` the :class:`TensionSpace`; ``result``:
    ``successful``, ``singular`` or ``infeasible`` (empty or zero-area region).
    """

    polygon: Polygon
    area: Float[Array, ""]
    centroid: Float[Array, "2"]
    tensions: Float[Array, " m"]
    space: TensionSpace
    result: Status


def tension_halfplanes(space: TensionSpace, tmin, tmax):
    """The ``2m`` half-planes ``A φ <= b`` of eq. (21): ``N φ <= t_max - t_p`` and
    ``-N φ <= t_p - t_min``."""
    N, tp = space.null_basis, space.particular
    return jnp.concatenate([N, -N]), jnp.concatenate([tmax - tp, tp - tmin])


def ctfr_from_space(space: TensionSpace, tmin, tmax) -> CTFR:
    """CTFR polygon, area and centroid from a :class:`TensionSpace` with ``r = 2``."""
    m, r = space.null_basis.shape
    if r != 2:
        raise ValueError(f"ctfr: the CTFR polygon needs 2 degrees of redundancy (m = 8), got r = {r} (m = {m})")
    A, b = tension_halfplanes(space, tmin, tmax)
    # |φ| = |N φ| <= |T - t_p| <= sqrt(m) max|t - t_p| over the box: a square of twice that
    # half-width strictly contains the CTFR, so none of its edges survives the clipping.
    big = jnp.max(jnp.maximum(jnp.abs(tmax - space.particular), jnp.abs(tmin - space.particular)))
    poly0 = box_polygon(2.0 * jnp.sqrt(m) * big + 1.0, 2 * m + 4)
    poly = jax.lax.fori_loop(0, 2 * m, lambda k, p: clip_polygon(p, A[k], b[k]), poly0)
    area, c = polygon_area_centroid(poly)
    scale = jnp.maximum(big, 1.0) ** 2
    ok = (poly.count >= 3) & (area > 1e-12 * scale)
    result = Status.where(space.result != Status.successful, space.result,
                          Status.where(ok, Status.successful, Status.infeasible))
    c = jnp.where(result == Status.successful, c, 0.0)
    return CTFR(poly, area, c, space.particular + space.null_basis @ c, space, result)


@solver_errors
@eqx.filter_jit
def ctfr(robot, pose, external=None, *, throw: bool = True) -> CTFR:
    """CTFR of a 2-DOR robot (m = 8) at ``pose`` under ``external`` (+ weight).

    **Arguments:** ``robot`` with ``tension_min``/``tension_max`` (N), ``pose`` (m, rad),
    ``external`` ``[f, m]`` (N, N·m) or None; ``throw``: raise when not successful.

    **Returns:** a :class:`CTFR`; ``tensions`` are those at the centroid (Cui et al. 2019 Table 3).
    """
    space = tension_space(robot, pose, external)
    out = ctfr_from_space(space, robot.tension_min, robot.tension_max)
    return raise_if_failed(out.result, out, throw)


# -------------------------------------------------------------- feasible tensions
class FeasibleTensions(eqx.Module):
    """Chosen tensions (m,) N, the wrench residual ``S T + W`` (6,), ``μ`` (eq. 25a) and
    a :class:`Status` (``infeasible`` when no tensions within the limits hold the pose)."""

    tensions: Float[Array, " m"]
    residual: Float[Array, "6"]
    stability: Float[Array, ""]
    result: Status


def _interval_midpoint(space, tmin, tmax):
    n = space.null_basis[:, 0]
    lo_b, hi_b = tmin - space.particular, tmax - space.particular
    safe = jnp.where(n == 0, 1.0, n)
    lower = jnp.where(n > 0, lo_b / safe, jnp.where(n < 0, hi_b / safe, -jnp.inf))
    upper = jnp.where(n > 0, hi_b / safe, jnp.where(n < 0, lo_b / safe, jnp.inf))
    fixed_ok = jnp.all(jnp.where(n == 0, (lo_b <= 0) & (hi_b >= 0), True))
    L, U = jnp.max(lower), jnp.min(upper)
    ok = fixed_ok & (L <= U)
    phi = jnp.where(ok, 0.5 * (L + U), 0.0)
    return space.particular + n * phi, ok


def _qp_closest_to_midpoint(robot, pose, external, tol, maxiter):
    S = structure_matrix_closed_form(robot, pose)
    w = gravity_wrench(robot, pose) + external_wrench(external)
    m = S.shape[1]
    tbar = tension_midpoint(robot)
    A = jnp.concatenate([S, jnp.eye(m)])
    lo = jnp.concatenate([-w, jnp.full(m, robot.tension_min)])
    hi = jnp.concatenate([-w, jnp.full(m, robot.tension_max)])
    import jaxopt  # lazily: only r >= 3 needs it (and it warns on import)

    qp = jaxopt.BoxOSQP(tol=tol, maxiter=maxiter, jit=True)
    sol = qp.run(params_obj=(jnp.eye(m), -tbar * jnp.ones(m)), params_eq=A, params_ineq=(lo, hi))
    return sol.params.primal[0]


@solver_errors
@eqx.filter_jit
def feasible_tensions(robot, pose, external=None, *, qp_tol: float = 1e-8, qp_maxiter: int = 20000,
                      throw: bool = True) -> FeasibleTensions:
    """Tensions within ``[tension_min, tension_max]`` that hold ``pose`` under ``external``.

    The choice depends on the degree of redundancy ``r = m - 6``: ``r = 0`` the unique
    solution (fewer than 6 cables: the least-squares one, which balances only at an
    equilibrium pose: elsewhere the check below makes it ``infeasible``); ``r = 1`` the
    midpoint of the feasible segment; ``r = 2`` the centroid of the CTFR (Cui et al. 2019 Table 3);
    ``r >= 3`` the tensions closest (Euclidean) to the midpoint of the limits (QP,
    ``jaxopt.BoxOSQP`` with ``qp_tol``/``qp_maxiter``). In every case the answer is
    checked: within the limits (to 1e-6 N) and balanced (``|S T + W| <= 1e-6 (|W| + 1)``),
    else ``infeasible``; ``singular`` when ``S`` is rank deficient.

    **Returns:** :class:`FeasibleTensions`; raises when ``throw`` and not successful.
    """
    space = tension_space(robot, pose, external)
    r = space.null_basis.shape[1]
    tmin, tmax = robot.tension_min, robot.tension_max
    if r == 0:  # also fewer than 6 cables (no null space)
        t = space.particular
    elif r == 1:
        t, _ = _interval_midpoint(space, tmin, tmax)
    elif r == 2:
        t = ctfr_from_space(space, tmin, tmax).tensions
    else:
        t = _qp_closest_to_midpoint(robot, pose, external, qp_tol, qp_maxiter)
    S = structure_matrix_closed_form(robot, pose)
    w = gravity_wrench(robot, pose) + external_wrench(external)
    res = S @ t + w
    ok = (jnp.all(t >= tmin - 1e-6) & jnp.all(t <= tmax + 1e-6)
          & (jnp.linalg.norm(res) <= 1e-6 * (jnp.linalg.norm(w) + 1.0)))
    result = Status.where(space.result != Status.successful, space.result,
                          Status.where(ok, Status.successful, Status.infeasible))
    t = jnp.where(jnp.all(jnp.isfinite(t)), t, space.particular)
    out = FeasibleTensions(t, res, local_stability(robot, t), result)
    return raise_if_failed(result, out, throw)
