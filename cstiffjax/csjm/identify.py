"""Stiffness identification, pose prediction and symmetry audit of a CSJM (Yang et al. 2019 §III-IV).

Frames (see :mod:`cstiffjax.csjm.model`): ``frame="body"`` is Yang et al.'s convention: displacements
``Δζ = log(R0ᵀ R)`` (``R = R0 exp(hat(Δζ))``, eq. 62) and loads ``τ_A`` in the platform frame
{A} *at each pose* (the left trivialization of eq. 59: ``ΔF = Δτ`` componentwise), ``τ_A``
being the load the cables balance, external + gravity (§III.B.2). ``frame="base"`` is the
package convention: ``Δθ = log(R R0ᵀ)`` and loads in the base frame.

- :func:`identify`: ``K_D ≈ Ψ Ω⁺`` (eq. 49), ``K = K_D + K_L`` (eq. 50) with the correct
  ``K_L = -½ hat(τ0)`` (body; the printed eq. 48b has ``-hat(τ0)``).
- :func:`predict_rotation`: ``R_est = R0 exp(hat(K_D⁻¹ Δτ))`` (eqs 61-62). Pass the *raw*
  ``K_D``: ``Δτ`` of eq. (59) is the change of the trivialized components, whose first-order
  change is ``K_D Δζ``, not ``K Δζ`` (eq. 60 mixes the two). Table 4 Col. C was computed this
  way: it reproduces from Table 3's ``K_D`` (not ``K_meas``) to print precision.
- :func:`estimation_error`: ``E_θ = ‖log(R_actᵀ R_est)‖`` (eqs 63-65).
- :func:`audit_asymmetry` (CSJM side): the antisymmetric part a conservative module
  must have under its load versus the identified one; the excess is non-conservative.

Seed 000 Tables 3-4 (``tests/test_csjm.py::TestSeed000Tables``)
---------------------------------------------------------------
Reproduces: ``K_L = -hat(ᴬτ0)`` and ``K_meas = K_D + K_L`` to print precision (so the table
uses the printed, wrong, coefficient); Table 4 Col. C from ``R0``, ``K_D`` and Col. A with
``R_est = R0 exp(hat(K_D⁻¹ Δτ))`` to 1.3e-3 per entry (3-decimal rounding), but only after
fixing a sign typo in ``R0``: printed ``R0[2,1] = +0.300`` makes ``R0`` non-orthogonal
(``max|R0ᵀR0 - I| = 0.57``); ``-0.300`` gives 3.6e-4. Using ``K_meas`` instead of ``K_D``
misses Col. C by 0.018-0.028 rad. Does not reproduce: Col. D. ``E_θ`` from Cols B and C is
(0.054, 0.052, 0.039, 0.040, 0.046) rad against the printed (0.016, 0.034, 0.023, 0.058,
0.046); only case 5 agrees, and 3-decimal rounding moves ``E_θ`` by < 3e-3. Table 3 itself
(``K_D`` from 85 measurement sets, Fig. 5) cannot be recomputed: the data are not printed.

Audit of Table 3 (``audit_asymmetry(K_D, ᴬτ0)``): a conservative module needs
``vee(K_D - K_Dᵀ) = ᴬτ0 = (-0.06, -3.08, 1.07)`` N·m; Table 3's ``K_D`` has
``(-0.35, 6.16, -3.28)``: opposite in direction (best multiple -2.11 of ``ᴬτ0``), excess
``(-0.29, 9.24, -4.35)``, ``|excess| = 10.2`` N·m/rad = 0.33 of the largest eigen-stiffness
of sym(K_D) (30.6).
Read at face value this is a large non-conservative effect (the paper's §IV.D names
friction in the holes and housings); a sign convention of ``ᴬτ0`` or ``Δζ`` different from
the printed equations would change the conservative prediction to ``-ᴬτ0``, but still
leaves an excess of ``|(-0.41, 3.08, -2.21)| = 3.8`` N·m/rad. Either way the paper's printed
``K_meas`` (coefficient 1) is *less* symmetric than ``K_D`` (``|vee(K - Kᵀ)|`` 13.5 vs 7.0).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from cstiffjax.core import lie
from cstiffjax.csjm.model import check_frame, connection_term, conservative_antisymmetry, covariant, gravity_moment


def _is_concrete(*xs) -> bool:
    return not any(isinstance(x, jax.core.Tracer) for x in xs)


def _check_shape(name, x, shape):
    if x.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {x.shape}")


class Identification(eqx.Module):
    """Identified CSJM stiffness (Yang et al. 2019 eqs 47-50), N·m/rad, in the coordinates of ``frame``.

    ``K_D`` raw ``Ψ Ω⁺``; ``K_L`` connection term ``-½ hat(s)``; ``K = K_D + K_L`` (covariant);
    ``load`` the load at the reference pose, N·m; ``K_D_std`` standard errors of ``K_D``
    from the fit residuals (``nan`` with exactly 3 measurements); ``residual_rms`` N·m;
    ``num_measurements`` and ``frame`` (static).
    """

    K_D: Float[Array, "3 3"]
    K_L: Float[Array, "3 3"]
    K: Float[Array, "3 3"]
    load: Float[Array, "3"]
    K_D_std: Float[Array, "3 3"]
    residual_rms: Float[Array, ""]
    num_measurements: int = eqx.field(static=True)
    frame: str = eqx.field(static=True, default="body")


def identify(delta_tau: Float[ArrayLike, "N 3"], delta_zeta: Float[ArrayLike, "N 3"],
             load: Float[ArrayLike, "3"], frame: str = "body") -> Identification:
    """Stiffness from ``N >= 3`` measured (load increment, displacement) pairs (eqs 46-50).

    **Arguments:** ``delta_tau`` ``(N, 3)`` load increments ``Δτ``, N·m; ``delta_zeta``
    ``(N, 3)`` displacements ``Δζ``, rad; ``load`` ``(3,)`` the load ``τ0`` at the reference
    pose (what the elastic elements balance), N·m; ``frame``: ``"body"`` (Yang et al. 2019) or
    ``"base"`` (module docstring).

    **Returns:** an :class:`Identification` (``K_D = Ψ Ω⁺`` with ``Ψ = [Δτ_k]``, ``Ω = [Δζ_k]``).

    **Raises:** ``ValueError`` for wrong shapes, fewer than 3 measurements or displacements
    that do not span three directions.
    """
    check_frame(frame)
    dt = jnp.asarray(delta_tau, dtype=jnp.float64)
    dz = jnp.asarray(delta_zeta, dtype=jnp.float64)
    load = jnp.asarray(load, dtype=jnp.float64)
    if dt.ndim != 2 or dt.shape[1] != 3:
        raise ValueError(f"delta_tau must have shape (N, 3), got {dt.shape}")
    if dz.shape != dt.shape:
        raise ValueError(f"delta_zeta must have the shape of delta_tau {dt.shape}, got {dz.shape}")
    _check_shape("load", load, (3,))
    n = dt.shape[0]
    if n < 3:
        raise ValueError(f"got {n} measurement(s); at least 3 are needed (Yang et al. 2019 §III.B.3)")
    if _is_concrete(dz):
        sv = np.linalg.svd(np.asarray(dz), compute_uv=False)
        if not np.all(np.isfinite(sv)) or sv[-1] <= 1e-10 * max(sv[0], 1e-300):
            raise ValueError(f"delta_zeta does not span three directions (singular values {sv}); "
                             f"K_D = Ψ Ω⁺ needs displacements about three independent axes")
    return _identify(dt, dz, load, frame)


@eqx.filter_jit
def _identify(dt, dz, load, frame):
    n = dt.shape[0]
    G_inv = jnp.linalg.inv(dz.T @ dz)
    K_D = dt.T @ dz @ G_inv  # Ψ Ω⁺ with Ψ = dtᵀ, Ω = dzᵀ (full row rank)
    res = dt - dz @ K_D.T
    if n > 3:
        s2 = jnp.sum(res**2, axis=0) / (n - 3)
        std = jnp.sqrt(s2[:, None] * jnp.diag(G_inv)[None, :])
    else:
        std = jnp.full((3, 3), jnp.nan)
    K_L = connection_term(load, frame)
    return Identification(K_D, K_L, K_D + K_L, load, std, jnp.sqrt(jnp.mean(res**2)), n, frame)


def displacements(R0, rotations: Float[ArrayLike, "N 3 3"], frame: str = "body") -> Float[Array, "N 3"]:
    """``Δζ_k = log(R0ᵀ R_k)`` (body) or ``log(R_k R0ᵀ)`` (base), rad, for rotation matrices ``(N, 3, 3)``."""
    return _displacements(jnp.asarray(R0, dtype=jnp.float64), jnp.asarray(rotations, dtype=jnp.float64),
                          check_frame(frame))


@eqx.filter_jit
def _displacements(R0, Rs, frame):
    if frame == "body":
        return jax.vmap(lambda R: lie.log(R0.T @ R))(Rs)
    return jax.vmap(lambda R: lie.log(R @ R0.T))(Rs)


_exp_batch = jax.jit(jax.vmap(lie.exp))


def identify_from_rotations(R0, load0, rotations, loads, frame: str = "body", *, atol: float = 1e-6) -> Identification:
    """:func:`identify` from a reference ``(R0, load0)`` and ``N`` measured poses and loads.

    ``rotations`` ``(N, 3, 3)`` or rotation vectors ``(N, 3)``; ``loads`` ``(N, 3)`` N·m, each in
    the platform frame at its own pose (``"body"``, eq. 59) or in the base frame (``"base"``).
    """
    R0 = jnp.asarray(lie.as_rotation(R0, atol) if _is_concrete(R0) else R0)
    Rs = jnp.asarray(rotations, dtype=jnp.float64)
    if Rs.ndim == 2 and Rs.shape[1] == 3:
        Rs = _exp_batch(Rs)
    if Rs.ndim != 3 or Rs.shape[1:] != (3, 3):
        raise ValueError(f"rotations must have shape (N, 3, 3) or (N, 3), got {jnp.shape(rotations)}")
    loads = jnp.asarray(loads, dtype=jnp.float64)
    _check_shape("loads", loads, (Rs.shape[0], 3))
    load0 = jnp.asarray(load0, dtype=jnp.float64)
    _check_shape("load0", load0, (3,))
    return identify(loads - load0, displacements(R0, Rs, frame), load0, frame)


def platform_loads(robot, recordings, *, include_gravity: bool = True) -> Float[Array, "N 3"]:
    """Load on the platform about O in the platform frame, ``ᴬτ_E + ᴬτ_G`` (Yang et al. 2019 §III.B.2), N·m.

    ``ᴬτ_E`` is the recordings' measured moment (columns ``tx ty tz``, formats.md §2) and
    ``ᴬτ_G = Rᵀ (R com) × (mass g)`` the weight of the platform (eq. 56).
    """
    if recordings.kind != "csjm":
        raise ValueError(f"recordings of kind {recordings.kind!r}; a CSJM identification needs kind 'csjm'")
    return _platform_loads(robot, recordings.pose[:, 3:], recordings.moment, include_gravity)


@eqx.filter_jit
def _platform_loads(robot, rotvecs, moment, include_gravity):
    if not include_gravity:
        return moment
    return moment + jax.vmap(lambda r: lie.exp(r).T @ gravity_moment(robot, lie.exp(r)))(rotvecs)


def identify_from_recordings(robot, recordings, reference: int = 0, *,
                             include_gravity: bool = True) -> Identification:
    """Seed 000 identification from CSJM recordings: row ``reference`` is ``(R0, ᴬτ0)``, the
    other rows the measurements (platform frame, :func:`platform_loads`)."""
    n = recordings.pose.shape[0]
    if not -n <= reference < n:
        raise ValueError(f"reference={reference} is not a row of the {n} recordings (allowed 0..{n - 1})")
    reference %= n
    tau = platform_loads(robot, recordings, include_gravity=include_gravity)
    Rs = _exp_batch(recordings.pose[:, 3:])
    keep = np.array([i for i in range(n) if i != reference], dtype=int)
    return identify_from_rotations(Rs[reference], tau[reference], Rs[keep], tau[keep], "body")


def predict_rotation(R0, K_D: Float[ArrayLike, "3 3"], delta_tau: Float[ArrayLike, "3"],
                     frame: str = "body", *, atol: float = 1e-6) -> Float[Array, "3 3"]:
    """Pose under a load increment (Yang et al. 2019 eqs 61-62): ``R0 exp(hat(K_D⁻¹ Δτ))`` (body) or
    ``exp(hat(K_D⁻¹ Δτ)) R0`` (base).

    **Arguments:** ``R0`` rotation matrix (checked with :func:`cstiffjax.core.lie.as_rotation` to
    ``atol`` when concrete); ``K_D`` the raw stiffness in the coordinates of ``frame``
    (N·m/rad, see module docstring); ``delta_tau`` ``(3,)`` load increment, N·m, platform
    frame (``"body"``) or base frame (``"base"``).

    **Returns:** the estimated rotation matrix ``R_est``.
    """
    check_frame(frame)
    if _is_concrete(R0):
        R0 = lie.as_rotation(R0, atol)
    R0 = jnp.asarray(R0, dtype=jnp.float64)
    K_D = jnp.asarray(K_D, dtype=jnp.float64)
    dtau = jnp.asarray(delta_tau, dtype=jnp.float64)
    _check_shape("K_D", K_D, (3, 3))
    _check_shape("delta_tau", dtau, (3,))
    if _is_concrete(K_D):
        cond = np.linalg.cond(np.asarray(K_D))
        if not np.isfinite(cond) or cond > 1e12:
            raise ValueError(f"K_D is singular (condition number {cond:.3g}); cannot solve K_D Δζ = Δτ")
    step = lie.exp(jnp.linalg.solve(K_D, dtau))
    return R0 @ step if frame == "body" else step @ R0


def estimation_error(R_act: Float[ArrayLike, "3 3"], R_est: Float[ArrayLike, "3 3"]) -> Float[Array, ""]:
    """``E_θ = ‖log(R_actᵀ R_est)‖``, rad (Yang et al. 2019 eqs 63-65, :func:`cstiffjax.core.lie.rotation_distance`)."""
    return lie.rotation_distance(R_act, R_est)


class AsymmetryAudit(eqx.Module):
    """Antisymmetric part of an identified stiffness against what a conservative module needs.

    All vectors are ``vee`` of antisymmetric parts (``hat(v) = K - Kᵀ``), N·m/rad:
    ``measured`` of ``K``; ``conservative`` = ``±load`` (:func:`cstiffjax.csjm.model.conservative_antisymmetry`);
    ``excess = measured - conservative``, the non-conservative part (friction, hysteresis,
    drift; or a frame/sign convention of the data different from the one declared);
    ``excess_std`` its standard error (``nan`` when no ``K_std``); ``multiple`` the
    least-squares ``c`` in ``measured ≈ c · conservative`` (1 if conservative);
    ``relative_excess`` ``|excess|`` over the spectral norm of sym(K); ``K_covariant``
    ``K - ½ hat(conservative)``, with ``K_covariant - K_covariantᵀ = hat(excess)``;
    ``K_printed`` the paper's ``K_D - hat(τ)`` (eq. 48b coefficient), for comparison.
    """

    measured: Float[Array, "3"]
    conservative: Float[Array, "3"]
    excess: Float[Array, "3"]
    excess_std: Float[Array, "3"]
    multiple: Float[Array, ""]
    relative_excess: Float[Array, ""]
    K_covariant: Float[Array, "3 3"]
    K_printed: Float[Array, "3 3"]


def audit_asymmetry(K_D: Float[ArrayLike, "3 3"], load: Float[ArrayLike, "3"], frame: str = "body",
                    K_std=None) -> AsymmetryAudit:
    """Audit the antisymmetric part of an identified raw stiffness ``K_D`` (CSJM side).

    **Arguments:** ``K_D`` raw stiffness identified at the load ``load`` (N·m, the load the
    elastic elements balance, in the coordinates of ``frame``); ``K_std`` optional
    standard errors of ``K_D`` (e.g. :attr:`Identification.K_D_std`).

    **Returns:** an :class:`AsymmetryAudit`.
    """
    K = jnp.asarray(K_D, dtype=jnp.float64)
    _check_shape("K_D", K, (3, 3))
    load = jnp.asarray(load, dtype=jnp.float64)
    _check_shape("load", load, (3,))
    check_frame(frame)
    S = jnp.full((3, 3), jnp.nan) if K_std is None else jnp.asarray(K_std, dtype=jnp.float64)
    _check_shape("K_std", S, (3, 3))
    return _audit(K, load, S, frame)


@eqx.filter_jit
def _audit(K, load, S, frame):
    measured = lie.vee(K - K.T)
    cons = conservative_antisymmetry(load, frame)
    excess = measured - cons
    V = S**2 + (S**2).T
    ex_std = jnp.sqrt(jnp.array([V[2, 1], V[0, 2], V[1, 0]]))
    c2 = jnp.sum(cons**2)
    multiple = jnp.where(c2 > 0, jnp.sum(measured * cons) / jnp.where(c2 > 0, c2, 1.0), jnp.nan)
    scale = jnp.linalg.norm(0.5 * (K + K.T), ord=2)
    return AsymmetryAudit(measured, cons, excess, ex_std, multiple, jnp.linalg.norm(excess) / scale,
                          covariant(K, load, frame), K + connection_term(load, frame, 1.0))
