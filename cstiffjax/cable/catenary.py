"""Elastic catenary (Irvine): one sagging, stretching cable between two points.

Seed 003 Section 2.1, eqs (1)-(10) (and eqs 23-24 for the end point). Conventions used
throughout (fixed, see :func:`catenary`):

- End ``A`` at the origin, end ``B`` at ``(span_x > 0, span_z)``; ``z`` points up
  (against gravity). ``B`` may be above or below ``A``.
- ``length`` is the *unstrained* length ``L``, ``EA`` the axial stiffness (N) and ``w``
  the weight per unit unstrained length (N/m, ``w = ρ g``).
- The cable pulls ``A`` with the force ``(H, V_A)`` and ``B`` with ``(-H, -V_B)``;
  vertical equilibrium of the cable gives ``V_A = V_B - w L``.

With ``s`` the unstrained arc length from ``A`` the tension vector is ``(H, V_A + w s)``
and (Yuan et al. 2015 eqs 9-10, written from ``A``)::

    x(s) = H s/EA + (H/w) [asinh(V(s)/H) - asinh(V_A/H)]
    z(s) = (V_A s + w s²/2)/EA + (T(s) - T_A)/w,    T = sqrt(H² + V²).

Seed 003 writes these from the far end with ``f_A`` the force at the platform; the two
are the same curve read from the other end. Evaluated at ``s = L`` they are the two
equations solved for ``(H, V_B)``. They are used here in forms that are exact
rewrites but have no cancellation and no division by ``w``:

- ``(T_B - T_A)/w = L (V_A + V_B)/(T_A + T_B)`` (difference of squares).
- ``(H/w)(asinh b - asinh a) = L g asinhc(D)`` with ``a = V_A/H``, ``b = V_B/H``,
  ``D = sinh(asinh b - asinh a) = (w L/H) g``, ``asinhc(D) = asinh(D)/D`` and
  ``g = cosh δ / cosh μ`` (``δ, μ`` the half difference and half sum of the two
  hyperbolic angles), evaluated as ``g² = (H² + T_A T_B - V_A V_B)/(H² + T_A T_B + V_A V_B)``
  with the cancelling one of the two sums rewritten by the difference of squares.

At ``w = 0`` these reduce exactly to the straight spring ``x = L (1 + T/EA) H/T``, so the
massless limit needs no special case and derivatives stay smooth through it.

The unknowns are nondimensional, ``y = [log(H/F), V_B/F]`` with ``F`` the force scale of
the start, and the residuals are the span errors divided by ``L``. The start is the
shallow elastic cable (parabolic sag + Hooke, a cubic in the chord tension) when its
sag is small and the Peyrot-Goulois (1979) inextensible estimate otherwise. The solve is
an ``optimistix`` root find (default :class:`~cstiffjax.cable.newton2.Newton2`, step-limited Newton); derivatives
(``stiffness_B`` included) come from the implicit function theorem at the solution,
``d(H, V_B) = -(∂p/∂(H, V_B))⁻¹ ∂p/∂args · d args`` (a ``jax.custom_jvp``, see
:func:`_solve_ift`; optimistix's ``ImplicitAdjoint`` computes the same thing but its
lineax solve raises on non-finite trial points, which Levenberg-Marquardt in the statics
solves produces and then rejects).

Accuracy: the end forces solve the equations to rounding; since the spans are given in
float64, the forces are determined only to about ``eps · EA / T`` relative (``eps /
strain``): ~2e-10 at strain 1e-6. Tested to 1e-9 of the largest tension over the whole
range (spans 1 m..1 km, EA 1e3..1e9 N, w 1e-4..1e3 N/m, sag/chord up to 0.3, strain to 1%).
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from cstiffjax.cable.force import CableForce
from cstiffjax.cable.path import cable_path
from cstiffjax.core import config as _config  # noqa: F401  (float64)
from cstiffjax.core.status import Status, from_codes, raise_if_failed, solver_errors, to_codes

_SERIES = 1e-3


class CatenarySolution(eqx.Module):
    """Solution of one (or a batch of) elastic catenary problems (see :func:`catenary`).

    - ``H``: horizontal tension, N (> 0).
    - ``V_A``, ``V_B``: vertical force of the cable on ``A`` (up positive) and minus the
      one on ``B``; ``V_A = V_B - w L``. N.
    - ``stiffness_B``: ``∂(H, V_B)/∂(span_x, span_z)`` (2x2, N/m): the stiffness of the
      cable at ``B`` in the plane. Symmetric positive definite.
    - ``result``: a :class:`~cstiffjax.core.status.Status`.
    - ``num_steps``: solver iterations.
    """

    H: Float[Array, "*batch"]
    V_A: Float[Array, "*batch"]
    V_B: Float[Array, "*batch"]
    stiffness_B: Float[Array, "*batch 2 2"]
    result: Status
    num_steps: Array

    @property
    def tension_A(self) -> Float[Array, "*batch"]:
        """Tension at ``A``, N."""
        return jnp.hypot(self.H, self.V_A)

    @property
    def tension_B(self) -> Float[Array, "*batch"]:
        """Tension at ``B``, N."""
        return jnp.hypot(self.H, self.V_B)


# ----------------------------------------------------------------- stable kernels
def asinhc(d):
    """``asinh(d)/d`` (1 at 0), with a series below ``|d| < 1e-3`` (smooth, exact to eps)."""
    small = jnp.abs(d) < _SERIES
    ds = jnp.where(small, 1.0, d)
    d2 = d * d
    series = 1.0 - d2 / 6.0 + 3.0 * d2 * d2 / 40.0 - 5.0 * d2 * d2 * d2 / 112.0
    return jnp.where(small, series, jnp.arcsinh(ds) / ds)


def _g_factor(h, va, vb):
    """``g = cosh δ / cosh μ`` of the module docstring, from forces (any common unit)."""
    ta, tb = jnp.hypot(h, va), jnp.hypot(h, vb)
    p, q = ta * tb, va * vb
    r = h * h * (va * va + vb * vb + h * h)
    h2 = h * h
    pos = q >= 0
    num = jnp.where(pos, h2 + r / jnp.where(pos, p + q, 1.0), h2 + p - q)
    den = jnp.where(pos, h2 + p + q, h2 + r / jnp.where(pos, 1.0, p - q))
    return jnp.sqrt(num / den)


def end_point(H, V_B, length, EA, w):
    """Position of ``B`` relative to ``A`` for end forces ``(H, V_B)`` (Yuan et al. 2015 eqs 23-24).

    **Arguments:** ``H`` (> 0), ``V_B`` N; ``length`` unstrained m; ``EA`` N; ``w`` N/m.

    **Returns:** ``(span_x, span_z)``, m. Stable for ``w → 0`` (the spring limit) and any
    sag; see the module docstring for the rewrites.
    """
    va = V_B - w * length
    g = _g_factor(H, va, V_B)
    x = length * (H / EA + g * asinhc(w * length * g / H))
    z = length * (va + V_B) * (0.5 / EA + 1.0 / (jnp.hypot(H, va) + jnp.hypot(H, V_B)))
    return x, z


def catenary_profile(H, V_A, length, EA, w, s):
    """Points ``(x(s), z(s))`` of the cable at unstrained arc lengths ``s`` from ``A``, m.

    Seed 003 eqs (9)-(10) (read from ``A``), in the stable form of :func:`end_point`
    applied to the piece ``[0, s]``. ``H``, ``V_A`` from a :class:`CatenarySolution`.
    """
    s = jnp.asarray(s, dtype=jnp.float64)
    return end_point(H, V_A + w * s, s, EA, w)


# ------------------------------------------------------------------- start guess
def _peyrot_goulois(sx, sz, L, w):
    """Peyrot & Goulois (1979) start for an inextensible catenary: ``(H, V_B)``."""
    chord = jnp.hypot(sx, sz)
    ratio = (L * L - sz * sz) / (sx * sx) - 1.0
    lam = jnp.where(L > chord, jnp.sqrt(3.0 * jnp.clip(ratio, 1e-12, 1e12)), 0.2)
    lam = jnp.clip(lam, 1e-6, 1e6)
    return w * sx / (2.0 * lam), 0.5 * w * (sz / jnp.tanh(lam) + L)


def _shallow_elastic_tension(sx, sz, L, EA, w, steps: int = 8):
    """Chord tension ``T`` of the shallow elastic cable (parabolic sag + Hooke).

    Root of ``L (1 + T/EA) - L (w L c)²/(24 T²) = chord`` (``c`` = cosine of the chord
    angle), i.e. of the cubic ``(L/EA) T³ + (L - chord) T² - L (w L c)²/24``, which has
    exactly one positive root. Newton from an upper bound on the convex branch
    decreases monotonically onto it.
    """
    chord = jnp.hypot(sx, sz)
    slack = L - chord
    k = L * (w * L * sx / chord) ** 2 / 24.0
    t_e = EA * jnp.maximum(-slack, 0.0) / L
    t_c = jnp.cbrt(k * EA / L)
    t_s = jnp.sqrt(k / jnp.where(slack > 0, slack, 1.0))
    t = jnp.where(slack > 0, jnp.minimum(t_c, t_s), t_e + t_c)
    for _ in range(steps):
        f = (L / EA) * t**3 + slack * t * t - k
        df = 3.0 * (L / EA) * t * t + 2.0 * slack * t
        t = t - f / jnp.where(df > 0, df, 1.0)
    return t


def _initial_guess(sx, sz, L, EA, w):
    """Start ``(H, V_B)``: shallow elastic cable when its sag is small, else Peyrot-Goulois."""
    chord = jnp.hypot(sx, sz)
    t = _shallow_elastic_tension(sx, sz, L, EA, w)
    h_el, v_el = t * sx / chord, t * sz / chord + 0.5 * w * L
    h_pg, v_pg = _peyrot_goulois(sx, sz, L, w)
    shallow = w * L * sx / chord < 1.0 * t
    H0 = jnp.where(shallow, h_el, h_pg)
    V0 = jnp.where(shallow, v_el, v_pg)
    # A massless slack line has no equilibrium; keep the start finite and positive.
    return jnp.maximum(H0, 1e-12 * (EA + w * L)), V0


# ------------------------------------------------------------------------ solve
def _residual(y, args):
    sx, sz, L, EA, w, F = args
    h = jnp.exp(y[0])
    x, z = end_point(h, y[1], L, EA / F, w / F)
    return jnp.stack([x - sx, z - sz]) / L


def default_solver(rtol: float = 1e-10, atol: float = 1e-10):
    """Root finder used by :func:`catenary` (pass any optimistix root finder instead): a
    :class:`~cstiffjax.cable.newton2.Newton2`.

    The tolerances are on the step in ``[log H, V_B/F]`` (relative force change); Newton
    converges quadratically, so the error after the last step is about their square.
    """
    from cstiffjax.cable.newton2 import Newton2  # optimistix: imported when a catenary is traced (module doc)

    return Newton2(rtol=rtol, atol=atol)


def _valid(sx, sz, L, EA, w):
    finite = jnp.isfinite(sx) & jnp.isfinite(sz) & jnp.isfinite(L) & jnp.isfinite(EA) & jnp.isfinite(w)
    return finite & (sx > 0) & (L > 0) & (EA > 0) & (w >= 0)


def _check_concrete(**kw):
    allowed = {"span_x": "> 0", "length": "> 0", "EA": "> 0", "w": ">= 0", "span_z": "finite"}
    for name, val in kw.items():
        try:
            a = np.asarray(val, dtype=float)
        except (TypeError, jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
            continue
        bad = ~np.isfinite(a)
        if name in ("span_x", "length", "EA"):
            bad |= ~(a > 0)
        elif name == "w":
            bad |= ~(a >= 0)
        if np.any(bad):
            v = a[bad].flat[0] if a.ndim else float(a)
            raise ValueError(f"catenary: {name} = {v!r} is not allowed; {name} must be {allowed[name]} "
                             "(and not NaN/inf)")


def _solve_one(sx, sz, L, EA, w, solver, max_steps):
    valid = _valid(sx, sz, L, EA, w)
    # Replace bad inputs by a benign case so the solve stays finite; the Status says why.
    sx_, sz_ = jnp.where(valid, sx, 1.0), jnp.where(valid, sz, 0.0)
    L_, EA_, w_ = jnp.where(valid, L, 1.0), jnp.where(valid, EA, 1.0), jnp.where(valid, w, 1.0)
    H0, V0 = jax.lax.stop_gradient(_initial_guess(sx_, sz_, L_, EA_, w_))
    F = jax.lax.stop_gradient(jnp.hypot(H0, V0))
    y0 = jnp.stack([jnp.log(H0 / F), V0 / F])
    args = (sx_, sz_, L_, EA_, w_, F)
    import optimistix as optx  # optimistix only when traced (cstiffjax.cable.newton2's module doc)

    sol = optx.root_find(_residual, solver, y0, args=args, max_steps=max_steps, throw=False)
    H, VB = F * jnp.exp(sol.value[0]), F * sol.value[1]
    err = jnp.max(jnp.abs(_residual(sol.value, args)))
    ok = (sol.result == optx.RESULTS.successful) & (err < 1e-10) & jnp.isfinite(H) & jnp.isfinite(VB)
    result = Status.where(valid, Status.where(ok, Status.successful, Status.not_converged), Status.invalid_input)
    return H, VB, result, sol.stats["num_steps"]


@functools.partial(jax.custom_jvp, nondiff_argnums=(5, 6))
def _solve_ift(sx, sz, L, EA, w, solver, max_steps):
    """``(H, V_B, status code, steps)`` with a hand-written implicit-function-theorem JVP (the
    :class:`Status` passes the ``custom_jvp`` as its integer code, :func:`~cstiffjax.core.status.to_codes`).

    Same solve as :func:`_solve_one` (default solver). Its JVP is
    ``d(H, V_B) = -(∂p/∂(H, V_B))⁻¹ (∂p/∂args · d args)`` with ``p`` = :func:`end_point`,
    the flexibility inverted by Cramer's rule. Used inside the statics solves: unlike
    optimistix's adjoint (a lineax solve that raises on non-finite input) it stays plain
    arithmetic under the transposes that Levenberg-Marquardt applies.
    """
    H, VB, result, steps = _solve_one(sx, sz, L, EA, w, solver, max_steps)
    return H, VB, to_codes(result), steps


@_solve_ift.defjvp
def _solve_ift_jvp(solver, max_steps, primals, tangents):
    sx, sz, L, EA, w = primals
    dsx, dsz, dL, dEA, dw = tangents
    H, VB, code, steps = _solve_ift(sx, sz, L, EA, w, solver, max_steps)
    J = jax.jacfwd(lambda u: jnp.stack(end_point(u[0], u[1], L, EA, w)))(jnp.stack([H, VB]))
    _, dp = jax.jvp(lambda a, b, c: jnp.stack(end_point(H, VB, a, b, c)), (L, EA, w), (dL, dEA, dw))
    rhs = jnp.stack([dsx, dsz]) - dp
    det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
    dH = (J[1, 1] * rhs[0] - J[0, 1] * rhs[1]) / det
    dV = (J[0, 0] * rhs[1] - J[1, 0] * rhs[0]) / det
    zero = np.zeros(np.shape(code), dtype=jax.dtypes.float0)
    return (H, VB, code, steps), (dH, dV, zero, np.zeros(np.shape(steps), dtype=jax.dtypes.float0))


def _forces(sx, sz, L, EA, w, solver, max_steps):
    H, VB, code, steps = _solve_ift(sx, sz, L, EA, w, solver, max_steps)
    return jnp.stack([H, VB]), (H, VB, code, steps)


def _solve_with_stiffness(sx, sz, L, EA, w, solver, max_steps):
    K, (H, VB, code, steps) = jax.jacfwd(_forces, argnums=(0, 1), has_aux=True)(sx, sz, L, EA, w, solver, max_steps)
    K = jnp.stack(K, axis=-1)
    return CatenarySolution(H, VB - w * L, VB, K, from_codes(code), steps)


@eqx.filter_jit
def _catenary_batched(sx, sz, L, EA, w, solver, max_steps):
    shape = jnp.broadcast_shapes(sx.shape, sz.shape, L.shape, EA.shape, w.shape)
    flat = [jnp.broadcast_to(a, shape).reshape(-1) for a in (sx, sz, L, EA, w)]
    sol = jax.vmap(lambda *a: _solve_with_stiffness(*a, solver, max_steps))(*flat)
    return jax.tree.map(lambda a: a.reshape(*shape, *a.shape[1:]), sol)


@solver_errors
def catenary(
    span_x: ArrayLike, span_z: ArrayLike, length: ArrayLike, EA: ArrayLike, w: ArrayLike,
    *, solver=None, max_steps: int = 64, throw: bool = True,
) -> CatenarySolution:
    """Solve the elastic catenary for the end forces (Yuan et al. 2015 eqs 23-24, Irvine).

    **Arguments** (broadcast against each other; any batch shape):

    - ``span_x``: horizontal distance from ``A`` to ``B``, m (> 0).
    - ``span_z``: height of ``B`` above ``A``, m (negative: ``B`` below ``A``).
    - ``length``: unstrained length, m (> 0). ``EA``: axial stiffness, N (> 0).
    - ``w``: weight per unstrained length, N/m (>= 0; ``0`` is the massless spring, which
      needs a taut line: a slack massless line has no equilibrium and is ``not_converged``).
    - ``solver``: an ``optx`` root finder (default :func:`default_solver`); ``max_steps``.
    - ``throw``: raise (also under ``jit``) unless every case succeeded.

    **Returns:** a :class:`CatenarySolution` with the batch shape. Bad inputs raise
    ``ValueError`` naming the argument when they are concrete; under ``jit`` they give
    ``Status.invalid_input``. Non-convergence is ``Status.not_converged`` (never another
    model). Differentiable in every argument (implicit function theorem).
    """
    _check_concrete(span_x=span_x, span_z=span_z, length=length, EA=EA, w=w)
    args = [jnp.asarray(a, dtype=jnp.float64) for a in (span_x, span_z, length, EA, w)]
    sol = _catenary_batched(*args, solver or default_solver(), max_steps)
    return raise_if_failed(sol.result, sol, throw)


def stiffness_B_closed_form(H, V_B, length, EA, w):
    """Irvine's flexibility matrix ``∂(span_x, span_z)/∂(H, V_B)`` inverted (2x2, N/m).

    Classic closed form (needs ``w > 0``), used in the tests to check the autodiff
    ``stiffness_B``::

        ∂x/∂H = L/EA + (asinh(V_B/H) - asinh(V_A/H))/w - (V_B/T_B - V_A/T_A)/w
        ∂x/∂V = ∂z/∂H = (H/w)(1/T_B - 1/T_A)
        ∂z/∂V = L/EA + (V_B/T_B - V_A/T_A)/w
    """
    VA = V_B - w * length
    TA, TB = jnp.hypot(H, VA), jnp.hypot(H, V_B)
    fxh = length / EA + (jnp.arcsinh(V_B / H) - jnp.arcsinh(VA / H)) / w - (V_B / TB - VA / TA) / w
    fxv = (H / w) * (1.0 / TB - 1.0 / TA)
    fzv = length / EA + (V_B / TB - VA / TA) / w
    flex = jnp.stack([jnp.stack([fxh, fxv], -1), jnp.stack([fxv, fzv], -1)], -2)
    return jnp.linalg.inv(flex)


# ------------------------------------------------------------------------- 3-D
def frame_3d(anchor, attachment, gravity):
    """The vertical plane of a cable: its spans and unit axes.

    **Arguments:**

    - `anchor`, `attachment`: the cable's ends, `(3,)` (m).
    - `gravity`: the gravity vector, `(3,)` (m/s²).

    **Returns:** `(sx, sz, ex, up, g)`: the horizontal span `sx >= 0` and the signed vertical
    span `sz` from anchor to attachment (m), the horizontal unit vector `ex` towards the
    attachment (the zero vector when `sx` is 0), the unit vector `up` against
    gravity and the gravity magnitude `g` (m/s²).
    """
    g = jnp.linalg.norm(gravity)
    up = -gravity / g
    d = attachment - anchor
    sz = jnp.dot(d, up)
    hvec = d - sz * up
    sx2 = jnp.sum(hvec * hvec)
    sx = jnp.sqrt(jnp.where(sx2 > 0, sx2, 1.0))
    ex = hvec / sx
    return jnp.where(sx2 > 0, sx, 0.0), sz, ex, up, g


def free_span(anchor, attachment, l0, EA, radius=0.0, axis=(0.0, 0.0, 0.0)):
    """Start point and unstrained length of a cable's free span, ``(T (3,), l0_free)``.

    Without a pulley: ``(anchor, l0)`` exactly. Over a swivel pulley
    (:func:`cstiffjax.cable.path.cable_path`): the tangent point T and
    ``l0_free = l0 - r beta / (1 + eps)``, the wrapped arc ``r beta`` being strained by
    ``eps``, estimated as the spring strain of the whole path ``max(l - l0, 0) / l0`` (exact
    for a massless cable, so the catenary tends to the spring law on the whole path as
    ``w -> 0``; with sag the error is ``r beta`` times the strain error, second order).
    T is where the chord to P is tangent to the pulley (the catenary's own end slope moves
    it along the pulley by ``r`` times the sag angle, which changes the length only to
    second order).
    """
    path = cable_path(anchor, attachment, radius, jnp.asarray(axis, dtype=jnp.float64))
    eps = jnp.maximum(path.length - l0, 0.0) / l0
    return path.tangent_point, l0 - radius * path.wrap / (1.0 + eps)


def catenary_force(anchor, attachment, l0, EA, mass_per_length, gravity, radius=0.0,
                   axis=(0.0, 0.0, 0.0)) -> CableForce:
    """Elastic catenary between an anchor (exit point) and a platform attachment, 3-D.

    The cable hangs in the vertical plane through both ends ("down" is the direction of
    ``gravity``). ``A`` is the anchor and ``B`` the attachment in :func:`catenary`'s
    conventions, so ``tension_anchor = hypot(H, V_A)`` is the exit-point tension.

    **Arguments:** ``anchor``, ``attachment`` (3,) base frame, m; ``l0`` unstrained length,
    m; ``EA`` N; ``mass_per_length`` kg/m; ``gravity`` (3,) m/s² (nonzero); ``radius`` m
    and ``axis`` (3,): swivel pulley at the anchor (default none). With a pulley the
    catenary hangs from the tangent point T with the free span's unstrained length
    (:func:`free_span`); its vertical plane through T and P is the pulley plane when the
    swivel axis is vertical, and ``on_anchor`` is the force at T.

    **Returns:** :class:`~cstiffjax.cable.laws.CableForce`. A massless cable (``ρ = 0``) that is
    not stretched (chord ≤ ``l0``) carries no force (the ``w → 0`` limit of the catenary)
    and is reported ``slack``. A cable whose ends are vertically aligned (horizontal span
    below ``1e-9`` of the chord) is solved at that minimal horizontal span (a vertical
    cable is the limit of the plane solution; the error is of the same relative size).
    Non-convergence gives non-finite forces, which the statics solvers report as
    ``not_converged``.
    """
    anchor, l0 = free_span(anchor, attachment, l0, EA, radius, axis)
    sx, sz, ex, up, g = frame_3d(anchor, attachment, gravity)
    w = mass_per_length * g
    chord = jnp.hypot(sx, sz)
    sx = jnp.maximum(sx, 1e-9 * chord)
    massless_slack = (w <= 0) & (chord <= l0)
    # keep the massless slack case solvable (its answer is discarded below)
    l0_ = jnp.where(massless_slack, 0.5 * chord, l0)
    H, VB, code, _ = _solve_ift(sx, sz, l0_, EA, w, default_solver(), 64)
    bad = code != to_codes(Status.successful)
    H = jnp.where(massless_slack, 0.0, jnp.where(bad, jnp.nan, H))
    VB = jnp.where(massless_slack, 0.0, jnp.where(bad, jnp.nan, VB))
    VA = jnp.where(massless_slack, 0.0, VB - w * l0)
    on_anchor = H * ex + VA * up
    on_platform = -H * ex - VB * up
    return CableForce(on_platform, on_anchor, jnp.hypot(H, VA), jnp.hypot(H, VB), massless_slack)


def catenary_stiffness_3d(anchor, attachment, l0, EA, mass_per_length, gravity) -> Float[Array, "3 3"]:
    """3x3 tangent stiffness of one catenary cable at the attachment, N/m (autodiff).

    ``K = -∂(force on platform)/∂(attachment position)``: symmetric positive
    semi-definite (the cable is conservative). Same arguments as :func:`catenary_force`.
    """
    def f(p):
        return catenary_force(anchor, p, l0, EA, mass_per_length, gravity).on_platform

    return -jax.jacfwd(f)(jnp.asarray(attachment, dtype=jnp.float64))
