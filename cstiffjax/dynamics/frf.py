"""Robot dynamics with sagging cables: mass matrix, dynamic stiffness ``K_M(ω)``, FRF,
natural frequencies (Yuan et al. 2015 Section 3.3, eqs 27-32) and the two classical modal
analyses it is compared with (massless springs, static sagging cables; Table 4).

Coordinates are the base-frame twists of :mod:`cstiffjax.statics.geometry` ``[δp, δθ]``.

Robot dynamic stiffness (Yuan et al. 2015 eqs 27-29, completed)::

    K_M(ω) = Σ_i A_iᵀ K_i(ω) A_i  -  Σ_i hat(f_i) hat(r_i)  -  hat(W) hat(R c)

with ``A_i = [I, -hat(r_i)]`` (eq. 29; ``r_i = R b_i``), ``K_i(ω)`` the base-frame DSM of
cable ``i`` (:mod:`cstiffjax.cable.dsm`), ``f_i`` the static force of cable ``i`` on the
platform and ``W`` the platform weight acting at the centre of mass ``R c``. **The last
two (geometric) terms are missing from Yuan et al. 2015 eq. (28)**: when the platform turns, the
static forces keep their direction but their lever arms turn. Without them ``K_M(0)``
would not equal the static stiffness ``-∂W/∂x`` (:mod:`cstiffjax.stiffness.matrix`); with them
it does (tested), and ``K_M`` is symmetric at an equilibrium with no external moment.

Mass matrix (kinetic energy ``½ m |v + ω × c|² + ½ ωᵀ I_b ω``, ``c = R com``,
``I_b = R I Rᵀ``)::

    M = [[m I, -m hat(c)], [m hat(c), I_b - m hat(c)²]]

FRF (eq. 32): ``X(ω) = [-ω² M + K_M(ω)]⁻¹ F``.

Natural frequencies: the roots of ``det(-ω² M + K_M(ω))`` are found with the
Wittrick-Williams algorithm, the standard exact method for dynamic stiffness
matrices: the number of natural frequencies below ``ω`` is ``J(ω) = J_0(ω) + s(ω)``,
``s`` the number of negative eigenvalues of the (undamped, symmetric) ``-ω² M + K_M(ω)``
and ``J_0`` the number of clamped-cable frequencies below ``ω``
(:func:`cstiffjax.cable.dsm.clamped_mode_count`). Bisection on ``J`` brackets every natural
frequency, multiple ones included (e.g. the double mode of Table 4), to a resolution
``tol`` (Hz) of the caller's choice, with no grid to miss close pairs.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from cstiffjax.cable.dsm import (
    cable_dynamic_stiffness,
    cable_frame,
    cable_parameters,
    cable_point_response,
    clamped_mode_count,
)
from cstiffjax.cable.laws import CABLE_FORCE_LAWS, CableLaw, check_law
from cstiffjax.cable.path import robot_paths
from cstiffjax.core import lie
from cstiffjax.core.status import Status, raise_if_failed, solver_errors
from cstiffjax.statics.geometry import elastic_cable_forces, elastic_wrench, frame, inverse_statics
from cstiffjax.stiffness.matrix import stiffness, unstrained_lengths


# ------------------------------------------------------------------ input checks
def _concrete(x):
    try:
        return np.asarray(x, dtype=float)
    except (TypeError, jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
        return None


def _require(name: str, x, lower: float, strict: bool, allowed: str):
    """Check ``x`` finite and ``> lower`` (``strict``) or ``>= lower``. Raise ``ValueError``
    naming ``name``, the bad value and ``allowed`` when ``x`` is concrete; under ``jit``
    raise at run time through ``eqx.error_if``."""
    a = _concrete(x)
    if a is not None:
        bad = ~(np.isfinite(a) & ((a > lower) if strict else (a >= lower)))
        if np.any(bad):
            v = float(a[bad].flat[0]) if a.ndim else float(a)
            raise ValueError(f"{name} = {v!r} is not allowed: {name} must be {allowed}")
        return jnp.asarray(x, jnp.float64)
    x = jnp.asarray(x, jnp.float64)
    ok = jnp.isfinite(x) & ((x > lower) if strict else (x >= lower))
    return eqx.error_if(x, jnp.any(~ok), f"{name} must be {allowed}")


def _check_omega_xi(omega, xi):
    omega = _require("omega", omega, 0.0, False, "finite and >= 0 (rad/s)")
    xi = _require("xi", xi, 0.0, False, "finite and >= 0 (damping ratio)")
    return omega, xi


def _check_robot(robot):
    _require("platform_mass", robot.platform_mass, 0.0, True,
             "> 0 kg (the platform mass matrix is singular otherwise)")
    ev = _concrete(robot.inertia)
    if ev is not None and not np.all(np.linalg.eigvalsh(0.5 * (ev + ev.T)) > 0):
        raise ValueError(f"inertia = {ev.tolist()} is not allowed: inertia must be symmetric positive definite "
                         "(kg m², about the centre of mass)")


# ------------------------------------------------------------------- static state
class CableStatics(eqx.Module):
    """Static state of the cables that the DSM is linearized about.

    ``tension``: (m,) chord-parallel tension τ of each cable, N (Yuan et al. 2015 Section 2.2).
    ``force``: (m, 3) static force of each cable on the platform, base frame, N.
    """

    tension: Float[Array, " m"]
    force: Float[Array, "m 3"]


def span_starts(robot, att: Float[Array, "m 3"]) -> Float[Array, "m 3"]:
    """Where each cable's vibrating free span starts: the anchor, or the tangent point of
    its swivel pulley (:func:`cstiffjax.cable.path.cable_path`), base frame, m."""
    return robot_paths(robot, att).tangent_point


def cable_statics_from_tensions(robot, pose, tensions) -> CableStatics:
    """Straight-cable static state: forces ``t_i u_i`` along the chords, ``τ_i = t_i``.

    Use with tensions from :func:`cstiffjax.statics.geometry.inverse_statics` (massless cables).
    The sag makes the chord-parallel tension of a heavy cable differ from the end
    tension by about ``ρ g Δz / 2``; :func:`cable_statics_from_lengths` is exact.
    """
    t = _require("tensions", tensions, 0.0, True,
                 "finite and > 0 N (a slack cable has no dynamic stiffness)")
    return CableStatics(t, t[:, None] * _unit_chords(robot, pose))


def cable_statics_from_lengths(robot, pose, l0, law: CableLaw = CableLaw.catenary) -> CableStatics:
    """Static state of cables of unstrained lengths ``l0`` (m) at ``pose`` under ``law`` (one
    of :data:`~cstiffjax.cable.laws.CABLE_FORCE_LAWS`).

    ``force`` is the end force at the attachment; ``τ = H / cos α`` with ``H`` the
    horizontal component of that force (constant along a catenary) and ``α`` the chord
    inclination: the tension where the cable is parallel to its chord, exactly.
    """
    cf = elastic_cable_forces(robot, pose, l0, check_law(law, CABLE_FORCE_LAWS, "cable_statics_from_lengths"))
    p, R = frame(pose)
    att = p + robot.attachments @ R.T
    g = robot.gravity
    g_hat = g / jnp.linalg.norm(g)
    f = cf.on_platform
    H = jnp.linalg.norm(f - (f @ g_hat)[:, None] * g_hat, axis=-1)
    cos_a = jax.vmap(lambda a, b: cable_frame(a, b, g).cos_alpha)(span_starts(robot, att), att)
    return CableStatics(H / cos_a, f)


class CatenaryLengths(eqx.Module):
    """Result of :func:`catenary_lengths`: ``l0`` (m,) unstrained lengths, m, and ``result``
    a :class:`~cstiffjax.core.status.Status`."""

    l0: Float[Array, " m"]
    result: Status


@solver_errors
def catenary_lengths(robot, pose, external=None, *, steps: int = 12, throw: bool = True) -> CatenaryLengths:
    """Unstrained lengths ``l0`` that hold ``pose`` with elastic-catenary cables.

    Seed 003 Section 3.2.1 a) (sagging inverse kinematics): solves
    ``elastic_wrench(pose, l0, law=CableLaw.catenary) = 0`` by Gauss-Newton (minimum-norm steps,
    Jacobian by forward-mode autodiff through the catenary solves), starting from the
    spring lengths of the minimum-norm tensions; for ``m > 6`` the answer is a solution
    near that start. ``steps`` Newton steps (quadratic convergence: 5-6 suffice for the
    prototype); ``throw``: raise (also under jit) unless successful. **Returns:** a
    :class:`CatenaryLengths`, ``result`` ``not_converged`` when the wrench residual is
    above ``1e-9 (|weight| + 1)``.
    """
    return _catenary_lengths(robot, jnp.asarray(pose, jnp.float64), external, steps, throw)


@eqx.filter_jit
def _catenary_lengths(robot, pose, external, steps, throw):
    t = inverse_statics(robot, pose, external, throw=False).tensions
    l0_spring = unstrained_lengths(robot, pose, t)
    scale = jnp.linalg.norm(robot.weight) + 1.0

    def resid(x):
        return elastic_wrench(robot, pose, l0_spring * (1.0 + x), external, CableLaw.catenary) / scale

    def step(_, x):
        J = jax.jacfwd(resid)(x)
        dx = -jnp.linalg.pinv(J) @ resid(x)
        return jnp.where(jnp.all(jnp.isfinite(dx)), x + dx, x)

    x = jax.lax.fori_loop(0, steps, step, jnp.zeros(robot.num_cables))
    l0 = l0_spring * (1.0 + x)
    ok = (jnp.max(jnp.abs(resid(x))) < 1e-9) & jnp.all(jnp.isfinite(l0))
    result = Status.where(ok, Status.successful, Status.not_converged)
    return raise_if_failed(result, CatenaryLengths(l0, result), throw)


# -------------------------------------------------------------------- mass and K_M
def mass_matrix(robot, pose) -> Float[Array, "6 6"]:
    """6x6 platform mass matrix in base-frame twist coordinates (kg, kg m, kg m²)."""
    _check_robot(robot)
    return _mass_matrix(robot, pose)


def _mass_matrix(robot, pose):
    _, R = frame(pose)
    m = robot.platform_mass
    C = lie.hat(R @ robot.com)
    Ib = R @ robot.inertia @ R.T
    top = jnp.concatenate([m * jnp.eye(3), -m * C], axis=1)
    bottom = jnp.concatenate([m * C, Ib - m * C @ C], axis=1)
    return jnp.concatenate([top, bottom], axis=0)


def geometric_stiffness(robot, pose, statics: CableStatics) -> Float[Array, "6 6"]:
    """Lever-arm term ``-Σ hat(f_i) hat(r_i) - hat(W) hat(R c)`` (rotation block only)."""
    _, R = frame(pose)
    r = robot.attachments @ R.T
    Kr = -jnp.einsum("iab,ibc->ac", lie.hat(statics.force), lie.hat(r))
    Kr = Kr - lie.hat(robot.weight) @ lie.hat(R @ robot.com)
    return jnp.zeros((6, 6)).at[3:, 3:].set(Kr)


def cable_dsms(robot, pose, statics: CableStatics, omega, xi) -> Complex[Array, "m 3 3"]:
    """Base-frame DSM of every cable at its attachment (Yuan et al. 2015 eq. 27), N/m."""
    p, R = frame(pose)
    att = p + robot.attachments @ R.T
    return jax.vmap(cable_dynamic_stiffness, in_axes=(0, 0, 0, 0, 0, None, None, None))(
        span_starts(robot, att), att, statics.tension, robot.EA, robot.mass_per_length, robot.gravity, omega, xi)


def _dynamic_stiffness(robot, pose, statics, omega, xi):
    _, R = frame(pose)
    r = robot.attachments @ R.T
    K = cable_dsms(robot, pose, statics, omega, xi)
    A = jnp.concatenate([jnp.broadcast_to(jnp.eye(3), K.shape), -lie.hat(r)], axis=-1)  # (m, 3, 6)
    KM = jnp.einsum("iak,iab,ibl->kl", A, K, A)
    return KM + geometric_stiffness(robot, pose, statics)


_dynamic_stiffness_jit = eqx.filter_jit(_dynamic_stiffness)


def dynamic_stiffness(robot, pose, statics: CableStatics, omega, xi=0.0) -> Complex[Array, "6 6"]:
    """Robot dynamic stiffness ``K_M(ω)`` (Yuan et al. 2015 eqs 27-29 + lever-arm term), complex.

    **Arguments:** ``robot``; ``pose`` (6,); ``statics`` a :class:`CableStatics`;
    ``omega`` rad/s (>= 0); ``xi`` cable damping ratio (>= 0).

    **Returns:** (6, 6) complex; rows ``[f; m]`` (N, N·m), columns ``[δp; δθ]`` (m, rad).
    """
    omega, xi = _check_omega_xi(omega, xi)
    return _dynamic_stiffness_jit(robot, jnp.asarray(pose, jnp.float64), statics, omega, xi)


def dynamic_matrix(robot, pose, statics, omega, xi=0.0) -> Complex[Array, "6 6"]:
    """``-ω² M + K_M(ω)`` (the matrix inverted in Yuan et al. 2015 eq. 32)."""
    _check_robot(robot)
    omega, xi = _check_omega_xi(omega, xi)
    return _dynamic_matrix_jit(robot, jnp.asarray(pose, jnp.float64), statics, omega, xi)


@eqx.filter_jit
def _dynamic_matrix_jit(robot, pose, statics, omega, xi):
    return -(omega**2) * _mass_matrix(robot, pose) + _dynamic_stiffness(robot, pose, statics, omega, xi)


# --------------------------------------------------------------------------- FRF
@eqx.filter_jit
def _frf(robot, pose, statics, omegas, xis, wrench):
    M = _mass_matrix(robot, pose)

    def one(w, x):
        D = -(w**2) * M + _dynamic_stiffness(robot, pose, statics, w, x)
        return jnp.linalg.solve(D, wrench.astype(D.dtype))

    return jax.vmap(one)(omegas, xis)


def frf(robot, pose, statics: CableStatics, frequencies, xi=0.0, wrench=None) -> Complex[Array, "n 6"]:
    """Platform response ``X(ω) = [-ω² M + K_M(ω)]⁻¹ F`` on a frequency list (eq. 32).

    **Arguments:** ``frequencies`` (n,) Hz (>= 0); ``xi`` damping ratio, scalar or (n,)
    (e.g. Yuan et al.'s ``0.01 f_n / f``); ``wrench`` (6,) harmonic force/moment amplitude
    in the base frame (N, N·m), default a unit vertical force ``[0, 0, 1, 0, 0, 0]``.

    **Returns:** (n, 6) complex twist amplitudes ``[δp (m), δθ (rad)]`` per unit wrench.
    """
    _check_robot(robot)
    f = _require("frequencies", frequencies, 0.0, False, "finite and >= 0 Hz")
    f = jnp.atleast_1d(f)
    xi = jnp.broadcast_to(_require("xi", xi, 0.0, False, "finite and >= 0"), f.shape)
    wrench = jnp.array([0.0, 0, 1, 0, 0, 0]) if wrench is None else jnp.asarray(wrench, jnp.float64)
    return _frf(robot, jnp.asarray(pose, jnp.float64), statics, 2 * jnp.pi * f, xi, wrench)


def point_acceleration(pose, X, frequencies, point=None) -> Complex[Array, "n 3"]:
    """Acceleration of a platform point in the *platform* frame from an FRF ``X``.

    ``a = -ω² Rᵀ (δp + δθ × R b)`` with ``b`` the point in the platform frame (m,
    default the reference point). Per unit excitation: (m/s²)/N for a unit force.
    """
    _, R = frame(pose)
    b = jnp.zeros(3) if point is None else jnp.asarray(point, jnp.float64)
    w = 2 * jnp.pi * jnp.asarray(frequencies, jnp.float64)
    disp = X[:, :3] + jnp.cross(X[:, 3:], R @ b)
    return -(w**2)[:, None] * (disp @ R)


@eqx.filter_jit
def cable_response(robot, pose, statics, X, frequencies, xi=0.0, cable: int = 0, s: float = 0.25):
    """Acceleration of cable ``cable``'s point at chord fraction ``s`` (0 anchor, 1
    attachment) in its chord frame ``[e_u, e_v, e_w]`` (chord, in-plane normal, out of
    plane), from the platform FRF ``X`` (as in Yuan et al. 2015 Fig. 9). **Returns:** (n, 3)."""
    p, R = frame(pose)
    att = p + robot.attachments[cable] @ R.T
    r = R @ robot.attachments[cable]
    freqs = jnp.atleast_1d(jnp.asarray(frequencies, jnp.float64))
    xi = jnp.broadcast_to(jnp.asarray(xi, jnp.float64), freqs.shape)
    start = span_starts(robot, p + robot.attachments @ R.T)[cable]
    fr = cable_frame(start, att, robot.gravity)
    basis = jnp.stack([fr.e_u, fr.e_v, fr.e_w])

    def one(f, x, Xk):
        d = Xk[:3] + jnp.cross(Xk[3:], r)
        y = cable_point_response(start, att, statics.tension[cable], robot.EA[cable],
                                 robot.mass_per_length[cable], robot.gravity, 2 * jnp.pi * f, x, d, s)
        return -((2 * jnp.pi * f) ** 2) * (basis.astype(y.dtype) @ y)

    return jax.vmap(one)(freqs, xi, X)


# ---------------------------------------------------------- natural frequencies (W-W)
def _cable_Omegas_lambdas(robot, pose, statics, omega):
    p, R = frame(pose)
    att = p + robot.attachments @ R.T
    g = jnp.linalg.norm(robot.gravity)
    fr = jax.vmap(lambda a, b: cable_frame(a, b, robot.gravity))(span_starts(robot, att), att)
    _, lam2, _, _ = cable_parameters(fr.length, fr.cos_alpha, statics.tension, robot.EA, robot.mass_per_length, g)
    Om = omega * fr.length * jnp.sqrt(robot.mass_per_length / statics.tension)
    return Om, lam2


def mode_count(robot, pose, statics: CableStatics, omega) -> Array:
    """Wittrick-Williams count: number of natural frequencies of the undamped robot
    (platform + cables) strictly below ``omega`` (rad/s), with multiplicity."""
    omega = _require("omega", omega, 0.0, False, "finite and >= 0 (rad/s)")
    return _mode_count_jit(robot, jnp.asarray(pose, jnp.float64), statics, omega)


def _mode_count(robot, pose, statics, omega):
    L = jnp.linalg.cholesky(_mass_matrix(robot, pose))
    D = jnp.real(-(omega**2) * _mass_matrix(robot, pose) + _dynamic_stiffness(robot, pose, statics, omega, 0.0))
    D = 0.5 * (D + D.T)
    Li = jax.scipy.linalg.solve_triangular(L, jnp.eye(6), lower=True)
    ev = jnp.linalg.eigvalsh(Li @ D @ Li.T)
    Om, lam2 = _cable_Omegas_lambdas(robot, pose, statics, omega)
    return jnp.sum(ev < 0) + jnp.sum(jax.vmap(clamped_mode_count)(Om, lam2))


_mode_count_jit = eqx.filter_jit(_mode_count)


def _bisect_mode(robot, pose, statics, k, f_lo, f_hi, iters: int):
    """Smallest ``f`` in ``[f_lo, f_hi]`` (Hz) with ``J(2πf) >= k``, to ``(f_hi-f_lo)/2^iters``."""

    def body(_, ab):
        a, b = ab
        m = 0.5 * (a + b)
        up = _mode_count(robot, pose, statics, 2 * jnp.pi * m) >= k
        return jnp.where(up, a, m), jnp.where(up, m, b)

    a, b = jax.lax.fori_loop(0, iters, body, (f_lo, f_hi))
    return 0.5 * (a + b)


@eqx.filter_jit
def _bisect_modes(robot, pose, statics, ks, f_lo, f_hi, iters):
    return jax.vmap(lambda k: _bisect_mode(robot, pose, statics, k, f_lo, f_hi, iters))(ks)


def _iterations(span, tol):
    return max(1, math.ceil(math.log2(max(span, tol) / tol)) + 1)


_CHUNK = 16  # modes bisected together; one compilation serves every call


def natural_frequencies(robot, pose, statics: CableStatics, fmax, fmin=0.0, *, tol=1e-6,
                        max_modes: int = 200) -> Float[Array, " k"]:
    """All natural frequencies (Hz) of the robot with its cables in ``[fmin, fmax)``.

    Exact roots of ``det(-ω² M + K_M(ω)) = 0`` (undamped: ``ξ`` shifts them little)
    found by Wittrick-Williams counting and bisection; each is within ``tol`` Hz of the
    model's root (the resolution; default 1e-6 Hz), repeated roots appear repeatedly.
    At an unstable pose (``K_M(0)`` with negative eigenvalues) ``J(0) > 0``: those modes
    have no real frequency and are not listed. Poles of ``K_M`` (clamped-cable
    frequencies) are not roots; ``J_0`` accounts for them.

    **Arguments:** ``robot``, ``pose`` (6,), ``statics`` (:class:`CableStatics`);
    ``fmax`` > ``fmin`` >= 0 Hz; ``tol`` resolution Hz; ``max_modes`` cap on the count.

    **Returns:** (k,) ascending natural frequencies, Hz.
    """
    _check_robot(robot)
    fmin = float(_require("fmin", fmin, 0.0, False, "finite and >= 0 Hz"))
    fmax = float(_require("fmax", fmax, fmin, True, f"finite and > fmin = {fmin} Hz"))
    n_lo = int(mode_count(robot, pose, statics, 2 * np.pi * fmin))
    n_hi = int(mode_count(robot, pose, statics, 2 * np.pi * fmax))
    n = min(n_hi, n_lo + max_modes) - n_lo
    if n <= 0:
        return jnp.zeros(0)
    ks = n_lo + 1 + np.minimum(np.arange(-(-n // _CHUNK) * _CHUNK), n - 1)
    iters = jnp.asarray(_iterations(fmax - fmin, tol))
    pose = jnp.asarray(pose, jnp.float64)
    f = [_bisect_modes(robot, pose, statics, jnp.asarray(c), jnp.asarray(fmin), jnp.asarray(fmax), iters)
         for c in ks.reshape(-1, _CHUNK)]
    return jnp.concatenate(f)[:n]


def first_natural_frequency(robot, pose, statics: CableStatics, fmax=50.0, iters: int = 40) -> Float[Array, ""]:
    """Lowest natural frequency (Hz) below ``fmax`` (``nan`` if none), jit/vmap-friendly;
    resolution ``fmax / 2^iters`` Hz."""
    f = _bisect_mode(robot, pose, statics, 1, jnp.asarray(0.0), jnp.asarray(fmax, jnp.float64), iters)
    return jnp.where(_mode_count(robot, pose, statics, 2 * jnp.pi * fmax) >= 1, f, jnp.nan)


class PlatformModes(eqx.Module):
    """Platform side of the coupled modes at natural frequencies ``frequencies`` (Hz):
    ``shapes`` (k, 6) unit platform twists (null vectors of ``-ω² M + K_M(ω)``) and
    ``participation`` (k,) the platform's share of the modal kinetic energy, in (0, 1]."""

    frequencies: Float[Array, " k"]
    shapes: Float[Array, "k 6"]
    participation: Float[Array, " k"]


