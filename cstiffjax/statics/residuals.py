"""The residuals of forward statics' elastic laws and the quantities built from them
(:mod:`cstiffjax.statics.forward` solves them; every law reads the cable paths from
:func:`cstiffjax.statics.geometry.cable_geometry`; the ideal law's kinematic residual stays in
:mod:`cstiffjax.statics.forward`).

Every residual is ``fn(z, args)`` with ``args`` a :class:`ResidualArgs` (the problem as
solved, the start pose and the wrench scale):

- spring laws (:data:`SPRING_LAWS`: ``spring``, ``bilateral``, ``small_sag``): ``z`` the
  twist (6) from ``pose0``; the residual is the platform's net wrench (Cui et al. 2019 eq. 3)
  divided by ``scale`` = ``|weight| + |external| + 1`` (:func:`spring_residual`, tensions by
  :func:`spring_tensions`, forces by :func:`spring_platform_forces`);
- ``catenary``: the twist and every cable's end forces ``(H, V_B)`` divided by ``scale``
  (``6 + 2m``); the residual is the scaled wrench and the span equations in closed form
  (Yuan et al. 2015 eqs 23-24) divided by ``l0`` (:func:`catenary_residual`; its start from
  straight cables: :func:`catenary_start`, :func:`end_forces`);
- ``small_sag``'s mean tensions and readings follow Irvine's small-sag theory (*Cable
  Structures* §3.2): :func:`sag_tension`, :func:`sag_root`, :func:`small_sag_readings`,
  :func:`half_span_weight`.
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from cstiffjax.cable.catenary import end_point
from cstiffjax.cable.laws import ALL_LAWS, CableLaw, check_law
from cstiffjax.statics.geometry import cable_geometry, moved_frame, platform_wrench

SPRING_LAWS = frozenset({CableLaw.spring, CableLaw.bilateral, CableLaw.small_sag})  # unknown: the twist alone
ELASTIC_LAWS = ALL_LAWS - {CableLaw.ideal}  # the laws with a residual (the ideal law's pose is kinematic)


class ResidualArgs(eqx.Module):
    """The arguments ``args`` of every residual ``fn(z, args)``: the problem as solved and
    where its unknowns are measured from.

    ``robot`` a :class:`~cstiffjax.io.robot.CableRobot`; ``l0`` (m,) unstrained lengths, m;
    ``external`` (6,) wrench besides the weight, N / N·m (zeros when there is none);
    ``tension`` the spring laws' tension hook or None
    (:class:`cstiffjax.statics.forward.StaticsProblem`); ``pose0`` (6,) the pose the twist
    ``z[:6]`` starts from, m / rad; ``scale`` the wrench scale ``|weight| + |external| + 1``,
    N (:func:`cstiffjax.statics.forward.wrench_scale`).
    """

    robot: object
    l0: Float[Array, " m"]
    external: Float[Array, "6"]
    tension: Callable | None
    pose0: Float[Array, "6"]
    scale: Float[Array, ""]


def spring_tensions(law: CableLaw, geom, l0, robot, tension):
    """Cable tensions (m,) N of a spring law (:data:`SPRING_LAWS`) at the cable paths
    ``geom``: ``EA (l - l0)/l0``, for ``small_sag`` the free spans' mean tensions
    (:func:`sag_tension`), then the ``tension`` hook (or None), then, for the one-sided
    ``spring``, zero where negative."""
    t = robot.EA * (geom.length - l0) / l0
    t = sag_tension(robot, geom, l0, t) if law is CableLaw.small_sag else t
    t = t if tension is None else tension(t)
    return jnp.where(t > 0, t, 0.0) if law is CableLaw.spring else t


def spring_residual(law: CableLaw, z, args: ResidualArgs):
    """The platform's net wrench (6) at the twist ``z`` (6) from ``args.pose0``, divided by
    the wrench scale (N / N, N·m / N), under a spring law."""
    p, R = moved_frame(args.pose0, z)
    g = cable_geometry(args.robot, p, R)
    forces = spring_platform_forces(law, args.robot, g, args.l0, args.tension)
    return platform_wrench(args.robot, R, g.offset, forces, args.external) / args.scale


def spring_platform_forces(law: CableLaw, robot, g, l0, tension):
    """Every cable's force on the platform (m, 3), N, under a spring law at the cable paths
    ``g`` (``small_sag``: the mean tensions along the chords, :func:`sag_tension`, and half
    of every free span's weight)."""
    force = spring_tensions(law, g, l0, robot, tension)[:, None] * g.direction
    if law is CableLaw.small_sag:
        force = force - half_span_weight(robot, g, l0)[:, None] * up_vector(robot)
    return force


def up_vector(robot):
    """Unit vector against gravity (base frame)."""
    return -robot.gravity / jnp.linalg.norm(robot.gravity)


def weight_per_length(robot):
    """Cable weight per unstrained length (m,), N/m."""
    return robot.mass_per_length * jnp.linalg.norm(robot.gravity)


def half_span_weight(robot, g, l0):
    """Half the weight of each cable's free span (N): what the platform carries of it to
    first order in the mass per length (the ``small_sag`` law)."""
    return 0.5 * weight_per_length(robot) * free_span_l0(g, l0)


SAG_NEWTON = 3  # Newton steps without gradients after the start of sag_root (then one with)


def sag_tension(robot, g, l0, t_lin):
    """Mean tension ``T`` (m,) N of sagging free spans (Irvine's small-sag theory, *Cable
    Structures* §3.2): the sag shortens the chord by ``(w l_x)² L / (24 T²)`` (``w`` weight
    per length, ``l_x`` the chord's horizontal span, ``L`` the free span's unstrained
    length), so the spring's ``t_lin = EA (l - l0)/l0`` becomes the positive root ``T`` of
    ``T² (T - t_lin) = c = EA (w l_x)² L / (24 l0)`` (:func:`sag_root`)."""
    up, w = up_vector(robot), weight_per_length(robot)
    horizontal = g.vector - (g.vector @ up)[:, None] * up
    c = robot.EA * w * w * jnp.sum(horizontal * horizontal, axis=-1) * free_span_l0(g, l0) / (24.0 * l0)
    return sag_root(t_lin, c)


def sag_root(a, c):
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


def small_sag_readings(robot, g, l0, t):
    """``(t_exit, t_att)`` (m,) N of the ``small_sag`` law: the spring tension ``t`` is the
    free span's mean tension; along the chord the tension grows by the weight's component
    (first order in the mass per length; the catenary's ``hypot(H, V_B - μ g l0)`` at the
    exit and ``hypot(H, V_B)`` at the attachment, linearized at ``μ = 0``)."""
    s = g.direction @ up_vector(robot)  # sine of the chord's elevation, attachment -> exit
    half = half_span_weight(robot, g, l0)
    return t + s * (weight_per_length(robot) * l0 - half), t - s * half


def catenary_spans(g, up):
    """Each cable's chord from exit A to attachment B in its catenary plane: horizontal span
    (m,) m (>= 0), vertical span (m,) m along ``up``, and the horizontal unit vectors (m, 3)
    (undefined, but finite, for a vertical chord)."""
    d = -g.vector  # exit (A) -> attachment (B)
    sz = d @ up
    hvec = d - sz[:, None] * up
    sx2 = jnp.sum(hvec * hvec, axis=-1)
    sx = jnp.sqrt(jnp.where(sx2 > 0, sx2, 1.0))
    return jnp.where(sx2 > 0, sx, 0.0), sz, hvec / sx[:, None]


def catenary_residual(z, args: ResidualArgs):
    """Platform wrench balance (6) and the span equations of every cable (2m)."""
    robot, l0, scale = args.robot, args.l0, args.scale
    m = l0.shape[0]
    p, R = moved_frame(args.pose0, z[:6])
    g = cable_geometry(robot, p, R)
    up = up_vector(robot)
    sx, sz, ex = catenary_spans(g, up)
    H, VB = z[6:6 + m] * scale, z[6 + m:] * scale
    lf = free_span_l0(g, l0)
    x_c, z_c = end_point(H, VB, lf, robot.EA, weight_per_length(robot))
    W = platform_wrench(robot, R, g.offset, -H[:, None] * ex - VB[:, None] * up, args.external)
    return jnp.concatenate([W / scale, (x_c - sx) / l0, (z_c - sz) / l0])


def free_span_l0(g, l0):
    """Unstrained length of the free span from T (the catenary's part of the path): ``l0``
    less the wrapped arc ``r beta`` unstrained at the spring strain of the whole path
    (:func:`cstiffjax.cable.catenary.free_span`); exactly ``l0`` without a pulley."""
    return l0 - g.wrap / (1.0 + jnp.maximum(g.length - l0, 0.0) / l0)


def residual_fn(law: CableLaw):
    """The residual ``fn(z, args)`` of an elastic ``law`` (:data:`ELASTIC_LAWS`):
    :func:`catenary_residual`, or :func:`spring_residual` for the three spring laws."""
    if check_law(law, ELASTIC_LAWS, "residual_fn") is CableLaw.catenary:
        return catenary_residual
    return lambda z, args: spring_residual(law, z, args)


def end_forces(robot, g, t):
    """``(H, V_B)`` (2, m), N, of straight cables of tensions ``t`` along ``g.direction``."""
    up = up_vector(robot)
    vb = -t * (g.direction @ up)
    return jnp.stack([jnp.sqrt(jnp.maximum(t * t - vb * vb, 0.0)), vb])


def catenary_start(args: ResidualArgs, tw):
    """Catenary unknowns at the twist ``tw``: straight bilateral spring end forces with
    tensions floored at ``1e-3`` of the wrench scale (the joint solve starts taut)."""
    robot, scale = args.robot, args.scale
    g = cable_geometry(robot, *moved_frame(args.pose0, tw))
    t = jnp.maximum(spring_tensions(CableLaw.bilateral, g, args.l0, robot, None), 1e-3 * scale)
    return jnp.concatenate([tw, *(end_forces(robot, g, t) / scale)])
