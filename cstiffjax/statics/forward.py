"""Forward statics (Yuan et al. 2015 "direct kinematics"): the one equilibrium solver of cstiffjax.

The platform hangs on cables of unstrained lengths ``l0`` under its weight and an external
wrench (a :class:`StaticsProblem`); :func:`forward_statics` finds where it settles, for every
cable law (:class:`~cstiffjax.cable.laws.CableLaw`):

- ``spring`` (one-sided: slack cables carry nothing), ``bilateral`` (a spring that
  also pushes when ``l < l0``: smooth, for fits whose intermediate models must not stall
  at the slack kink; the same equilibrium while every cable is taut): the unknown is the
  base-frame twist ``δx`` (6) from the start pose; the residual is the net wrench
  (Cui et al. 2019 eq. 3) divided by ``|weight| + |external| + 1``.
- ``catenary``: the twist and every cable's end forces ``(H, V_B)`` at the attachment
  are solved together (``6 + 2m`` unknowns), with the span equations in closed form
  (:func:`cstiffjax.cable.catenary.end_point`, Yuan et al. 2015 eqs 23-24, residuals divided by
  ``l0``): no root find is nested in another.
- ``small_sag``: the bilateral spring with the cables' weight (``mass_per_length``) to
  small sag (Irvine, *Cable Structures* §3.2): every spring tension is its free span's
  mean tension, lowered by the sag's shortening of the chord
  (:func:`~cstiffjax.statics.residuals.sag_tension`); the platform carries half of each
  span's weight at the attachment; the load cell reads the tension grown along the chord.
  Within 0.2 % of the elastic catenary's change of the pose and 1.3 % of its change of
  the tensions at 0.25 kg/m on the bundled robots
  (``tests/test_small_sag.py``), at a spring law's cost: the diagnosis screens
  ``cable_mass`` with it (:class:`fitting.effects.CableMassScreen`). Without cable weight it
  is the bilateral law (every added term is 0; equal to rounding); with weight, a cable the
  bilateral law would compress carries a small positive tension instead (a sagging cable
  cannot push, as on the catenary).
- ``ideal``: inextensible cables: the pose matching the lengths
  (:func:`~cstiffjax.statics.kinematics.forward_kinematics`), tensions by
  :func:`cstiffjax.statics.geometry.inverse_statics`.

Every law reads the cable paths from :func:`cstiffjax.statics.geometry.cable_geometry` only. The
residuals of the laws are in :mod:`cstiffjax.statics.residuals`, the iterations that solve
them (Newton, dense Levenberg-Marquardt, the implicit step) in :mod:`cstiffjax.statics.root_finding`;
this module puts them together behind one function and one result type.

Two starts, one function (``start``):

- ``"cold"`` (default): from any start pose (default the ideal-cable pose of ``l0``):
  Levenberg-Marquardt (a small dense one, :func:`~cstiffjax.statics.root_finding.dense_lm`; or an
  optimistix solver passed as ``solver``) on the bilateral spring law first (nearly linear), then
  on the requested law from there. For the catenary, the joint solve starts from the
  spring equilibrium with the straight cables' end forces.
- ``"warm"``: at most ``steps`` clipped Newton steps (fewer once a step is below
  :data:`~cstiffjax.statics.root_finding.NEWTON_STOP`) from a start that is already close (the
  measured pose, or the solution at a nearby parameter point, with its catenary end
  forces ``forces0``): a few ms per 100 samples, what fits and samplers need by the
  thousand.

Fewer than 6 cables (a suspended robot, :mod:`cstiffjax.statics.suspended`): the same
equations; the default start is the pose of least potential energy of straight spring
cables and the weight (:func:`~cstiffjax.statics.suspended.energy_start`), the ``ideal`` law
is refused, and an equilibrium whose stiffness (the weight's term included) is not
positive definite is ``Status.unstable``.

Both end with one Newton step taken *with* gradients at the converged point (all earlier
iterations run under ``stop_gradient``): its derivative is exactly the implicit-function
derivative ``-J⁻¹ ∂F/∂θ`` with respect to every array of the problem (robot leaves, ``l0``,
``external``, the parameters of a ``tension`` hook); the start has no derivative. The
solve alone is :func:`solve_unknowns`; ``forward_statics(problem, solved=...)`` then takes
only that last step (many derivative passes at one point share one solve).

Why the cold catenary start is done this way: see :func:`forward_statics` (Notes).
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from cstiffjax.cable.laws import ALL_LAWS, CableLaw, check_law
from cstiffjax.core import lie
from cstiffjax.core.arrays import batched_like
from cstiffjax.core.status import Status, raise_if_failed, solver_errors
from cstiffjax.io.robot import CableRobot
from cstiffjax.statics.batch import batch_shape, first_failure, over_batch
from cstiffjax.statics.geometry import cable_geometry, inverse_statics, moved_frame, pose_vector
from cstiffjax.statics.kinematics import ForwardKinematics as ForwardKinematics
from cstiffjax.statics.kinematics import forward_kinematics as forward_kinematics
from cstiffjax.statics.residuals import (
    ELASTIC_LAWS,
    SPRING_LAWS,
    ResidualArgs,
    catenary_start,
    end_forces,
    half_span_weight,
    residual_fn,
    small_sag_readings,
    spring_tensions,
    weight_per_length,
)
from cstiffjax.statics.root_finding import implicit_step, least_squares_root, newton
from cstiffjax.statics.suspended import FULL, energy_start, is_stable, platform_size, stiffness_at, under_constrained

NEWTON_STEPS = 12  # most Newton steps of a warm start per stage (it stops earlier once converged)
TOL = {"cold": 1e-9, "warm": 1e-7}  # largest scaled residual (wrench / (|weight| + |external| + 1), span / l0)


def _float64(x):
    return jnp.asarray(x, dtype=jnp.float64)


def _float64_or_none(x):
    return None if x is None else jnp.asarray(x, dtype=jnp.float64)


class StaticsProblem(eqx.Module):
    """What :func:`forward_statics` solves: the platform of ``robot`` hanging on cables of
    unstrained lengths ``l0`` under its weight and ``external``, the cables following ``law``.

    **Fields:**

    - ``robot``: a :class:`~cstiffjax.io.robot.CableRobot`.
    - ``l0``: (m,) unstrained lengths, m (converted to float64).
    - ``external``: (6,) wrench besides the weight, N / N·m about the reference point, base
      frame; None (default) for none.
    - ``law``: a :class:`~cstiffjax.cable.laws.CableLaw` (default ``CableLaw.spring``; every
      law, module docstring). Static: each law is its own compiled program.
    - ``tension``: spring laws only (``spring``, ``bilateral``, ``small_sag``): ``t -> t'``
      applied to the linear tensions ``EA (l - l0)/l0`` (m,) before the one-sided clamp (a
      modified cable law, e.g. the diagnosis's effects), or None. Pass an ``eqx.Module`` or
      ``jax.tree_util.Partial`` whose leaves hold its parameters: they then get the
      implicit-function derivative.

    Every array leaf may carry a derivative (:func:`forward_statics`). ``l0`` and
    ``external`` may have leading batch axes, broadcast together (``(n, m)`` lengths with one
    ``(6,)`` wrench, or the reverse): :func:`forward_statics` then solves every problem of the
    batch (under ``jax.vmap``, :mod:`cstiffjax.statics.batch`) and its results carry the batch
    axes in front; the robot and the ``tension`` hook are shared.

    **Raises** at construction: ``TypeError`` when ``law`` is not a ``CableLaw``;
    ``ValueError`` when ``l0``'s last axis is not one entry per cable of ``robot``,
    ``external``'s not 6, their batch axes do not broadcast, or a ``tension`` hook comes
    with a law that has none.
    """

    robot: CableRobot
    l0: Float[Array, "*batch m"] = eqx.field(converter=_float64)
    external: Float[Array, "*batch 6"] | None = eqx.field(default=None, converter=_float64_or_none)
    law: CableLaw = eqx.field(static=True, default=CableLaw.spring)
    tension: Callable | None = None

    def __check_init__(self):
        check_law(self.law, ALL_LAWS, "StaticsProblem")
        m = self.robot.anchors.shape[-2]
        if self.l0.ndim < 1 or self.l0.shape[-1] != m:
            raise ValueError(f"StaticsProblem: l0 has shape {self.l0.shape}; robot {self.robot.name!r} has {m} "
                             f"cables: shape ({m},) expected (or leading batch axes)")
        if self.external is not None and (self.external.ndim < 1 or self.external.shape[-1] != 6):
            raise ValueError(f"StaticsProblem: external has shape {self.external.shape}; a wrench [f, m] of "
                             f"shape (6,) expected (or leading batch axes), or None")
        batch_shape(self.l0, self.external)
        if self.tension is not None:
            check_law(self.law, SPRING_LAWS, "a tension hook (StaticsProblem.tension)")


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
    in place of the built-in dense one (:func:`~cstiffjax.statics.root_finding.dense_lm`; any
    ``optx`` least-squares solver can be passed)."""
    import optimistix as optx  # optimistix only when traced (cstiffjax.cable.newton2's module doc)

    return optx.LevenbergMarquardt(rtol=rtol, atol=atol)


def wrench_scale(robot, external) -> Float[Array, ""]:
    """``|weight| + |external| + 1`` (N): the scale of the wrench residuals."""
    ext = jnp.zeros(6) if external is None else jnp.asarray(external, dtype=jnp.float64)
    return jnp.linalg.norm(robot.weight) + jnp.linalg.norm(ext) + 1.0


def wrench_floor(robot, l0, pose, scale) -> Float[Array, ""]:
    """The smallest scaled wrench residual float64 can resolve at this stiffness: a cable's
    length is known to a rounding error of about ``eps (|a_i| + |p| + |b_i|)`` (its anchor,
    the platform position and its attachment, m), which its spring turns into a force of
    ``EA_i / l0_i`` times that and a moment of up to ``|b_i|`` times the force; summed over
    the cables and divided by the wrench ``scale`` (:func:`wrench_scale`). 4e-12 for the
    bundled 6-cable robot (EA = 1e6 N: far below :data:`TOL`, which then decides alone),
    4e-6 at EA = 1e12 N, where no pose in float64 balances the wrench better: converged
    solves' residuals were at most a quarter of it for EA from 1e6 to 1e14 N, every law,
    both starts (``tests/test_limits.py``). :func:`forward_statics` accepts the wrench rows
    of a solution within ``max(tol, floor)``, the catenary's span rows within ``tol``.

    **Arguments:** ``robot``; ``l0`` (m,) m; ``pose`` (6,) the solution; ``scale`` N.

    **Returns:** the floor (dimensionless, like the scaled residual), without derivative.
    """
    eps = jnp.finfo(jnp.float64).eps
    arm = jnp.sqrt(jnp.sum(robot.attachments**2, axis=1))  # |b_i|, m
    size = jnp.sqrt(jnp.sum(robot.anchors**2, axis=1)) + jnp.sqrt(jnp.sum(pose[:3] ** 2)) + arm
    floor = jnp.sum(robot.EA / l0 * eps * size * jnp.maximum(1.0, arm)) / scale
    return jax.lax.stop_gradient(floor)


def _frozen(tree):
    """``tree`` with every array leaf behind ``stop_gradient`` (other leaves untouched)."""
    return jax.tree.map(lambda x: jax.lax.stop_gradient(x) if eqx.is_array(x) else x, tree)


# ------------------------------------------------------------------ forward statics
def _solve(law, start, args, forces0, solver, steps, max_steps, chord=False):
    """Converged unknowns and the residual's Jacobian there (no gradients; ``J`` None when
    an optimistix solver gave ``z``), LM health and steps of one elastic solve (``chord``:
    the warm Newton's, :func:`~cstiffjax.statics.root_finding.newton`)."""
    scale = args.scale
    fn = residual_fn(law)
    chord = chord and law is not CableLaw.spring  # the one-sided law's kink at slack softens: no chord exit (newton)
    if start == "warm":
        n = jnp.zeros((), jnp.int32)
        if law is CableLaw.catenary and forces0 is not None:
            z0 = jnp.concatenate([jnp.zeros(6), forces0[0] / scale, forces0[1] / scale])
        else:
            spring_law = CableLaw.bilateral if law is CableLaw.catenary else law
            z0 = batched_like(jnp.zeros(6), args.pose0)  # batched as the sample is: newton's loop batched once
            tw, J, n = newton(lambda z: residual_fn(spring_law)(z, args), z0, steps, 0.05, chord)
            if law is not CableLaw.catenary:
                return tw, J, jnp.array(True), n
            z0 = catenary_start(args, tw)
        z, J, n2 = newton(lambda z: fn(z, args), z0, steps, 0.5, chord)
        return z, J, jnp.array(True), n + n2
    # cold: the bilateral spring (smooth, nearly linear from the ideal pose, where every
    # cable sits exactly at l = l0 and the one-sided law has no gradient), then the law
    tw, J, ok, n = least_squares_root(residual_fn(CableLaw.bilateral), jnp.zeros(6), args, solver, max_steps)
    if law is CableLaw.bilateral:
        return tw, J, ok, n
    z0 = catenary_start(args, tw) if law is CableLaw.catenary else tw
    z, J, ok2, n2 = least_squares_root(fn, z0, args, solver, max_steps)
    return z, J, ok & ok2, n + n2


def _outputs(law, z, args: ResidualArgs):
    """Pose, tensions at both ends, slack flags and end forces at the unknowns ``z``."""
    robot, l0 = args.robot, args.l0
    p, R = moved_frame(args.pose0, z[:6])
    pose = jnp.concatenate([p, lie.log(R)])
    if law is CableLaw.catenary:
        m = l0.shape[0]
        forces = z[6:].reshape(2, m) * args.scale
        t_att = jnp.hypot(forces[0], forces[1])
        t_exit = jnp.hypot(forces[0], forces[1] - weight_per_length(robot) * l0)
        return pose, t_exit, t_att, forces[0] <= 0, forces
    g = cable_geometry(robot, p, R)
    t = spring_tensions(law, g, l0, robot, args.tension)
    forces = end_forces(robot, g, t)
    if law is not CableLaw.small_sag:
        return pose, t, t, t <= 0, forces
    # weightless cables (mass per length 0): every added term below is 0
    t_exit, t_att = small_sag_readings(robot, g, l0, t)
    return pose, t_exit, t_att, t <= 0, forces.at[1].add(half_span_weight(robot, g, l0))


def _ideal(robot, l0, external, pose0, solver, max_steps):
    fk = forward_kinematics(robot, l0, pose0, solver=solver, max_steps=max_steps, throw=False)
    pose, kin = fk.pose, fk.result
    inv = inverse_statics(robot, pose, external, throw=False)
    t = inv.tensions
    res = Status.where(kin == Status.successful, inv.result, kin)
    forces = end_forces(robot, cable_geometry(robot, *moved_frame(pose, jnp.zeros(6))), t)
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


def _checked_problem(problem) -> StaticsProblem:
    """``problem`` if it is a :class:`StaticsProblem`, else a ``TypeError`` saying what is expected."""
    if not isinstance(problem, StaticsProblem):
        raise TypeError(f"forward statics takes a StaticsProblem(robot, l0, external, law, tension) and the solver "
                        f"options as keywords; got {type(problem).__name__} first")
    return problem


def _setup(problem: StaticsProblem, pose0, start, forces0):
    """Checked and converted arguments: ``(ext, pose0, forces0, live)``, ``live`` the
    residual's arguments with their derivatives (pose0 and the scale have none)."""
    law = _checked_problem(problem).law
    if start not in TOL:
        raise ValueError(f"start must be 'cold' or 'warm', got {start!r}")
    if forces0 is not None and (law is not CableLaw.catenary or start != "warm"):
        raise ValueError("forces0 warm-starts the catenary law only (law=CableLaw.catenary, start='warm')")
    robot, l0 = problem.robot, problem.l0
    ext = jnp.zeros(6) if problem.external is None else problem.external
    if pose0 is None:
        pose0 = forward_kinematics(robot, l0, throw=False).pose
        if under_constrained(robot):  # an ideal-cable pose of l0 is a family: start where the platform hangs
            pose0 = energy_start(robot, l0, ext, pose0)
    pose0 = jax.lax.stop_gradient(pose_vector(pose0, "forward statics (pose0)"))
    forces0 = None if forces0 is None else jax.lax.stop_gradient(jnp.asarray(forces0, dtype=jnp.float64))
    scale = jax.lax.stop_gradient(wrench_scale(robot, ext))
    return ext, pose0, forces0, ResidualArgs(robot, l0, ext, problem.tension, pose0, scale)


def _solved(law, start, frozen, forces0, solver, steps, max_steps, chord=False) -> Solved:
    """:func:`_solve` with ``J`` always formed, as a :class:`Solved`."""
    z, J, healthy, num_steps = _solve(law, start, frozen, forces0, solver, steps, max_steps, chord)
    if J is None:  # an optimistix solver: linearize at its solution
        J = jax.lax.stop_gradient(jax.jacfwd(lambda y: residual_fn(law)(y, frozen))(z))
    return Solved(z, J, healthy, num_steps)


@eqx.filter_jit
def solve_unknowns(
    problem: StaticsProblem, *, pose0: Float[Array, "6"] | None = None, start: str = "cold",
    forces0: Float[Array, "2 m"] | None = None, steps: int = NEWTON_STEPS, solver=None, max_steps: int = 256,
) -> Solved:
    """The solve of :func:`forward_statics` alone (same arguments; the elastic laws,
    :data:`~cstiffjax.statics.residuals.ELASTIC_LAWS`): its converged unknowns, without
    gradients. Hand the result to ``forward_statics(problem, solved=...)`` with the *same*
    problem and start (their values may carry tangents there) to take only the implicit
    step: for many derivative passes at one point (the diagnosis's Jacobian columns in
    chunks), the solve is then done once.

    **Returns:** a :class:`Solved` (with the problem's batch axes in front, as
    :func:`forward_statics`)."""
    law = check_law(_checked_problem(problem).law, ELASTIC_LAWS, "solve_unknowns")

    def one(problem, pose0, forces0, _):
        _, _, forces0, live = _setup(problem, pose0, start, forces0)
        return _solved(law, start, _frozen(live), forces0, solver, steps, max_steps)

    batch = batch_shape(problem.l0, problem.external)
    return over_batch(one, problem, batch, pose0, forces0, None) if batch else one(problem, pose0, forces0, None)


def _check_solved(solved, law, m) -> None:
    """A :class:`Solved` for ``law`` and ``m`` cables, or a ``ValueError`` saying what is wrong."""
    check_law(law, ELASTIC_LAWS, "forward_statics with solved=")
    k = 6 + 2 * m if law is CableLaw.catenary else 6
    if not isinstance(solved, Solved) or solved.z.shape[-1:] != (k,) or solved.J.shape[-2:] != (k, k):
        got = solved.z.shape if isinstance(solved, Solved) else type(solved).__name__
        raise ValueError(f"solved: a Solved of solve_unknowns with {k} unknowns for law {law.name!r} and {m} cables "
                         f"was expected, got {got}")


@solver_errors
@eqx.filter_jit
def forward_statics(
    problem: StaticsProblem, *, pose0: Float[Array, "6"] | None = None, start: str = "cold",
    forces0: Float[Array, "2 m"] | None = None, steps: int = NEWTON_STEPS, solver=None, max_steps: int = 256,
    tol: float | None = None, throw: bool = True, solved: Solved | None = None, derivatives: bool = True,
) -> ForwardStatics:
    """Pose and tensions of the platform of ``problem`` (a :class:`StaticsProblem`).

    Seed 003 "direct kinematics" (see the module docstring for the unknowns and the two
    starts). Differentiable (exact implicit-function derivative) in the problem's arrays:
    ``l0``, ``external``, the robot's leaves and the array leaves of ``tension``.

    **Arguments:**

    - ``problem``: what is solved: robot, ``l0``, ``external``, ``law`` (every
      :class:`~cstiffjax.cable.laws.CableLaw`) and the spring laws' ``tension`` hook.
      With batch axes on ``l0`` / ``external`` (:class:`StaticsProblem`) every problem is
      solved (vmapped) and every field of the result has the batch axes in front.
    - ``pose0``: (6,) start pose (for a batch: shared, or ``(*batch, 6)``); default (and
      required for ``start="warm"``): the ideal-cable pose of ``l0``. Another shape is a
      ``ValueError``.
    - ``start``: ``"cold"`` (Levenberg-Marquardt, robust from far away) or ``"warm"``
      (``steps`` clipped Newton steps from a nearby ``pose0``, cheap).
    - ``forces0``: (2, m) catenary end forces ``(H, V_B)`` N to warm-start from together
      with ``pose0`` (e.g. ``ForwardStatics.forces`` of a nearby solution); ``start="warm"``
      and the catenary law only.
    - ``steps``: most Newton steps of a warm start (per stage; it stops once converged).
      ``solver``: None (default) for the built-in dense Levenberg-Marquardt of the cold
      start (:func:`~cstiffjax.statics.root_finding.dense_lm`), or an ``optx`` least-squares
      solver (e.g. :func:`default_solver`); ``max_steps`` per cold stage.
    - ``tol``: largest allowed scaled residual (wrench / ``(|weight| + |external| + 1)``,
      span errors / ``l0``); default :data:`TOL` (1e-9 cold, 1e-7 warm). The wrench rows
      are held to ``max(tol, wrench_floor(...))``: what float64 resolves at the cables'
      stiffness (:func:`wrench_floor`; above ``tol`` only for EA beyond ~1e8 N).
    - ``throw``: raise :class:`~cstiffjax.core.errors.SolverError` with the status text on
      failure (a batch: that of its first failed problem); under your own ``jax.jit`` it is
      JAX's ``JaxRuntimeError`` carrying the text (:func:`cstiffjax.core.status.readable_errors`
      converts it). Else (False) check ``result``.
    - ``derivatives``: False when no derivative will be taken (a sampler's evaluations): the
      outputs then carry none (``stop_gradient``), and, for the laws without a softening
      kink (not the one-sided ``spring``) and a ``tension`` hook without one, the warm
      Newton iteration may end with a chord check instead of one more linearization
      (:func:`~cstiffjax.statics.root_finding.newton`, ``chord``; the last step is then still
      within :data:`~cstiffjax.statics.root_finding.NEWTON_STOP`). Default True.
    - ``solved``: :func:`solve_unknowns` of this same problem and start (at their primal
      values): the solve is skipped (``solver``, ``steps`` and ``max_steps`` are then unused)
      and only the implicit step is taken; the result is the same. Elastic laws only; a
      ``Solved`` of the wrong size (another law, another number of cables) is a ``ValueError``.

    **Returns:** a :class:`ForwardStatics`; ``result`` ``invalid_input`` when an ``l0`` is
    not finite and positive or the wrench or a given ``pose0`` is not finite, else
    ``not_converged`` when the residual is above ``tol``, anything is non-finite or the
    cold solver failed; fewer than 6 cables: ``unstable`` for a converged equilibrium that
    is a saddle or has a direction without restoring force
    (:func:`~cstiffjax.statics.suspended.is_stable`).

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
    _checked_problem(problem)
    if solved is not None:
        _check_solved(solved, problem.law, problem.l0.shape[-1])

    def one(problem, pose0, forces0, solved):
        return _forward_one(problem, pose0, start, forces0, steps, solver, max_steps, tol, solved, derivatives)

    batch = batch_shape(problem.l0, problem.external)
    if not batch:
        out = one(problem, pose0, forces0, solved)
        return raise_if_failed(out.result, out, throw)
    out = over_batch(one, problem, batch, pose0, forces0, solved)
    return raise_if_failed(first_failure(out.result), out, throw)


def _forward_one(problem, pose0, start, forces0, steps, solver, max_steps, tol, solved, derivatives) -> ForwardStatics:
    """:func:`forward_statics` of one problem (no batch axes), without raising."""
    if not derivatives:  # values only: nothing below carries a derivative (the ideal law included)
        problem, pose0, forces0 = _frozen((problem, pose0, forces0))
    given = pose0
    ext, pose0, forces0, live = _setup(problem, pose0, start, forces0)
    law, l0 = problem.law, live.l0
    inputs = _input_status(l0, ext)  # invalid input wins over whatever the solve reports
    if given is not None:  # a start pose given: a non-finite one is invalid input too
        inputs = Status.where(jnp.all(jnp.isfinite(pose0)), inputs, Status.invalid_input)
    if law is CableLaw.ideal:
        if under_constrained(problem.robot):
            raise ValueError(f"forward statics with law ideal needs at least {FULL} cables; robot "
                             f"{problem.robot.name!r} has {l0.shape[0]}: fewer inextensible cables leave the pose "
                             f"free along {FULL - l0.shape[0]} directions (use an elastic law: gravity and the "
                             f"cables' stretch then decide where the platform hangs)")
        out = _ideal(problem.robot, l0, problem.external, pose0, solver, max_steps)
        return eqx.tree_at(lambda o: o.result, out, Status.where(inputs == Status.successful, out.result, inputs))
    frozen = _frozen(live)
    sv = (_solved(law, start, frozen, forces0, solver, steps, max_steps, chord=not derivatives) if solved is None
          else _frozen(solved))
    fn = residual_fn(law)
    z = implicit_step(fn, sv.z, sv.J, live)
    res = fn(z, live)
    pose, t_exit, t_att, slack, forces = _outputs(law, z, live)
    tol = TOL[start] if tol is None else tol
    wrench_tol = jnp.maximum(tol, wrench_floor(live.robot, l0, pose, live.scale))  # what float64 resolves
    within = (jnp.max(jnp.abs(res[:6])) < wrench_tol) & (jnp.max(jnp.abs(res[6:]), initial=0.0) < tol)
    ok = sv.healthy & jnp.all(jnp.isfinite(res)) & within & jnp.all(jnp.isfinite(t_exit))
    result = Status.where(ok, Status.successful, Status.not_converged)
    if under_constrained(live.robot):  # gravity closes the equilibrium: it may be a saddle (module suspended)
        stable = is_stable(stiffness_at(law, z, frozen), platform_size(live.robot), live.scale)
        result = Status.where((result == Status.successful) & ~stable, Status.unstable, result)
    result = Status.where(inputs == Status.successful, result, inputs)
    out = ForwardStatics(pose, t_exit, t_att, slack, forces, res[:6] * live.scale, result, sv.num_steps)
    return out if derivatives else _frozen(out)  # (a hook closing over a traced value included)
