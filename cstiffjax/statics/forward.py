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
  (:func:`cstiffjax.cable.catenary.end_point`, seed 003 eqs 23-24, residuals divided by
  ``l0``): no root find is nested in another.
- ``"small_sag"``: the bilateral spring with the cables' weight (``mass_per_length``) to
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
- ``"ideal"``: inextensible cables: the pose matching the lengths
  (:func:`forward_kinematics`), tensions by :func:`cstiffjax.statics.geometry.inverse_statics`.

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

from cstiffjax.core import lie
from cstiffjax.core.status import Status, raise_if_failed
from cstiffjax.statics.geometry import apply_twist, cable_geometry, inverse_statics, lengths_at, moved_frame
from cstiffjax.statics.residuals import (
    catenary_start,
    end_forces,
    half_span_weight,
    residual_fn,
    small_sag_readings,
    spring_tensions,
    weight_per_length,
)
from cstiffjax.statics.root_finding import dense_lm, implicit_step, levenberg_marquardt, newton

LAWS = ("ideal", "spring", "bilateral", "small_sag", "catenary")
SPRING_LAWS = ("spring", "bilateral", "small_sag")  # the laws whose unknown is the twist alone
NEWTON_STEPS = 12  # most Newton steps of a warm start per stage (it stops earlier once converged)
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
    in place of the built-in dense one (:func:`~cstiffjax.statics.root_finding.dense_lm`; any
    ``optx`` least-squares solver can be passed)."""
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


# ------------------------------------------------------------------ kinematics
def _kinematic_residual(twist, args):
    robot, pose0, l0 = args
    return lengths_at(robot, *moved_frame(pose0, twist)) - l0


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
        tw, _, ok, _ = dense_lm(lambda z: _kinematic_residual(z, args), jnp.zeros(6), max_steps, 1e-12, 1e-12)
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
    the warm Newton's, :func:`~cstiffjax.statics.root_finding.newton`)."""
    scale = args[5]
    fn = residual_fn(law)
    chord = chord and law != "spring"  # the one-sided law's kink at slack softens: no chord exit (newton)
    if start == "warm":
        n = jnp.zeros((), jnp.int32)
        if law == "catenary" and forces0 is not None:
            z0 = jnp.concatenate([jnp.zeros(6), forces0[0] / scale, forces0[1] / scale])
        else:
            spring_law = "bilateral" if law == "catenary" else law
            tw, J, n = newton(lambda z: residual_fn(spring_law)(z, args), jnp.zeros(6), steps, 0.05, chord)
            if law != "catenary":
                return tw, J, jnp.array(True), n
            z0 = catenary_start(args, tw)
        z, J, n2 = newton(lambda z: fn(z, args), z0, steps, 0.5, chord)
        return z, J, jnp.array(True), n + n2
    # cold: the bilateral spring (smooth, nearly linear from the ideal pose, where every
    # cable sits exactly at l = l0 and the one-sided law has no gradient), then the law
    tw, J, ok, n = levenberg_marquardt(residual_fn("bilateral"), jnp.zeros(6), args, solver, max_steps)
    if law == "bilateral":
        return tw, J, ok, n
    z0 = catenary_start(args, tw) if law == "catenary" else tw
    z, J, ok2, n2 = levenberg_marquardt(fn, z0, args, solver, max_steps)
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
        t_exit = jnp.hypot(forces[0], forces[1] - weight_per_length(robot) * l0)
        return pose, t_exit, t_att, forces[0] <= 0, forces
    g = cable_geometry(robot, p, R)
    t = spring_tensions(law, g, l0, robot, tension)
    forces = end_forces(robot, g, t)
    if law != "small_sag":
        return pose, t, t, t <= 0, forces
    # weightless cables (mass per length 0): every added term below is 0
    t_exit, t_att = small_sag_readings(robot, g, l0, t)
    return pose, t_exit, t_att, t <= 0, forces.at[1].add(half_span_weight(robot, g, l0))


def _ideal(robot, l0, external, pose0, solver, max_steps):
    pose, kin = forward_kinematics(robot, l0, pose0, solver=solver, max_steps=max_steps, throw=False)
    inv = inverse_statics(robot, pose, external, throw=False)
    t = inv.tensions
    res = Status.where(kin == Status.successful, inv.result, kin)
    forces = end_forces(robot, cable_geometry(robot, *moved_frame(pose, jnp.zeros(6))), t)
    return ForwardStatics(pose, t, t, t <= 0, forces, inv.residual, res, jnp.array(0))