def platform_modes(robot, pose, statics: CableStatics, frequencies) -> PlatformModes:
    """Mode shapes and platform participation of the coupled modes at ``frequencies``.

    For a dynamic stiffness matrix of a conservative system, ``-∂D/∂(ω²)`` is the full
    modal mass form (platform + cable inertia condensed into ``K_M``), so the platform
    share of the kinetic energy of mode ``φ`` is ``φᵀMφ / (-φᵀ ∂D/∂(ω²) φ)``; the
    derivative is taken by autodiff. Modes with participation near 0 are cable modes
    that the platform barely feels (invisible in a platform FRF, e.g. Yuan et al. 2015 Fig. 10);
    the table-4-like "robot" frequencies are those with a large participation.
    """
    f = jnp.atleast_1d(_require("frequencies", frequencies, 0.0, True, "finite and > 0 Hz"))
    n = f.shape[0]
    if n == 0:
        return PlatformModes(f, jnp.zeros((0, 6)), jnp.zeros(0))
    pad = jnp.concatenate([f, jnp.full(((-n) % _CHUNK,), f[-1])])
    shapes, part = _platform_modes(robot, jnp.asarray(pose, jnp.float64), statics, pad)
    return PlatformModes(f, shapes[:n], part[:n])


@eqx.filter_jit
def _platform_modes(robot, pose, statics, frequencies):
    M = _mass_matrix(robot, pose)

    def D(w):
        Dw = -(w**2) * M + jnp.real(_dynamic_stiffness(robot, pose, statics, w, 0.0))
        return 0.5 * (Dw + Dw.T)

    def one(f):
        w = 2 * jnp.pi * f
        lam, V = jnp.linalg.eigh(D(w))
        phi = V[:, jnp.argmin(jnp.abs(lam))]
        dD = jax.jacfwd(D)(w) / (2 * w)
        total = -phi @ dD @ phi
        return phi, (phi @ M @ phi) / total

    return jax.vmap(one)(frequencies)


