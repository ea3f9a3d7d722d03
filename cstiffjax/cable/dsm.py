"""Dynamic stiffness matrix (DSM) of one inclined, sagging, damped cable.

Seed 003 (``003_3d570275fddb08e8.txt``) Section 2.2, eqs (12)-(20), after Starossek
(1991) and Irvine's linear theory of a shallow cable. One end of the cable (the
*anchor*) is fixed; the other (the *attachment*) moves harmonically,
``δ(t) = Re(δ e^{iωt})``. The DSM ``K(ω)`` gives the force that must be applied to the
moving end, ``f = K(ω) δ`` (3x3 complex, N/m).

Cable frame
-----------
``e_u``: unit chord from anchor to attachment. ``e_v``: unit normal to the chord in the
vertical plane of the cable, pointing to the sag side (towards gravity). ``e_w = e_u ×
e_v``: out of the cable plane. In this frame (seed eq. 20)::

    K = [[k_a, k_b, 0], [k_b, k_c, 0], [0, 0, k_w]]

Derivation (re-done here; it fixes the paper's typos)
------------------------------------------------------
Static profile along the chord: ``τ y'' = -ρ g cos α`` (sag ``y`` towards ``e_v``,
``τ`` the chord-parallel tension). Small harmonic motion, longitudinal inertia neglected
(the dynamic tension ``h`` is uniform), transverse viscous damping ``c``::

    τ v'' + ρ ω_c² v = h ε / l,    h L_e / EA' = u_l + ∫ y' v' dx,   ω_c² = ω²(1 - 2iξ)

with ``v(0) = 0, v(l) = v_l``. Solving and taking the end forces gives, with
``Ω_c = ω_c l sqrt(ρ/τ)``, ``κ = tan(Ω_c/2)/(Ω_c/2)``, ``D = 1 + (λ²/Ω_c²)(κ - 1)``::

    k_a = (EA'/L_e) / D                                          (eq. 17)
    k_b = (EA'/L_e) (ε/2)(κ - 1) / D                             (eq. 18)
    k_c = (τ/l) [1/κ - (Ω_c²/4)(κ + (λ²/Ω_c²)(κ - 1)) / D]       (eq. 19)
        = (τ/l) Ω_c cot Ω_c + (ε²/4)(κ - 1)² k_a
    k_w = (τ/l) Ω_c cot Ω_c = τ (4 - κ²Ω_c²) / (4 κ l)           (K_yy below eq. 20)

    ε = ρ g l cos α / τ (= 8 d / l),  λ² = ε² EA' l / (τ L_e),  L_e = l (1 + ε²/8)

Corrections to the printed text of Yuan et al. 2015 (each checked by a test):

- ``κ = tan(Ω_c/2)/(Ω_c/2)``; the paper prints ``tan(α/2)/(α/2)`` (α is the inclination).
- ``ε = ρ g l_c cos α / τ``; the printed ``ε = ω l_c/Ω_c cos α`` is garbled.
- ``λ² = (ρ g l_c cos α / τ)² EA l_c / (τ L_e)``; the paper prints ``l_c`` for ``L_e``.
- eq. (19): the first term is ``EA ε² / (L_e λ² κ) = τ/(l κ)``; the paper has an extra 1/κ.
- eqs (13)-(16) rotate with the in-plane normal ``(-sin α, cos α)``. They give the right
  sign of ``k_b`` only if ``α`` is the inclination of the chord measured from the
  *moving* end towards the fixed end; with the cable frame of Section 3 (origin at the
  anchor ``B_i``, chord towards the platform) the ``k_b`` terms change sign. We avoid the
  ambiguity by rotating with explicit unit vectors (``e_v`` to the sag side) and check the
  sign against a lumped-mass chain (``tests/test_dynamics.py``).
- ``EA' = EA + τ`` instead of ``EA``: the compliance of a strained element per unit
  *strained* length is ``1/(EA + T)``. With this, a massless cable gives exactly the
  spring stiffness ``EA/l0`` of Cui et al. 2019 eq. (17) (Irvine's small-strain theory has
  ``EA``; the difference is ``τ/EA`` ~ 1e-4 for the prototype).

Limits: ``ω → 0`` gives Irvine's static stiffness ``k_a = (EA'/L_e)/(1 + λ²/12)``,
``k_b = 0``, ``k_c = k_w = τ/l`` (to first order in the sag; the exact catenary adds
``O(ε tan α)`` couplings from the variation of tension along an inclined span). A light
taut cable has poles of ``k_w`` at ``Ω = nπ``, i.e. ``f_n = n/(2l) sqrt(τ/ρ)``.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Complex, Float

from cstiffjax.core import config as _config  # noqa: F401

_SERIES = 1e-2  # |Ω| below which series expansions replace tan/cot (error ~ Ω^6 < 1e-12)


class CableFrame(eqx.Module):
    """Chord frame of one cable: ``e_u`` (anchor → attachment), ``e_v`` (in-plane normal
    to the sag side), ``e_w`` (out of plane); ``length`` chord m; ``cos_alpha`` cosine
    of the chord inclination to the horizontal (horizontal = normal to gravity)."""

    e_u: Float[Array, "3"]
    e_v: Float[Array, "3"]
    e_w: Float[Array, "3"]
    length: Float[Array, ""]
    cos_alpha: Float[Array, ""]


class DSMCoefficients(eqx.Module):
    """Chord-frame DSM coefficients (N/m, complex) and the cable parameters.

    ``Omega`` = ``Ω_c`` (complex, dimensionless), ``lambda2`` = ``λ²``, ``epsilon`` =
    ``ε``, ``tension`` = ``τ`` N, ``length`` = chord m.
    """

    k_a: Complex[Array, ""]
    k_b: Complex[Array, ""]
    k_c: Complex[Array, ""]
    k_w: Complex[Array, ""]
    Omega: Complex[Array, ""]
    lambda2: Float[Array, ""]
    epsilon: Float[Array, ""]
    tension: Float[Array, ""]
    length: Float[Array, ""]


def cable_frame(anchor: Float[Array, "3"], attachment: Float[Array, "3"], gravity: Float[Array, "3"]) -> CableFrame:
    """Chord frame of the cable from ``anchor`` to ``attachment`` (base frame, m).

    For a vertical chord (or zero gravity) the cable plane is undefined; ``e_v`` is then
    any normal to the chord (the sag coupling vanishes there: ``cos α = 0`` or ``g = 0``).
    """
    d = jnp.asarray(attachment, jnp.float64) - jnp.asarray(anchor, jnp.float64)
    length = jnp.linalg.norm(d)
    e_u = d / length
    g = jnp.asarray(gravity, jnp.float64)
    gn = jnp.linalg.norm(g)
    g_hat = g / jnp.where(gn > 0, gn, 1.0)
    perp = g_hat - jnp.dot(g_hat, e_u) * e_u
    pn = jnp.linalg.norm(perp)
    # fallback normal for vertical chords / no gravity
    axis = jnp.where(jnp.abs(e_u[0]) < 0.9, jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 1.0, 0.0]))
    alt = axis - jnp.dot(axis, e_u) * e_u
    ok = pn > 1e-9
    e_v = jnp.where(ok, perp / jnp.where(ok, pn, 1.0), alt / jnp.linalg.norm(alt))
    e_w = jnp.cross(e_u, e_v)
    cos_alpha = jnp.where(gn > 0, pn, 1.0)
    return CableFrame(e_u, e_v, e_w, length, cos_alpha)


# ------------------------------------------------------------------ special functions
def _kappa_minus_one_over_omega2(Om):
    """``q(Ω) = (κ - 1)/Ω²`` with ``κ = tan(Ω/2)/(Ω/2)``; series near 0 (complex-safe)."""
    small = jnp.abs(Om) < _SERIES
    Os = jnp.where(small, 1.0, Om)
    direct = (jnp.tan(Os / 2) / (Os / 2) - 1.0) / Os**2
    O2 = Om * Om
    series = 1.0 / 12 + O2 / 120 + 17 * O2 * O2 / 20160
    return jnp.where(small, series, direct)


def _omega_cot_omega(Om):
    """``Ω cot Ω``, equal to 1 at ``Ω = 0`` (complex-safe)."""
    small = jnp.abs(Om) < _SERIES
    Os = jnp.where(small, 1.0, Om)
    direct = Os / jnp.tan(Os)
    O2 = Om * Om
    series = 1.0 - O2 / 3 - O2 * O2 / 45
    return jnp.where(small, series, direct)


def cable_parameters(length, cos_alpha, tension, EA, mass_per_length, g):
    """``(ε, λ², L_e, EA')`` of Yuan et al. 2015 Section 2.2 (corrected, see module docstring).

    **Arguments:** chord ``length`` m, ``cos_alpha``, chord-parallel ``tension`` τ N,
    ``EA`` N, ``mass_per_length`` kg/m, ``g`` = |gravity| m/s².
    """
    eps = mass_per_length * g * length * cos_alpha / tension
    L_e = length * (1.0 + eps**2 / 8)
    EAp = EA + tension
    lam2 = eps**2 * EAp * length / (tension * L_e)
    return eps, lam2, L_e, EAp


def dsm_coefficients(length, cos_alpha, tension, EA, mass_per_length, g, omega, xi) -> DSMCoefficients:
    """Chord-frame DSM coefficients ``k_a, k_b, k_c, k_w`` (Yuan et al. 2015 eqs 17-19, corrected).

    **Arguments:** ``length`` chord m; ``cos_alpha`` cosine of the inclination;
    ``tension`` chord-parallel static tension τ N (> 0); ``EA`` N; ``mass_per_length``
    ρ kg/m; ``g`` gravity magnitude m/s²; ``omega`` circular frequency rad/s (≥ 0);
    ``xi`` damping ratio ``c/(2ρω)`` (≥ 0).

    **Returns:** :class:`DSMCoefficients` (complex N/m).
    """
    eps, lam2, L_e, EAp = cable_parameters(length, cos_alpha, tension, EA, mass_per_length, g)
    Om = omega * length * jnp.sqrt(mass_per_length / tension) * jnp.sqrt(1.0 - 2j * xi)
    q = _kappa_minus_one_over_omega2(Om)  # (κ-1)/Ω²
    km1 = q * Om * Om  # κ - 1
    D = 1.0 + lam2 * q
    k_a = (EAp / L_e) / D
    k_b = k_a * (eps / 2) * km1
    ococ = _omega_cot_omega(Om)
    k_w = (tension / length) * ococ
    k_c = k_w + (eps**2 / 4) * km1 * km1 * k_a
    return DSMCoefficients(k_a, k_b, k_c, k_w, Om, lam2, eps, jnp.asarray(tension, jnp.float64),
                           jnp.asarray(length, jnp.float64))


def cable_dynamic_stiffness(
    anchor: Float[Array, "3"], attachment: Float[Array, "3"], tension, EA, mass_per_length,
    gravity: Float[Array, "3"], omega, xi,
) -> Complex[Array, "3 3"]:
    """Base-frame DSM of one cable at its moving end (Yuan et al. 2015 eqs 20 and 27).

    ``K = R K_local Rᵀ`` with ``R = [e_u e_v e_w]`` (see module docstring).

    **Arguments:** ``anchor`` (fixed end), ``attachment`` (moving end), base frame m;
    ``tension`` chord-parallel static tension N; ``EA`` N; ``mass_per_length`` kg/m;
    ``gravity`` (3,) m/s²; ``omega`` rad/s; ``xi`` damping ratio.

    **Returns:** (3, 3) complex, N/m: force to apply at the attachment per displacement.
    """
    fr = cable_frame(anchor, attachment, gravity)
    c = dsm_coefficients(fr.length, fr.cos_alpha, tension, EA, mass_per_length,
                         jnp.linalg.norm(jnp.asarray(gravity, jnp.float64)), omega, xi)
    uu = jnp.outer(fr.e_u, fr.e_u)
    vv = jnp.outer(fr.e_v, fr.e_v)
    ww = jnp.outer(fr.e_w, fr.e_w)
    uv = jnp.outer(fr.e_u, fr.e_v)
    return c.k_a * uu + c.k_b * (uv + uv.T) + c.k_c * vv + c.k_w * ww


def _sym_shape(Om, s):
    """``(1 - cos Ωs - tan(Ω/2) sin Ωs)/Ω²`` (the particular in-plane shape), series near 0."""
    small = jnp.abs(Om) < 1e-3
    Os = jnp.where(small, 1.0, Om)
    direct = (1.0 - jnp.cos(Os * s) - jnp.tan(Os / 2) * jnp.sin(Os * s)) / Os**2
    series = (s * s - s) / 2 + Om * Om * (-(s**4) / 24 - s / 24 + s**3 / 12)
    return jnp.where(small, series, direct)


def _sin_ratio(Om, s):
    """``sin(Ωs)/sin(Ω)``, equal to ``s`` at ``Ω = 0``."""
    small = jnp.abs(Om) < 1e-3
    Os = jnp.where(small, 1.0, Om)
    return jnp.where(small, s * (1 + Om * Om * (1 - s * s) / 6), jnp.sin(Os * s) / jnp.sin(Os))


def cable_point_response(
    anchor, attachment, tension, EA, mass_per_length, gravity, omega, xi,
    end_displacement: Complex[Array, "3"], s,
) -> Complex[Array, "3"]:
    """Complex displacement of the cable point at chord fraction ``s`` (0 = anchor,
    1 = attachment) when the attachment moves by ``end_displacement`` (base frame, m).

    From the same solution as the DSM: in-plane
    ``v(s) = (h ε l / τ) S(Ω, s) + v_l sin(Ωs)/sin Ω`` with ``h = k_a u_l + k_b v_l``,
    out of plane ``w(s) = w_l sin(Ωs)/sin Ω``; along the chord the quasi-static
    ``u(s) = s u_l`` (longitudinal inertia is neglected by the theory).

    **Returns:** (3,) complex displacement in the base frame, m.
    """
    fr = cable_frame(anchor, attachment, gravity)
    c = dsm_coefficients(fr.length, fr.cos_alpha, tension, EA, mass_per_length,
                         jnp.linalg.norm(jnp.asarray(gravity, jnp.float64)), omega, xi)
    u_l = jnp.dot(fr.e_u, end_displacement)
    v_l = jnp.dot(fr.e_v, end_displacement)
    w_l = jnp.dot(fr.e_w, end_displacement)
    h = c.k_a * u_l + c.k_b * v_l
    v = h * c.epsilon * fr.length / tension * _sym_shape(c.Omega, s) + v_l * _sin_ratio(c.Omega, s)
    w = w_l * _sin_ratio(c.Omega, s)
    return s * u_l * fr.e_u + v * fr.e_v + w * fr.e_w


# ------------------------------------------------------------- clamped cable frequencies
def _symmetric_function(Om, lambda2):
    """``Ω²/λ² + κ - 1`` (+inf when λ² = 0): its roots are the symmetric in-plane modes."""
    Os = jnp.where(Om > 0, Om, 1.0)
    ratio = jnp.where(lambda2 > 0, Os**2 / jnp.where(lambda2 > 0, lambda2, 1.0), jnp.inf)
    return ratio + jnp.tan(Os / 2) / (Os / 2) - 1


def clamped_mode_count(Omega: Float[Array, ""], lambda2: Float[Array, ""]) -> Array:
    """Number of natural frequencies of the cable with *both ends fixed* below ``Ω``
    (undamped), counted with multiplicity: out-of-plane ``Ω = nπ``, in-plane
    antisymmetric ``Ω = 2nπ`` and in-plane symmetric roots of
    ``1 + (λ²/Ω²)(κ - 1) = 0`` (Irvine), of which there is exactly one in each interval
    ``((2n-1)π, (2n+1)π)`` because ``Ω²/λ² + κ - 1`` increases from -∞ to +∞ there.

    This is the ``J_0`` term of the Wittrick-Williams count used by
    :func:`cstiffjax.dynamics.frf.mode_count`.
    """
    Om = jnp.asarray(Omega, jnp.float64)
    out_of_plane = jnp.floor(Om / jnp.pi)
    anti = jnp.floor(Om / (2 * jnp.pi))
    n = jnp.floor((Om + jnp.pi) / (2 * jnp.pi))  # Ω in ((2n-1)π, (2n+1)π)
    sym = jnp.where(n >= 1, n - 1 + (_symmetric_function(Om, lambda2) > 0), 0.0)
    return (out_of_plane + anti + sym).astype(jnp.int32)


def clamped_cable_frequencies(length, tension, mass_per_length, lambda2, num: int = 5) -> dict:
    """Natural frequencies (Hz) of one cable with both ends fixed: ``"out_of_plane"``
    ``n/(2l) sqrt(τ/ρ)``, ``"in_plane_antisymmetric"`` (even ``n``) and
    ``"in_plane_symmetric"`` (Irvine's roots, by bisection), ``num`` of each.
    """
    c = jnp.sqrt(tension / mass_per_length) / (2 * jnp.pi * length)  # Hz per unit Ω
    n = jnp.arange(1, num + 1, dtype=jnp.float64)

    def root(k):
        # g(Ω) = Ω²/λ² + κ - 1 increases from -inf to +inf on ((2k-1)π, (2k+1)π)
        lo, hi = (2 * k - 1) * jnp.pi + 1e-12, (2 * k + 1) * jnp.pi - 1e-12

        def body(_, ab):
            a, b = ab
            m = 0.5 * (a + b)
            up = _symmetric_function(m, lambda2) > 0
            return jnp.where(up, a, m), jnp.where(up, m, b)

        a, b = jax.lax.fori_loop(0, 80, body, (lo, hi))
        return 0.5 * (a + b)

    sym = jax.vmap(root)(n)
    return {"out_of_plane": n * jnp.pi * c, "in_plane_antisymmetric": 2 * n * jnp.pi * c,
            "in_plane_symmetric": sym * c}