@eqx.filter_jit
def input_status(l0, ext) -> Status:
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
        J = jax.lax.stop_gradient(jax.jacfwd(lambda y: residual_fn(law)(y, frozen))(z))
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

    - ``robot``: a :class:`~cstiffjax.io.robot.CableRobot`.
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
      start (:func:`~cstiffjax.statics.root_finding.dense_lm`), or an ``optx`` least-squares
      solver (e.g. :func:`default_solver`); ``max_steps`` per cold stage.
    - ``tol``: largest allowed scaled residual (wrench / ``(|weight| + |external| + 1)``,
      span errors / ``l0``); default :data:`TOL` (1e-9 cold, 1e-7 warm). The wrench rows
      are held to ``max(tol, wrench_floor(...))``: what float64 resolves at the cables'
      stiffness (:func:`wrench_floor`; above ``tol`` only for EA beyond ~1e8 N).
    - ``throw``: raise on failure (also under jit); else check ``result``.
    - ``derivatives``: False when no derivative will be taken (a sampler's evaluations): the
      outputs then carry none (``stop_gradient``), and, for the laws without a softening
      kink (not the one-sided ``"spring"``) and a ``tension`` hook without one, the warm
      Newton iteration may end with a chord check instead of one more linearization
      (:func:`~cstiffjax.statics.root_finding.newton`, ``chord``; the last step is then still
      within :data:`~cstiffjax.statics.root_finding.NEWTON_STOP`). Default True.
    - ``solved``: :func:`solve_unknowns` of these same arguments (at their primal values):
      the solve is skipped (``solver``, ``steps`` and ``max_steps`` are then unused) and only
      the implicit step is taken; the result is the same. Elastic laws only; a ``Solved``
      of the wrong size (another law, another number of cables) is a ``ValueError``.

    **Returns:** a :class:`ForwardStatics`; ``result`` ``invalid_input`` when an ``l0`` is
    not finite and positive or the wrench or a given ``pose0`` is not finite, else
    ``not_converged`` when the residual is above ``tol``, anything is non-finite or the
    cold solver failed.

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
    given = pose0
    l0, ext, pose0, forces0, live = _setup(robot, l0, external, pose0, law, start, forces0, tension)
    if solved is not None:
        _check_solved(solved, law, l0.shape[0])
    inputs = input_status(l0, ext)  # invalid input wins over whatever the solve reports
    if given is not None:  # a start pose given: a non-finite one is invalid input too
        inputs = Status.where(jnp.all(jnp.isfinite(pose0)), inputs, Status.invalid_input)
    if law == "ideal":
        out = _ideal(robot, l0, external, pose0, solver, max_steps)
        out = eqx.tree_at(lambda o: o.result, out, Status.where(inputs == Status.successful, out.result, inputs))
        return raise_if_failed(out.result, out, throw)
    frozen = _frozen(live)
    sv = (_solved(law, start, frozen, forces0, solver, steps, max_steps, chord=not derivatives) if solved is None
          else _frozen(solved))
    fn = residual_fn(law)
    z = implicit_step(fn, sv.z, sv.J, live)
    res = fn(z, live)
    pose, t_exit, t_att, slack, forces = _outputs(law, z, live)
    tol = TOL[start] if tol is None else tol
    wrench_tol = jnp.maximum(tol, wrench_floor(live[0], l0, pose, live[5]))  # what float64 resolves (stiff cables)
    within = (jnp.max(jnp.abs(res[:6])) < wrench_tol) & (jnp.max(jnp.abs(res[6:]), initial=0.0) < tol)
    ok = sv.healthy & jnp.all(jnp.isfinite(res)) & within & jnp.all(jnp.isfinite(t_exit))
    result = Status.where(ok, Status.successful, Status.not_converged)
    result = Status.where(inputs == Status.successful, result, inputs)
    out = ForwardStatics(pose, t_exit, t_att, slack, forces, res[:6] * live[5], result, sv.num_steps)
    out = out if derivatives else _frozen(out)  # (a hook closing over a traced value included)
    return raise_if_failed(result, out, throw)