# ---------------------------------------------------------- classical modal analyses
class Modes(eqx.Module):
    """Solution of ``K φ = ω² M φ``: ``frequencies`` (6,) Hz ascending (negative = unstable,
    ``-sqrt(|λ|)/2π``) and mass-normalized ``shapes`` (6, 6), one mode per column."""

    frequencies: Float[Array, " 6"]
    shapes: Float[Array, "6 6"]


def modal_analysis(K: Float[Array, "6 6"], M: Float[Array, "6 6"]) -> Modes:
    """Generalized symmetric eigenproblem ``K φ = ω² M φ`` (K symmetrized), Hz."""
    K = 0.5 * (K + K.T)
    L = jnp.linalg.cholesky(M)
    Li = jax.scipy.linalg.solve_triangular(L, jnp.eye(K.shape[0]), lower=True)
    lam, V = jnp.linalg.eigh(Li @ K @ Li.T)
    f = jnp.sign(lam) * jnp.sqrt(jnp.abs(lam)) / (2 * jnp.pi)
    return Modes(f, Li.T @ V)


def spring_modes(robot, pose, tensions) -> Modes:
    """Massless spring-cable modes (Yuan et al. 2015 Table 4 "[28]"): ``K`` of
    :func:`cstiffjax.stiffness.matrix.stiffness` at the given tensions, with ``M``."""
    return modal_analysis(stiffness(robot, pose, tensions).K, _mass_matrix(robot, pose))


