"""Elastic catenary (cstiffjax.cable.catenary) against independent references.

References: Yuan et al. 2015 eqs (9)-(10)/(23)-(24) evaluated naively in 40-digit mpmath
(no rewrites), mpmath root finding on those equations, the massless spring law,
Irvine's closed-form flexibility matrix, and finite differences.
"""

import jax
import jax.numpy as jnp
import mpmath as mp
import numpy as np
import pytest

import cstiffjax  # noqa: F401  (float64)
from cstiffjax.cable.catenary import (
    catenary,
    catenary_force,
    catenary_profile,
    catenary_stiffness_3d,
    end_point,
    stiffness_B_closed_form,
)
from cstiffjax.core.status import Status

mp.mp.dps = 40


def mp_spans(H, VB, L, EA, w):
    """Seed 003 eqs (23)-(24) read from A, naive form, 40 digits."""
    H, VB, L, EA, w = map(mp.mpf, (H, VB, L, EA, w))
    VA = VB - w * L
    x = H * L / EA + (H / w) * (mp.asinh(VB / H) - mp.asinh(VA / H))
    z = (VA * L + w * L**2 / 2) / EA + (mp.sqrt(H**2 + VB**2) - mp.sqrt(H**2 + VA**2)) / w
    return x, z


def sag_ratio(H, VB, L, EA, w, n=101):
    s = np.linspace(0, L, n)
    VA = VB - w * L
    V = VA + w * s
    x = H * s / EA + (H / w) * (np.arcsinh(V / H) - np.arcsinh(VA / H))
    z = (VA * s + w * s * s / 2) / EA + (np.hypot(H, V) - np.hypot(H, VA)) / w
    c = np.hypot(x[-1], z[-1])
    return np.max(np.abs(x * z[-1] - z * x[-1])) / c / c


def make_cases(n, seed):
    """Random cases over the whole range: spans 1 m..1 km, EA 1e3..1e9 N, w 1e-4..1e3 N/m,
    taut (strain 1e-6..1e-2) and slack (sag/chord <= 0.3) lines, B above and below A.
    The end forces are chosen, the spans computed in mpmath and rounded to float64."""
    rng = np.random.default_rng(seed)
    rows = []
    while len(rows) < n:
        L, EA, w = 10 ** rng.uniform(0, 3), 10 ** rng.uniform(3, 9), 10 ** rng.uniform(-4, 3)
        th = np.radians(rng.uniform(-80, 80))
        if rng.uniform() < 0.5:
            T = 10 ** rng.uniform(-6, -2) * EA
            H, VB = T * np.cos(th), T * np.sin(th) + w * L / 2
        else:
            H = w * L / 10 ** rng.uniform(-3, np.log10(2.4))
            VB = H * np.tan(th) + rng.uniform(0, 1) * w * L
        VA = VB - w * L
        if max(np.hypot(H, VA), np.hypot(H, VB)) > 0.01 * EA or sag_ratio(H, VB, L, EA, w) > 0.3:
            continue
        sx, sz = mp_spans(H, VB, L, EA, w)
        rows.append((H, VB, L, EA, w, float(sx), float(sz)))
    return np.array(rows).T


@pytest.fixture(scope="module")
def cases():
    H, VB, L, EA, w, sx, sz = make_cases(400, 2024)
    # named hard cases: near-taut light lines, B far below A, deep sag, long heavy span
    extra = [(1e3, 10.0, 100.0, 1e8, 1e-4), (50.0, -400.0, 30.0, 1e6, 2.0), (10.0, 5.0, 10.0, 1e5, 1.0),
             (2e5, 3e5, 1000.0, 1e9, 100.0), (0.02, 0.001, 1.0, 1e3, 1e-4)]
    for h, vb, l, ea, ww in extra:
        x, z = mp_spans(h, vb, l, ea, ww)
        H, VB, L, EA, w = (np.append(a, b) for a, b in zip((H, VB, L, EA, w), (h, vb, l, ea, ww)))
        sx, sz = np.append(sx, float(x)), np.append(sz, float(z))
    return dict(H=H, VB=VB, L=L, EA=EA, w=w, sx=sx, sz=sz)


@pytest.fixture(scope="module")
def solved(cases):
    c = cases
    return catenary(c["sx"], c["sz"], c["L"], c["EA"], c["w"], throw=False)


