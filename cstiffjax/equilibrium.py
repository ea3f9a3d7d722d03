"""Forward statics (seed 003 "direct kinematics"): the one equilibrium solver of cstiffjax.

The platform hangs on cables of unstrained lengths ``l0`` under its weight and an external
wrench; :func:`forward_statics` finds where it settles, for every cable law:

- ``"spring"`` (one-sided: slack cables carry nothing), ``"bilateral"`` (a spring that
  also pushes when ``l < l0``: smooth, for fits whose intermediate models must not stall
  at the slack kink; the same equilibrium while every cable is taut): the unknown is the
  base-frame twist ``δx`` (6) from the start pose; the residual is the net wrench
  (seed 004 eq. 3) divided by ``|weight| + |external| + 1``.
- ``"catenary"``: the twist and every cable's end forces ``(H, V_B)`` at the attachment
  are solved together (``6 + 2m`` unknowns), with the span equations in closed form
  (:func:`cstiffjax.catenary.end_point`, seed 003 eqs 23-24, residuals divided by
  ``l0``): no root find is nested in another.
- ``"small_sag"``: the bilateral spring with the cables' weight (``mass_per_length``) to
  small sag (Irvine, *Cable Structures* §3.2): every spring tension is its free span's
  mean tension, lowered by the sag's shortening of the chord (:func:`_sag_tension`); the
  platform carries half of each span's weight at the attachment; the load cell reads the
  tension grown along the chord. Within 0.2 % of the elastic catenary's change of the pose
  and 1.3 % of its change of the tensions at 0.25 kg/m on the bundled robots
  (``tests/test_small_sag.py``), at a spring law's cost: the diagnosis screens
  ``cable_mass`` with it (:class:`fitting.effects.CableMassScreen`). Without cable weight it
  is the bilateral law (every added term is 0; equal to rounding); with weight, a cable the
  bilateral law would compress carries a small positive tension instead (a sagging cable
  cannot push, as on the catenary).
- ``"ideal"``: inextensible cables: the pose matching the lengths
  (:func:`forward_kinematics`), tensions by :func:`cstiffjax.statics.inverse_statics`.

Every law reads the cable paths from :func:`cstiffjax.statics.cable_geometry` only.

Two starts, one function (``start``):

- ``"cold"`` (default): from any start pose (default the ideal-cable pose of ``l0``):
  Levenberg-Marquardt (a small dense one, :func:`_dense_lm`; or an optimistix solver
  passed as ``solver``) on the bilateral spring law first (nearly linear), then
  on the requested law from there. For the catenary, the joint solve starts from the
  spring equilibrium with the straight cables' end forces.
- ``"warm"``: at most ``steps`` clipped Newton steps (fewer once a step is below
  :data:`NEWTON_STOP`) from a start that is already close (the
  measured pose, or the solution at a nearby parameter point, with its catenary end
  forces ``forces0``): a few ms per 100 samples, what fits and samplers need by the
  thousand.

Both end with one Newton step taken *with* gradients at the converged point (all earlier
iterations run under ``stop_gradient``): its derivative is exactly the implicit-function
derivative ``-J⁻¹ ∂F/∂θ`` with respect to every argument (robot leaves, ``l0``,
``external``, the parameters of a ``tension`` hook); the start has no derivative. The
solve alone is :func:`solve_unknowns`; ``forward_statics(..., solved=...)`` then takes only
that last step (many derivative passes at one point share one solve).

Why the cold catenary start is done this way: see :func:`forward_statics` (Notes).
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from . import lie
from .catenary import end_point
from .statics import _lengths_at, apply_twist, cable_geometry, inverse_statics, moved_frame, platform_wrench
from .status import Status, raise_if_failed

LAWS = ("ideal", "spring", "bilateral", "small_sag", "catenary")
SPRING_LAWS = ("spring", "bilateral", "small_sag")  # the laws whose unknown is the twist alone
NEWTON_STEPS = 12  # most Newton steps of a warm start per stage (it stops earlier once converged)
NEWTON_STOP = 1e-10  # a warm Newton step this small (m, rad; end forces / wrench scale) ends the iteration
CHORD_STEP = 1e-6  # values only (derivatives=False): after a step this small, one residual evaluation may end it
TOL = {"cold": 1e-9, "warm": 1e-7}  # largest scaled residual (wrench / (|weight| + |external| + 1), span / l0)


class ForwardStatics(eqx.Module):
    """Equilibrium of the platform on its cables (one sample; vmap for a batch).

    ``pose`` (6,) m/rad; ``tensions`` (m,) N at the exit points (where load cells
    measure, formats.md §2); ``tensions_attachment`` (m,) N at the platform; ``slack``
    (m,) true for cables carrying no tension; ``forces`` (2, m) every cable's horizontal
    and vertical force ``(H, V_B)`` at the attachment, N (a ``forces0`` warm start);
    ``residual`` (6,) net wrench at the solution, N / N·m; ``result`` a :class:`Status`;
    ``num_steps`` solver iterations (warm start: the Newton steps taken, all stages).
    """

    pose: Float[Array, "6"]
    tensions: Float[Array, " m"]
    tensions_attachment: Float[Array, " m"]
    slack: Bool[Array, " m"]
    forces: Float[Array, "2 m"]
    residual: Float[Array, "6"]
    result: Status
    num_steps: Array


def default_solver(rtol: float = 1e-10, atol: float = 1e-10):
    """optimistix's Levenberg-Marquardt, for ``forward_statics(..., solver=default_solver())``
    in place of the built-in dense one (:func:`_dense_lm`; any ``optx`` least-squares
    solver can be passed)."""
    return optx.LevenbergMarquardt(rtol=rtol, atol=atol)


def wrench_scale(robot, external) -> Float[Array, ""]:
    """``|weight| + |external| + 1`` (N): the scale of the wrench residuals."""
    ext = jnp.zeros(6) if external is None else jnp.asarray(external, dtype=jnp.float64)
    return jnp.linalg.norm(robot.weight) + jnp.linalg.norm(ext) + 1.0


def _frozen(tree):
    """``tree`` with every array leaf behind ``stop_gradient`` (other leaves untouched)."""
    return jax.tree.map(lambda x: jax.lax.stop_gradient(x) if eqx.is_array(x) else x, tree)


# ------------------------------------------------------------------ residuals
def _spring_tensions(law, geom, l0, robot, tension):
    t = robot.EA * (geom.length - l0) / l0
    t = _sag_tension(robot, geom, l0, t) if law == "small_sag" else t
    t = t if tension is None else tension(t)
    return jnp.where(t > 0, t, 0.0) if law == "spring" else t


def _spring_residual(law, z, args):
    robot, l0, ext, tension, pose0, scale = args
    p, R = moved_frame(pose0, z)
    g = cable_geometry(robot, p, R)
    return platform_wrench(robot, R, g.offset, _cable_forces(law, robot, g, l0, tension), ext) / scale


def _cable_forces(law, robot, g, l0, tension):
    """Every cable's force on the platform (m, 3), N, under a spring law (``"small_sag"``:
    the mean tensions along the chords, :func:`_sag_tension`, and half of every free span's
    weight)."""
    force = _spring_tensions(law, g, l0, robot, tension)[:, None] * g.direction
    if law == "small_sag":
        force = force - _half_span_weight(robot, g, l0)[:, None] * _up(robot)
    return force


def _up(robot):
    """Unit vector against gravity (base frame)."""
    return -robot.gravity / jnp.linalg.norm(robot.gravity)


def _weight_per_length(robot):
    """Cable weight per unstrained length (m,), N/m."""
    return robot.mass_per_length * jnp.linalg.norm(robot.gravity)


def _half_span_weight(robot, g, l0):
    """Half the weight of each cable's free span (N): what the platform carries of it to
    first order in the mass per length (the ``"small_sag"`` law)."""
    return 0.5 * _weight_per_length(robot) * _free_span_l0(g, l0)


SAG_NEWTON = 3  # Newton steps without gradients after the start of _sag_root (then one with)


def _sag_tension(robot, g, l0, t_lin):
    """Mean tension ``T`` (m,) N of sagging free spans (Irvine's small-sag theory, *Cable
    Structures* §3.2): the sag shortens the chord by ``(w l_x)² L / (24 T²)`` (``w`` weight
    per length, ``l_x`` the chord's horizontal span, ``L`` the free span's unstrained
    length), so the spring's ``t_lin = EA (l - l0)/l0`` becomes the positive root ``T`` of
    ``T² (T - t_lin) = c = EA (w l_x)² L / (24 l0)`` (:func:`_sag_root`)."""
    up, w = _up(robot), _weight_per_length(robot)
    horizontal = g.vector - (g.vector @ up)[:, None] * up
    c = robot.EA * w * w * jnp.sum(horizontal * horizontal, axis=-1) * _free_span_l0(g, l0) / (24.0 * l0)
    return _sag_root(t_lin, c)


def _sag_root(a, c):
    """The positive root ``T`` of ``T² (T - a) = c`` for ``c > 0`` (one exists, and only one),
    ``a`` itself where ``c = 0``; elementwise. In closed form for ``a ≥ 0`` (Cardano with
    Vieta's substitution: no cancellation), else Newton from the upper bound
    ``min(c^(1/3), (c/|a|)^(1/2))`` (the cubic is convex there); then
    :data:`SAG_NEWTON` Newton steps, and a last one taken with gradients (its derivative
    is the implicit one, ``dT = (T² da + dc) / (T (3T - 2a))``)."""
    sag = c > 0
    cs, a_s = jnp.where(sag, c, 1.0), jnp.where(sag, a, 1.0)

    def step(T):
        return T - (T * T * (T - a_s) - cs) / (T * (3.0 * T - 2.0 * a_s))

    ap = jnp.maximum(a_s, 0.0)
    u = jnp.cbrt(ap**3 / 27.0 + cs / 2.0 + jnp.sqrt(cs * ap**3 / 27.0 + cs * cs / 4.0))
    below = jnp.minimum(jnp.cbrt(cs), jnp.sqrt(cs / jnp.where(a_s < 0, -a_s, 1.0)))
    T = jax.lax.stop_gradient(jnp.where(a_s >= 0, u + ap * ap / (9.0 * u) + ap / 3.0, below))
    for _ in range(SAG_NEWTON):
        T = jax.lax.stop_gradient(step(T))
    return jnp.where(sag, step(T), a)


def _small_sag_readings(robot, g, l0, t):
    """``(t_exit, t_att)`` (m,) N of the ``"small_sag"`` law: the spring tension ``t`` is the
    free span's mean tension; along the chord the tension grows by the weight's component
    (first order in the mass per length; the catenary's ``hypot(H, V_B - μ g l0)`` at the
    exit and ``hypot(H, V_B)`` at the attachment, linearized at ``μ = 0``)."""
    s = g.direction @ _up(robot)  # sine of the chord's elevation, attachment -> exit
    half = _half_span_weight(robot, g, l0)
    return t + s * (_weight_per_length(robot) * l0 - half), t - s * half


def _catenary_spans(g, up):
    d = -g.vector  # exit (A) -> attachment (B)
    sz = d @ up
    hvec = d - sz[:, None] * up
    sx2 = jnp.sum(hvec * hvec, axis=-1)
    sx = jnp.sqrt(jnp.where(sx2 > 0, sx2, 1.0))
    return jnp.where(sx2 > 0, sx, 0.0), sz, hvec / sx[:, None]


def _catenary_residual(z, args):
    """Platform wrench balance (6) and the span equations of every cable (2m)."""
    robot, l0, ext, _, pose0, scale = args
    m = l0.shape[0]
    p, R = moved_frame(pose0, z[:6])
    g = cable_geometry(robot, p, R)
    up = _up(robot)
    sx, sz, ex = _catenary_spans(g, up)
    H, VB = z[6:6 + m] * scale, z[6 + m:] * scale
    lf = _free_span_l0(g, l0)
    x_c, z_c = end_point(H, VB, lf, robot.EA, _weight_per_length(robot))
    W = platform_wrench(robot, R, g.offset, -H[:, None] * ex - VB[:, None] * up, ext)
    return jnp.concatenate([W / scale, (x_c - sx) / l0, (z_c - sz) / l0])


def _free_span_l0(g, l0):
    """Unstrained length of the free span from T (the catenary's part of the path): ``l0``
    less the wrapped arc ``r beta`` unstrained at the spring strain of the whole path
    (:func:`cstiffjax.catenary.free_span`); exactly ``l0`` without a pulley."""
    return l0 - g.wrap / (1.0 + jnp.maximum(g.length - l0, 0.0) / l0)


def _residual_fn(law):
    if law == "catenary":
        return _catenary_residual
    return lambda z, args: _spring_residual(law, z, args)


def _end_forces(robot, g, t):
    """``(H, V_B)`` (2, m), N, of straight cables of tensions ``t`` along ``g.direction``."""
    up = _up(robot)
    vb = -t * (g.direction @ up)
    return jnp.stack([jnp.sqrt(jnp.maximum(t * t - vb * vb, 0.0)), vb])


def _catenary_start(args, tw):
    """Catenary unknowns at the twist ``tw``: straight bilateral spring end forces with
    tensions floored at ``1e-3`` of the wrench scale (the joint solve starts taut)."""
    robot, l0, _, _, pose0, scale = args
    g = cable_geometry(robot, *moved_frame(pose0, tw))
    t = jnp.maximum(_spring_tensions("bilateral", g, l0, robot, None), 1e-3 * scale)
    return jnp.concatenate([tw, *(_end_forces(robot, g, t) / scale)])


# ------------------------------------------------------------------ iterations
def _linearize(fn, z):
    """``(f, J)``: ``fn(z)`` and its Jacobian (forward mode, one pass)."""
    J, f = jax.jacfwd(lambda y: (fn(y), fn(y)), has_aux=True)(z)
    return f, J


def _newton(fn, z0, steps, max_step, chord: bool = False):
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
    ``"spring"`` law) the old, stiffer ``J`` understates the step, so that law never uses
    it (:func:`_solve`). From a start whose first step is small enough (the posterior
    walkers' :func:`fitting.effects.model.chord_start`; a start 1e-8 away in the tests)
    this ends after one linearization instead of two (``taken`` 1 instead of 2)."""
    def body(c):
        k, taken, z, _, _, _ = c
        f, J = _linearize(fn, z)
        step = jnp.linalg.solve(J, f)
        size = jnp.max(jnp.abs(step))
        finite = jnp.all(jnp.isfinite(step))
        converged = finite & (size <= NEWTON_STOP)
        k = k + 1  # linearizations so far: at most steps + 1 (the last one only gives J)
        apply = finite & ~converged & (k <= steps)
        z = jnp.where(apply, z - step * jnp.minimum(1.0, max_step / (size + 1e-300)), z)
        done = converged | (k > steps)
        if chord:
            nxt = jnp.linalg.solve(J, fn(z))
            done = done | (apply & (size <= CHORD_STEP) & jnp.all(jnp.abs(nxt) <= NEWTON_STOP))
        return k, taken + apply.astype(k.dtype), z, J, done, converged

    zero = jnp.zeros((), jnp.int32)
    init = (zero, zero, z0, jnp.zeros((z0.shape[0],) * 2, z0.dtype), jnp.zeros((), bool), jnp.zeros((), bool))
    _, taken, z, J, _, converged = jax.lax.while_loop(lambda c: ~c[4], body, init)
    return jax.lax.stop_gradient(z), jax.lax.stop_gradient(J), taken + converged.astype(taken.dtype)


def _dense_lm(fn, z0, max_steps, rtol=1e-10, atol=1e-10):
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
        return _linearize(fn, z)

    def body(c):
        i, z, f, J, lam, _ = c
        A, g = J.T @ J, J.T @ f
        step = -jnp.linalg.solve(A + lam * jnp.eye(z.shape[0], dtype=z.dtype), g)
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
    init = (jnp.zeros((), jnp.int32), z0, f0, J0, jnp.asarray(1.0, z0.dtype), jnp.max(jnp.abs(f0)) <= 1e-15)
    i, z, _, J, *_ = jax.lax.while_loop(lambda c: (c[0] < max_steps) & ~c[5], body, init)
    return jax.lax.stop_gradient(z), jax.lax.stop_gradient(J), jnp.all(jnp.isfinite(z)), i


def _lm(fn, z0, args, solver, max_steps):
    """Levenberg-Marquardt on ``fn(z, args)`` (no gradients): ``(z, J, ok, num_steps)``
    (``J`` the Jacobian at ``z``; None from an optimistix solver, the caller forms it);
    ``ok`` false on a solver failure other than running out of steps (the residual is
    checked afterwards). ``solver`` None: :func:`_dense_lm`; else an optimistix
    least-squares solver (LM may stall at the rounding floor of an equilibrium that is
    within tolerance; optimistix reports that as ``nonlinear_max_steps_reached``,
    ``max_steps_reached`` is lineax's code)."""
    if solver is None:
        return _dense_lm(lambda z: fn(z, args), z0, max_steps)
    sol = optx.least_squares(fn, solver, z0, args=args, max_steps=max_steps, throw=False)
    z = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, z0)
    ok = (sol.result == optx.RESULTS.successful) | (sol.result == optx.RESULTS.nonlinear_max_steps_reached)
    return jax.lax.stop_gradient(z), None, ok, sol.stats["num_steps"]


def _implicit_step(fn, z, J, live):
    """One Newton step whose derivative is the implicit-function derivative ``-J⁻¹ ∂F/∂θ``."""
    return z - jnp.linalg.solve(J, fn(z, live))


# ------------------------------------------------------------------ kinematics
def _kinematic_residual(twist, args):
    robot, pose0, l0 = args
    return _lengths_at(robot, *moved_frame(pose0, twist)) - l0


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
    args = (robot, pose0, l0)
    if solver is None:
        tw, _, ok, _ = _dense_lm(lambda z: _kinematic_residual(z, args), jnp.zeros(6), max_steps, 1e-12, 1e-12)
    else:
        sol = optx.least_squares(_kinematic_residual, solver, jnp.zeros(6), args=args, max_steps=max_steps,
                                 throw=False)
        tw, ok = sol.value, sol.result == optx.RESULTS.successful
    err = jnp.max(jnp.abs(_kinematic_residual(tw, args)))
    ok = ok & (err < 1e-9)
    result = Status.where(ok, Status.successful, Status.not_converged)
    pose = apply_twist(pose0, tw)
    return raise_if_failed(result, (pose, result), throw)


# ------------------------------------------------------------------ forward statics
def _solve(law, start, args, forces0, solver, steps, max_steps, chord=False):
    """Converged unknowns and the residual's Jacobian there (no gradients; ``J`` None when
    an optimistix solver gave ``z``), LM health and steps of one elastic solve (``chord``:
    the warm Newton's, :func:`_newton`)."""
    scale = args[5]
    fn = _residual_fn(law)
    chord = chord and law != "spring"  # the one-sided law's kink at slack softens: no chord exit (_newton)
    if start == "warm":
        n = jnp.zeros((), jnp.int32)
        if law == "catenary" and forces0 is not None:
            z0 = jnp.concatenate([jnp.zeros(6), forces0[0] / scale, forces0[1] / scale])
        else:
            spring_law = "bilateral" if law == "catenary" else law
            tw, J, n = _newton(lambda z: _residual_fn(spring_law)(z, args), jnp.zeros(6), steps, 0.05, chord)
            if law != "catenary":
                return tw, J, jnp.array(True), n
            z0 = _catenary_start(args, tw)
        z, J, n2 = _newton(lambda z: fn(z, args), z0, steps, 0.5, chord)
        return z, J, jnp.array(True), n + n2
    # cold: the bilateral spring (smooth, nearly linear from the ideal pose, where every
    # cable sits exactly at l = l0 and the one-sided law has no gradient), then the law
    tw, J, ok, n = _lm(_residual_fn("bilateral"), jnp.zeros(6), args, solver, max_steps)
    if law == "bilateral":
        return tw, J, ok, n
    z0 = _catenary_start(args, tw) if law == "catenary" else tw
    z, J, ok2, n2 = _lm(fn, z0, args, solver, max_steps)
    return z, J, ok & ok2, n + n2


def _outputs(law, z, args):
    """Pose, tensions at both ends, slack flags and end forces at the unknowns ``z``."""
    robot, l0, _, tension, pose0, scale = args
    p, R = moved_frame(pose0, z[:6])
    pose = jnp.concatenate([p, lie.log(R)])
    if law == "catenary":
        m = l0.shape[0]
        forces = z[6:].reshape(2, m) * scale
        t_att = jnp.hypot(forces[0], forces[1])
        t_exit = jnp.hypot(forces[0], forces[1] - _weight_per_length(robot) * l0)
        return pose, t_exit, t_att, forces[0] <= 0, forces
    g = cable_geometry(robot, p, R)
    t = _spring_tensions(law, g, l0, robot, tension)
    forces = _end_forces(robot, g, t)
    if law != "small_sag":
        return pose, t, t, t <= 0, forces
    # weightless cables (mass per length 0): every added term below is 0
    t_exit, t_att = _small_sag_readings(robot, g, l0, t)
    return pose, t_exit, t_att, t <= 0, forces.at[1].add(_half_span_weight(robot, g, l0))


def _ideal(robot, l0, external, pose0, solver, max_steps):
    pose, kin = forward_kinematics(robot, l0, pose0, solver=solver, max_steps=max_steps, throw=False)
    inv = inverse_statics(robot, pose, external, throw=False)
    t = inv.tensions
    res = Status.where(kin == Status.successful, inv.result, kin)
    forces = _end_forces(robot, cable_geometry(robot, *moved_frame(pose, jnp.zeros(6))), t)
    return ForwardStatics(pose, t, t, t <= 0, forces, inv.residual, res, jnp.array(0))


@eqx.filter_jit
def _input_status(l0, ext) -> Status:
    """``invalid_input`` unless every ``l0`` is finite and positive and the wrench is finite."""
    ext = jnp.zeros(6) if ext is None else jnp.asarray(ext, dtype=jnp.float64)
    ok = jnp.all(jnp.isfinite(l0) & (l0 > 0)) & jnp.all(jnp.isfinite(ext))
    return Status.where(ok, Status.successful, Status.invalid_input)


class Solved(eqx.Module):
    """The converged unknowns of one elastic forward-statics solve, without gradients
    (:func:`solve_unknowns`): ``z`` the twist from ``pose0`` (6) and, for the catenary,
    every cable's end forces divided by the wrench scale (``6 + 2m``); ``J`` the scaled
    residual's Jacobian at ``z``; ``healthy`` the solver's health (the residual is checked
    by :func:`forward_statics`); ``num_steps`` its iterations."""

    z: Float[Array, " k"]
    J: Float[Array, "k k"]
    healthy: Bool[Array, ""]
    num_steps: Int[Array, ""]


def _setup(robot, l0, external, pose0, law, start, forces0, tension):
    """Checked and converted arguments: ``(l0, ext, pose0, forces0, live)``, ``live`` the
    residual's arguments with their derivatives (pose0 and the scale have none)."""
    if law not in LAWS:
        raise ValueError(f"unknown cable law {law!r}; allowed: {', '.join(map(repr, LAWS))}")
    if start not in TOL:
        raise ValueError(f"start must be 'cold' or 'warm', got {start!r}")
    if tension is not None and law not in SPRING_LAWS:
        raise ValueError(f"a tension hook needs a spring law ({', '.join(map(repr, SPRING_LAWS))}), got law {law!r}")
    if forces0 is not None and (law != "catenary" or start != "warm"):
        raise ValueError("forces0 warm-starts the catenary law only (law='catenary', start='warm')")
    l0 = jnp.asarray(l0, dtype=jnp.float64)
    ext = jnp.zeros(6) if external is None else jnp.asarray(external, dtype=jnp.float64)
    if pose0 is None:
        pose0, _ = forward_kinematics(robot, l0, throw=False)
    pose0 = jax.lax.stop_gradient(jnp.asarray(pose0, dtype=jnp.float64))
    forces0 = None if forces0 is None else jax.lax.stop_gradient(jnp.asarray(forces0, dtype=jnp.float64))
    scale = jax.lax.stop_gradient(wrench_scale(robot, ext))
    return l0, ext, pose0, forces0, (robot, l0, ext, tension, pose0, scale)


def _solved(law, start, frozen, forces0, solver, steps, max_steps, chord=False) -> Solved:
    """:func:`_solve` with ``J`` always formed, as a :class:`Solved`."""
    z, J, healthy, num_steps = _solve(law, start, frozen, forces0, solver, steps, max_steps, chord)
    if J is None:  # an optimistix solver: linearize at its solution
        J = jax.lax.stop_gradient(jax.jacfwd(lambda y: _residual_fn(law)(y, frozen))(z))
    return Solved(z, J, healthy, num_steps)


@eqx.filter_jit
def solve_unknowns(
    robot, l0: Float[Array, " m"], external: Float[Array, "6"] | None = None, pose0: Float[Array, "6"] | None = None,
    *, law: str = "spring", start: str = "cold", forces0: Float[Array, "2 m"] | None = None,
    tension: Callable | None = None, steps: int = NEWTON_STEPS, solver=None, max_steps: int = 256,
) -> Solved:
    """The solve of :func:`forward_statics` alone (same arguments; the elastic laws, not
    ``"ideal"``): its converged unknowns, without gradients. Hand the result to
    ``forward_statics(..., solved=...)`` with the *same* arguments (their values may
    carry tangents there) to take only the implicit step: for many derivative passes at
    one point (the diagnosis's Jacobian columns in chunks), the solve is then done once.

    **Returns:** a :class:`Solved`."""
    if law == "ideal":
        raise ValueError("solve_unknowns: the ideal law has no elastic solve (use forward_statics)")
    _, _, _, forces0, live = _setup(robot, l0, external, pose0, law, start, forces0, tension)
    return _solved(law, start, _frozen(live), forces0, solver, steps, max_steps)


def _check_solved(solved, law, m) -> None:
    """A :class:`Solved` for ``law`` and ``m`` cables, or a ``ValueError`` saying what is wrong."""
    if law == "ideal":
        raise ValueError("solved: the ideal law has no elastic solve")
    k = 6 + 2 * m if law == "catenary" else 6
    if not isinstance(solved, Solved) or solved.z.shape[-1:] != (k,) or solved.J.shape[-2:] != (k, k):
        got = solved.z.shape if isinstance(solved, Solved) else type(solved).__name__
        raise ValueError(f"solved: a Solved of solve_unknowns with {k} unknowns for law {law!r} and {m} cables "
                         f"was expected, got {got}")


@eqx.filter_jit
def forward_statics(
    robot, l0: Float[Array, " m"], external: Float[Array, "6"] | None = None, pose0: Float[Array, "6"] | None = None,
    *, law: str = "spring", start: str = "cold", forces0: Float[Array, "2 m"] | None = None,
    tension: Callable | None = None, steps: int = NEWTON_STEPS, solver=None, max_steps: int = 256,
    tol: float | None = None, throw: bool = True, solved: Solved | None = None, derivatives: bool = True,
) -> ForwardStatics:
    """Pose and tensions of the platform hanging on cables of unstrained lengths ``l0``.

    Seed 003 "direct kinematics" (see the module docstring for the unknowns and the two
    starts). Differentiable (exact implicit-function derivative) in ``l0``, ``external``,
    the robot's leaves and the array leaves of ``tension``.

    **Arguments:**

    - ``robot``: a :class:`~cstiffjax.robot.CableRobot`.
    - ``l0``: (m,) unstrained lengths, m. ``external``: (6,) wrench besides the weight,
      N / N·m about the reference point, base frame, or None.
    - ``pose0``: (6,) start pose; default (and required for ``start="warm"``): the
      ideal-cable pose of ``l0``.
    - ``law``: ``"spring"``, ``"bilateral"``, ``"small_sag"``, ``"catenary"`` or ``"ideal"``
      (module docstring).
    - ``start``: ``"cold"`` (Levenberg-Marquardt, robust from far away) or ``"warm"``
      (``steps`` clipped Newton steps from a nearby ``pose0``, cheap).
    - ``forces0``: (2, m) catenary end forces ``(H, V_B)`` N to warm-start from together
      with ``pose0`` (e.g. ``ForwardStatics.forces`` of a nearby solution); ``start="warm"``
      and the catenary law only.
    - ``tension``: spring laws only: ``t -> t'`` applied to the linear tensions
      ``EA (l - l0)/l0`` (m,) before the one-sided clamp (a modified cable law, e.g. the
      diagnosis's effects). Pass an ``eqx.Module`` or ``jax.tree_util.Partial`` whose
      leaves hold its parameters: they then get the implicit-function derivative.
    - ``steps``: most Newton steps of a warm start (per stage; it stops once converged).
      ``solver``: None (default) for the built-in dense Levenberg-Marquardt of the cold
      start (:func:`_dense_lm`), or an ``optx`` least-squares solver (e.g.
      :func:`default_solver`); ``max_steps`` per cold stage.
    - ``tol``: largest allowed scaled residual (wrench / ``(|weight| + |external| + 1)``,
      span errors / ``l0``); default :data:`TOL` (1e-9 cold, 1e-7 warm).
    - ``throw``: raise on failure (also under jit); else check ``result``.
    - ``derivatives``: False when no derivative will be taken (a sampler's evaluations): the
      outputs then carry none (``stop_gradient``), and, for the laws without a softening
      kink (not the one-sided ``"spring"``) and a ``tension`` hook without one, the warm
      Newton iteration may end with a chord check instead of one more linearization
      (:func:`_newton`, ``chord``; the last step is then still within
      :data:`NEWTON_STOP`). Default True.
    - ``solved``: :func:`solve_unknowns` of these same arguments (at their primal values):
      the solve is skipped (``solver``, ``steps`` and ``max_steps`` are then unused) and only
      the implicit step is taken; the result is the same. Elastic laws only; a ``Solved``
      of the wrong size (another law, another number of cables) is a ``ValueError``.

    **Returns:** a :class:`ForwardStatics`; ``result`` ``invalid_input`` when an ``l0`` is
    not finite and positive or the wrench is not finite, else ``not_converged`` when the
    residual is above ``tol``, anything is non-finite or the cold solver failed.

    **Notes:** the catenary cold start solves the pose and the end forces jointly from
    the spring equilibrium. The former design (LM on the pose with a per-cable catenary
    root find nested in every residual) failed on sample 12 of the uncertainty
    notebook's seed-1 data and on bench_fit's: its equilibrium was converged (wrench
    residual 6e-14 relative) but the nested root finds' forces jitter at rounding level
    from one trial step to the next, so LM's own step test never passed and it ran out
    of steps (``nonlinear_max_steps_reached``, which the residual check did not accept:
    it tested lineax's ``max_steps_reached``). The joint solve has no nested rounding
    floor (≤ 20 LM steps in all on those 210 samples) and the step-limit code is now the right
    one (``tests/test_statics.py::test_cold_catenary_converges_on_the_notebook_seed1_data``).
    """
    if not derivatives:  # values only: nothing below carries a derivative (the ideal law included)
        robot, l0, external, pose0, forces0, tension = _frozen((robot, l0, external, pose0, forces0, tension))
    l0, ext, pose0, forces0, live = _setup(robot, l0, external, pose0, law, start, forces0, tension)
    if solved is not None:
        _check_solved(solved, law, l0.shape[0])
    inputs = _input_status(l0, ext)  # invalid input wins over whatever the solve reports
    if law == "ideal":
        out = _ideal(robot, l0, external, pose0, solver, max_steps)
        out = eqx.tree_at(lambda o: o.result, out, Status.where(inputs == Status.successful, out.result, inputs))
        return raise_if_failed(out.result, out, throw)
    frozen = _frozen(live)
    sv = (_solved(law, start, frozen, forces0, solver, steps, max_steps, chord=not derivatives) if solved is None
          else _frozen(solved))
    fn = _residual_fn(law)
    z = _implicit_step(fn, sv.z, sv.J, live)
    res = fn(z, live)
    pose, t_exit, t_att, slack, forces = _outputs(law, z, live)
    tol = TOL[start] if tol is None else tol
    ok = sv.healthy & jnp.all(jnp.isfinite(res)) & (jnp.max(jnp.abs(res)) < tol) & jnp.all(jnp.isfinite(t_exit))
    result = Status.where(ok, Status.successful, Status.not_converged)
    result = Status.where(inputs == Status.successful, result, inputs)
    out = ForwardStatics(pose, t_exit, t_att, slack, forces, res[:6] * live[5], result, sv.num_steps)
    out = out if derivatives else _frozen(out)  # (a hook closing over a traced value included)
    return raise_if_failed(result, out, throw)