def sagging_modes(robot, pose, l0) -> Modes:
    """Static sagging-cable modes (Yuan et al. 2015 Table 4 "[19]"): catenary tangent stiffness
    ``-∂W/∂x`` (autodiff through the elastic catenary) with ``M``; cable inertia ignored."""
    from cstiffjax.stiffness.matrix import stiffness_from_lengths

    return modal_analysis(stiffness_from_lengths(robot, pose, l0, law=CableLaw.catenary), _mass_matrix(robot, pose))


# ------------------------------------------------------------------ workspace sweep
@eqx.filter_jit
def first_frequency_map(robot, poses: Float[Array, "n 6"], fmax=20.0, iters: int = 30) -> Float[Array, " n"]:
    """First natural frequency (Hz) at each pose (Yuan et al. 2015 Fig. 13), vmapped.

    Tensions: minimum-norm inverse statics under the platform weight; cable state:
    straight cables (:func:`cable_statics_from_tensions`). Poses where a tension is not
    positive give ``nan``. Resolution ``fmax / 2^iters`` Hz.
    """

    def one(pose):
        t = inverse_statics(robot, pose, throw=False).tensions
        ok = jnp.all(t > 0)
        st = CableStatics(jnp.where(ok, t, 1.0), jnp.where(ok, t, 1.0)[:, None] * _unit_chords(robot, pose))
        return jnp.where(ok, first_natural_frequency(robot, pose, st, fmax, iters), jnp.nan)

    return jax.vmap(one)(poses)


def _unit_chords(robot, pose):
    p, R = frame(pose)
    return robot_paths(robot, p + robot.attachments @ R.T).direction