def test_accuracy_against_mpmath(cases, solved):
    c = cases
    assert np.all(np.asarray(solved.result == Status.successful))
    tmax = np.maximum(np.hypot(c["H"], c["VB"]), np.hypot(c["H"], c["VB"] - c["w"] * c["L"]))
    err = np.maximum(np.abs(np.asarray(solved.H) - c["H"]), np.abs(np.asarray(solved.V_B) - c["VB"])) / tmax
    # the spans are rounded to float64, so the forces are determined only to about
    # eps * EA / T (= eps / strain); every case here has strain > 1e-7.
    strain = tmax / c["EA"]
    assert strain.min() > 1e-7 or np.all(err[strain < 1e-7] < 1e-15 / strain[strain < 1e-7])
    assert np.max(err[strain >= 1e-6]) < 1e-9
    assert np.max(err) < 1e-8
    np.testing.assert_allclose(np.asarray(solved.V_A), np.asarray(solved.V_B) - c["w"] * c["L"],
                               rtol=0, atol=1e-9 * tmax.max())
    # both sides of the range are really covered
    assert np.any(c["sz"] < 0) and np.any(c["sz"] > 0)
    assert np.any((c["VB"] - c["w"] * c["L"] < 0) & (c["VB"] > 0))  # lowest point inside the span


def test_mpmath_findroot_reference():
    """An independent solve: mpmath findroot on the naive equations, from the spans."""
    for sx, sz, L, EA, w in [(100.0, 20.0, 105.0, 1e7, 10.0), (80.0, -50.0, 94.0, 1e6, 3.0), (5.0, 2.0, 5.3, 1e4, 0.5)]:
        sol = catenary(sx, sz, L, EA, w)

        def f(H, VB, sx=sx, sz=sz, L=L, EA=EA, w=w):
            x, z = mp_spans(H, VB, L, EA, w)
            return [x - sx, z - sz]

        H, VB = mp.findroot(f, (mp.mpf(float(sol.H)) * 1.01, mp.mpf(float(sol.V_B)) * 0.99))
        tmax = float(max(sol.tension_A, sol.tension_B))
        assert abs(float(sol.H) - float(H)) < 1e-10 * tmax
        assert abs(float(sol.V_B) - float(VB)) < 1e-10 * tmax


@pytest.mark.parametrize("w", [0.0, 1e-12, 1e-8])
def test_spring_limit(w):
    sx, sz, L, EA = 3.0, 4.0, 4.99, 1e6
    sol = catenary(sx, sz, L, EA, w)
    T = EA * (5.0 - L) / L
    np.testing.assert_allclose(float(sol.H), T * 0.6, rtol=1e-9)
    np.testing.assert_allclose(float(sol.V_B), T * 0.8 + w * L / 2, rtol=1e-9)
    u = np.array([0.6, 0.8])
    K_spring = EA / L * np.outer(u, u) + T / 5.0 * (np.eye(2) - np.outer(u, u))
    np.testing.assert_allclose(np.asarray(sol.stiffness_B), K_spring, rtol=1e-6)


def test_gradient_through_massless_limit():
    """d(H, V_B)/dw at w = 0 is finite and matches a one-sided Richardson difference."""
    def f(w):
        s = catenary(3.0, 4.0, 4.99, 1e6, w)
        return jnp.stack([s.H, s.V_B])

    g = np.asarray(jax.jacfwd(f)(0.0))
    h = 1e-3
    f0, f1, f2 = (np.asarray(f(v)) for v in (0.0, h, h / 2))
    d1, d2 = (f1 - f0) / h, (f2 - f0) / (h / 2)
    assert np.all(np.isfinite(g))
    # O(h²) truncation of the Richardson estimate is ~4e-7 here (d1 - d2 ~ 3e-5)
    np.testing.assert_allclose(g, 2 * d2 - d1, rtol=1e-4, atol=2e-6)
    assert abs(g[1] - 4.99 / 2) < 1e-3  # V_B = T sin + w L / 2 to first order


def test_stiffness_symmetric_pd_and_closed_form(cases, solved):
    K = np.asarray(solved.stiffness_B)
    c = cases
    sym = np.abs(K[:, 0, 1] - K[:, 1, 0]) / np.abs(K).max(axis=(1, 2))
    assert sym.max() < 1e-8
    eig = np.linalg.eigvalsh(0.5 * (K + K.transpose(0, 2, 1)))
    assert np.all(eig > 0)
    # Irvine's flexibility inverse: fine where its cancellations are harmless
    sel = (c["w"] * c["L"] / c["H"] > 1e-2)
    Kc = np.asarray(stiffness_B_closed_form(solved.H, solved.V_B, c["L"], c["EA"], c["w"]))
    rel = np.abs(Kc - K).max(axis=(1, 2)) / np.abs(K).max(axis=(1, 2))
    assert sel.sum() > 50
    assert rel[sel].max() < 1e-7


def test_stiffness_vs_finite_differences():
    args = (105.0, 1e7, 10.0)
    sol = catenary(100.0, 20.0, *args)
    h = 1e-5

    def f(sx, sz):
        s = catenary(sx, sz, *args)
        return np.array([float(s.H), float(s.V_B)])

    fd = np.stack([(f(100 + h, 20.0) - f(100 - h, 20.0)) / (2 * h),
                   (f(100.0, 20 + h) - f(100.0, 20 - h)) / (2 * h)], -1)
    np.testing.assert_allclose(np.asarray(sol.stiffness_B), fd, rtol=1e-6)


def test_gradients_vs_fd():
    """Derivatives in length, EA and w (implicit function theorem) vs central differences."""
    x0 = np.array([104.0, 1e6, 10.0])

    def fn(p):
        s = catenary(100.0, -20.0, p[0], p[1], p[2])
        return s.H + 0.3 * s.V_B

    g = np.asarray(jax.grad(fn)(jnp.asarray(x0)))
    for k in range(3):
        h = 1e-6 * x0[k]
        e = np.eye(3)[k] * h
        fd = (float(fn(jnp.asarray(x0 + e))) - float(fn(jnp.asarray(x0 - e)))) / (2 * h)
        np.testing.assert_allclose(g[k], fd, rtol=1e-5)


@pytest.mark.slow
def test_jit_vmap_grad():
    sx = jnp.linspace(90.0, 99.0, 4)

    @jax.jit
    def total(sx):
        return jnp.sum(jax.vmap(lambda a: catenary(a, 5.0, 100.0, 1e7, 5.0, throw=False).H)(sx))

    g = jax.grad(total)(sx)
    direct = catenary(sx, 5.0, 100.0, 1e7, 5.0)
    np.testing.assert_allclose(float(total(sx)), float(jnp.sum(direct.H)), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(g), np.asarray(direct.stiffness_B[:, 0, 0]), rtol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(length=-1.0), r"length = -1\.0 .*must be > 0"),
        (dict(length=0.0), r"length = 0\.0 .*must be > 0"),
        (dict(EA=0.0), r"EA = 0\.0 .*must be > 0"),
        (dict(span_x=-2.0), r"span_x = -2\.0 .*must be > 0"),
        (dict(span_z=float("nan")), r"span_z = nan"),
        (dict(w=-1.0), r"w = -1\.0 .*must be >= 0"),
    ],
)
def test_bad_inputs_raise(kwargs, match):
    args = dict(span_x=10.0, span_z=1.0, length=11.0, EA=1e6, w=1.0) | kwargs
    with pytest.raises(ValueError, match=match):
        catenary(**args)


def test_bad_inputs_under_jit_give_status():
    f = jax.jit(lambda L: catenary(10.0, 1.0, L, 1e6, 1.0, throw=False).result)
    assert f(-1.0) == Status.invalid_input
    assert f(11.0) == Status.successful


def test_non_convergence_is_reported():
    """A massless slack line has no equilibrium: not_converged, and an error with throw."""
    sol = catenary(3.0, 4.0, 6.0, 1e6, 0.0, throw=False)
    assert sol.result == Status.not_converged
    with pytest.raises(Exception, match="did not converge"):
        catenary(3.0, 4.0, 6.0, 1e6, 0.0)


def test_profile_matches_seed_equations():
    sol = catenary(100.0, 20.0, 105.0, 1e7, 10.0)
    s = np.linspace(0, 105.0, 7)
    x, z = catenary_profile(sol.H, sol.V_A, 105.0, 1e7, 10.0, s)
    H, VA, w, EA = float(sol.H), float(sol.V_A), 10.0, 1e7
    # Yuan et al. 2015 eqs (9)-(10), read from A, plain numpy
    V = VA + w * s
    xr = H * s / EA + H / w * (np.arcsinh(V / H) - np.arcsinh(VA / H))
    zr = (VA * s + w * s * s / 2) / EA + (np.hypot(H, V) - np.hypot(H, VA)) / w
    np.testing.assert_allclose(np.asarray(x), xr, atol=1e-10)
    np.testing.assert_allclose(np.asarray(z), zr, atol=1e-10)
    assert abs(float(x[-1]) - 100.0) < 1e-9 and abs(float(z[-1]) - 20.0) < 1e-9


def test_end_point_massless_is_spring():
    x, z = end_point(600.0, 800.0, 5.0, 1e5, 0.0)
    np.testing.assert_allclose([float(x), float(z)], [5.0 * 1.01 * 0.6, 5.0 * 1.01 * 0.8], rtol=1e-14)


# ------------------------------------------------------------------ 3-D cable
G = jnp.array([0.0, 0.0, -9.81])


def test_3d_force_balance_and_plane_solution():
    anchor, att = jnp.array([5.3, -2.2, 4.2]), jnp.array([0.1, 0.2, 0.5])
    l0, EA, rho = 6.9, 2.5e5, 0.067
    cf = catenary_force(anchor, att, l0, EA, rho, G)
    # the cable's weight closes the balance
    # the cable weighs on its supports
    np.testing.assert_allclose(np.asarray(cf.on_platform + cf.on_anchor), [0, 0, -rho * 9.81 * l0], atol=1e-9)
    # same as the plane solve with A = anchor, B = attachment
    d = np.asarray(att - anchor)
    sol = catenary(np.hypot(d[0], d[1]), d[2], l0, EA, rho * 9.81)
    np.testing.assert_allclose(float(cf.tension_anchor), float(sol.tension_A), rtol=1e-12)
    np.testing.assert_allclose(float(cf.tension_attachment), float(sol.tension_B), rtol=1e-12)
    assert not bool(cf.slack)


def test_3d_gravity_direction_is_down():
    """Rotating everything (gravity included) rotates the forces."""
    from cstiffjax.core import lie

    R = lie.exp(jnp.array([0.3, -0.2, 0.5]))
    anchor, att = jnp.array([5.3, -2.2, 4.2]), jnp.array([0.1, 0.2, 0.5])
    a = catenary_force(anchor, att, 6.9, 2.5e5, 0.25, G)
    b = catenary_force(R @ anchor, R @ att, 6.9, 2.5e5, 0.25, R @ G)
    np.testing.assert_allclose(np.asarray(b.on_platform), np.asarray(R @ a.on_platform), atol=1e-9)


@pytest.mark.slow
def test_3d_stiffness_symmetric_and_fd():
    anchor, att = jnp.array([5.3, -2.2, 4.2]), jnp.array([0.1, 0.2, 0.5])
    args = (6.9, 2.5e5, 0.251, G)
    K = np.asarray(catenary_stiffness_3d(anchor, att, *args))
    force = jax.jit(lambda p: catenary_force(anchor, p, *args).on_platform)
    np.testing.assert_allclose(K, K.T, atol=1e-8 * np.abs(K).max())
    assert np.all(np.linalg.eigvalsh(K) > -1e-9 * np.abs(K).max())
    h = 1e-6
    fd = np.stack([-(np.asarray(force(att.at[j].add(h))) - np.asarray(force(att.at[j].add(-h)))) / (2 * h)
                   for j in range(3)], -1)
    np.testing.assert_allclose(K, fd, rtol=1e-5, atol=1e-6 * np.abs(K).max())


def test_3d_massless_slack_and_vertical():
    anchor = jnp.array([0.0, 0.0, 4.0])
    slack = catenary_force(anchor, jnp.array([3.0, 0.0, 0.0]), 6.0, 1e6, 0.0, G)
    assert bool(slack.slack) and float(slack.tension_anchor) == 0.0
    # a vertical hanging cable: tension at the top = stretch force + own weight
    v = catenary_force(anchor, jnp.array([0.0, 0.0, 0.5]), 3.4, 1e6, 0.25, G)
    w = 0.25 * 9.81
    # z(L) = -(T_B L + w L²/2)/EA - L  with T_B the force at the bottom end
    TB = (3.5 - 3.4 - w * 3.4**2 / 2 / 1e6) * 1e6 / 3.4
    np.testing.assert_allclose(float(v.tension_attachment), TB, rtol=1e-6)
    np.testing.assert_allclose(float(v.tension_anchor), TB + w * 3.4, rtol=1e-6)


def test_massless_catenary_just_taut_is_the_spring():
    """Spring limit of the catenary at ρ = 0: a cable stretched by 0.5% (chord = 1.005 l0) is
    taut with Hooke's tension EA (chord - l0) / l0 along the chord, not slack; at
    chord = 0.995 l0 it is slack and carries nothing."""
    anchor, attachment = jnp.array([1.2, 0.4, 2.1]), jnp.array([0.1, -0.2, 0.9])
    chord = float(np.linalg.norm(np.asarray(anchor - attachment)))
    g, EA = jnp.array([0.0, 0.0, -9.81]), 1.0e5
    taut = catenary_force(anchor, attachment, chord / 1.005, EA, 0.0, g)
    t = EA * (chord - chord / 1.005) / (chord / 1.005)
    assert not bool(taut.slack)
    assert float(taut.tension_anchor) == pytest.approx(t, rel=1e-8)
    np.testing.assert_allclose(taut.on_platform, t * np.asarray(anchor - attachment) / chord, rtol=1e-7, atol=1e-9)
    loose = catenary_force(anchor, attachment, chord / 0.995, EA, 0.0, g)
    assert bool(loose.slack) and float(loose.tension_anchor) == 0.0
