"""Tests of the sagging-cable DSM (cstiffjax.cable.dsm) and the robot dynamics (cstiffjax.dynamics.frf).

Independent references: a lumped-mass chain of springs (condensed to its end node), Irvine's
closed-form flexibility of the elastic catenary, the massless-spring stiffness of
cstiffjax.stiffness.matrix, the taut-string series, point-mass rigid bodies, finite differences.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.cable import dsm
from cstiffjax.cable.laws import CableLaw
from cstiffjax.core import lie
from cstiffjax.dynamics import frf as dy
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.geometry import inverse_statics
from cstiffjax.stiffness.matrix import stiffness

G = jnp.array([0.0, 0.0, -9.81])
POSE0 = jnp.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0])
POSE3 = jnp.array([3.0, 0.0, 0.5, 0.0, 0.0, 0.0])


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def proto8():
    robot = load_robot(example_path("prototype_8mm.toml"))
    t = inverse_statics(robot, POSE3).tensions
    return robot, t, dy.cable_statics_from_tensions(robot, POSE3, t)


@pytest.fixture(scope="module")
def massless():
    """Prototype with massless cables and a centre of mass off the reference point."""
    robot = load_robot(example_path("prototype_8mm.toml"))
    robot = eqx.tree_at(lambda r: (r.mass_per_length, r.com), robot, (jnp.zeros(6), jnp.array([0.0, 0.0, 0.05])))
    pose = jnp.array([0.1, 0.05, 0.5, 0.0, 0.0, 0.03])
    t = inverse_statics(robot, pose).tensions
    assert np.all(t > 0)
    return robot, pose, t, dy.cable_statics_from_tensions(robot, pose, t)


# ------------------------------------------------------------------- references
def chain_end_stiffness(span, l0, EA, rho, n=60, g=9.81):
    """Lumped-mass chain (n springs, n-1 masses rho*l0/n) hanging from the origin to ``span``.

    Plain numpy: static equilibrium by Newton with the assembled tangent stiffness (element
    ``(EA/ls) uuᵀ + (T/d)(I - uuᵀ)``). Returns ``(K_dyn(omega, xi), tau)``: the end-node
    dynamic stiffness from condensing the interior nodes,
    ``K_bb - K_bi (K_ii - ω²(1-2iξ) m I)^-1 K_ib``, and the chord-parallel tension ``H/cos α``.
    """
    span = np.asarray(span, float)
    ls, m = l0 / n, rho * l0 / n
    chord = np.linalg.norm(span)
    s = np.linspace(0, 1, n + 1)
    sag = np.sqrt(3 * chord * (l0 - chord) / 8) * 1.2
    X = s[:, None] * span + (4 * sag * s * (1 - s))[:, None] * np.array([0, 0, -1.0])

    def forces_and_stiffness(X):
        F = np.zeros_like(X)
        F[1:-1, 2] -= m * g
        K = np.zeros((3 * (n + 1), 3 * (n + 1)))
        for e in range(n):
            dv = X[e + 1] - X[e]
            d = np.linalg.norm(dv)
            u = dv / d
            T = EA * (d - ls) / ls
            F[e] += T * u
            F[e + 1] -= T * u
            ke = EA / ls * np.outer(u, u) + T / d * (np.eye(3) - np.outer(u, u))
            i, j = slice(3 * e, 3 * e + 3), slice(3 * e + 3, 3 * e + 6)
            K[i, i] += ke
            K[j, j] += ke
            K[i, j] -= ke
            K[j, i] -= ke
        return F, K

    inner = slice(3, 3 * n)
    for _ in range(50):
        F, K = forces_and_stiffness(X)
        dx = np.linalg.solve(K[inner, inner], F[1:-1].ravel())
        X[1:-1] += dx.reshape(-1, 3)
        if np.max(np.abs(dx)) < 1e-13:
            break
    F, K = forces_and_stiffness(X)
    assert np.max(np.abs(F[1:-1])) < 1e-8 and np.all(np.linalg.norm(np.diff(X, axis=0), axis=1) > ls)
    f_end = F[-1]  # force of the cable on the end node
    tau = np.linalg.norm(f_end[:2]) / (np.linalg.norm(span[:2]) / chord)
    k = 3 * (n - 1)
    Kii, Kib, Kbb = K[inner, inner], K[inner, 3 * n:], K[3 * n:, 3 * n:]

    def Kdyn(omega, xi=0.0):
        A = Kii - omega**2 * (1 - 2j * xi) * m * np.eye(k)
        return Kbb - Kib.T @ np.linalg.solve(A, Kib.astype(complex))

    return Kdyn, tau


def irvine_inplane_stiffness(H, V_B, L0, EA, w):
    """Irvine's elastic catenary: 2x2 stiffness ∂(H, V_B)/∂(span_x, span_z) at end B from the
    closed-form flexibility (A at the origin, z up, V_A = V_B - w L0)."""
    VA = V_B - w * L0
    TA, TB = np.hypot(H, VA), np.hypot(H, V_B)
    fxh = L0 / EA + (np.arcsinh(V_B / H) - np.arcsinh(VA / H)) / w - (V_B / TB - VA / TA) / w
    fxv = (H / w) * (1 / TB - 1 / TA)
    fzv = L0 / EA + (V_B / TB - VA / TA) / w
    return np.linalg.inv(np.array([[fxh, fxv], [fxv, fzv]]))


def irvine_span(H, V_B, L0, EA, w):
    """End point of the elastic catenary for end forces (H, V_B) (Irvine, closed form)."""
    VA = V_B - w * L0
    x = H * L0 / EA + (H / w) * (np.arcsinh(V_B / H) - np.arcsinh(VA / H))
    z = (VA * L0 + w * L0**2 / 2) / EA + (np.hypot(H, V_B) - np.hypot(H, VA)) / w
    return x, z


# ------------------------------------------------------------------ single-cable DSM
@pytest.mark.parametrize("alpha_deg", [0.0, -30.0])
def test_dsm_matches_lumped_chain(alpha_deg):
    """DSM (sign of k_b included) against a condensed lumped-mass chain, below and between
    cable resonances, with damping. Shallow-theory + discretization error ~1% measured."""
    a = np.deg2rad(alpha_deg)
    L, EA, rho = 6.0, 2.5e5, 0.067
    span = jnp.array([L * np.cos(a), 0.0, L * np.sin(a)])
    Kc, tau = chain_end_stiffness(span, 1.001 * L, EA, rho)
    f1 = np.sqrt(float(tau) / rho) / (2 * L)
    for r in (0.0, 0.3, 0.8, 1.3):
        w = 2 * np.pi * r * f1
        Kref = np.asarray(Kc(w, 0.01))
        K = np.asarray(dsm.cable_dynamic_stiffness(jnp.zeros(3), span, tau, EA, rho, G, w, 0.01))
        assert np.linalg.norm(K - Kref) < 0.03 * np.linalg.norm(Kref), (r, K, Kref)
        # out-of-plane (string) entry and the in-plane coupling, each on its own scale
        assert abs(K[1, 1] - Kref[1, 1]) < 0.05 * max(abs(Kref[1, 1]), float(tau) / L)
        if r > 0:
            fr = dsm.cable_frame(jnp.zeros(3), span, G)
            kb = fr.e_u @ K @ fr.e_v
            kb_ref = np.asarray(fr.e_u) @ Kref @ np.asarray(fr.e_v)
            assert np.sign(kb.real) == np.sign(kb_ref.real)
            # the shallow theory drops the chord-wise weight: an O(τ tan α / l) coupling
            assert abs(kb - kb_ref) < 0.05 * abs(kb_ref) + abs(np.tan(a)) * float(tau) / L


@pytest.mark.parametrize(("H", "V_B"), [(300.0, -130.0), (100.0, -45.0), (150.0, -120.0)])
def test_static_limit_is_irvine_catenary(H, V_B):
    """ω → 0: the DSM tends to the static tangent stiffness of the elastic catenary.

    In-plane to the accuracy of the shallow-cable theory, O(ε²) with ε = 8d/l (measured
    ~ε²/10); out of plane exactly H/span_x (the cable plane turns about the vertical
    through the anchor). The attachment B hangs below the anchor (V_B < 0)."""
    EA, rho, L0 = 1.01034e6, 0.251, 9.45
    w = rho * 9.81
    sx, sz = irvine_span(H, V_B, L0, EA, w)
    # cable frame: anchor at origin, attachment at (sx, 0, sz); stiffness at the attachment.
    chord = np.hypot(sx, sz)
    tau = H * chord / sx
    K = np.asarray(dsm.cable_dynamic_stiffness(jnp.zeros(3), jnp.array([sx, 0.0, sz]), tau, EA, rho, G, 0.0, 0.0))
    assert np.allclose(K.imag, 0.0)
    Kref = irvine_inplane_stiffness(H, V_B, L0, EA, w)
    Kxz = K.real[np.ix_([0, 2], [0, 2])]
    eps = w * sx / tau  # = ρ g l cos α / τ
    assert 0.03 < eps < 0.2
    assert np.linalg.norm(Kxz - Kref) < 0.5 * eps**2 * np.linalg.norm(Kref)
    # the soft (transverse) eigenvalue separately
    assert np.linalg.eigvalsh(Kxz)[0] == pytest.approx(np.linalg.eigvalsh(Kref)[0], rel=eps**2)
    assert K[1, 1].real == pytest.approx(H / sx, rel=1e-12)
    # and a frequency tending to zero reaches the same matrix continuously
    K_small = np.asarray(dsm.cable_dynamic_stiffness(jnp.zeros(3), jnp.array([sx, 0.0, sz]), tau, EA, rho, G,
                                                     1e-4, 0.0))
    assert np.allclose(K_small, K, rtol=1e-7, atol=1e-9 * np.abs(K).max())


def test_series_branches_are_continuous():
    """The series used near Ω = 0 join the closed forms (no jump at the switch)."""
    for O in (0.99e-2, 1.01e-2):
        q = dsm._kappa_minus_one_over_omega2(jnp.asarray(O + 0j))
        exact = (np.tan(O / 2) / (O / 2) - 1) / O**2
        assert abs(complex(q) - exact) < 1e-9
    assert abs(complex(dsm._omega_cot_omega(jnp.asarray(0.0099 + 0j))) - 0.0099 / np.tan(0.0099)) < 1e-12


def test_dsm_symmetric_and_jit_vmap():
    K = jax.jit(dsm.cable_dynamic_stiffness)(jnp.array([5.3, -2.2, 4.2]), jnp.array([3.0, 0.1, 0.5]), 150.0,
                                            1e6, 0.251, G, 2 * np.pi * 3.3, 0.01)
    assert np.allclose(K, K.T, rtol=0, atol=1e-9 * np.abs(K).max())
    ws = jnp.linspace(0.0, 60.0, 7)
    Ks = jax.vmap(lambda w: dsm.cable_dynamic_stiffness(jnp.zeros(3), jnp.array([5.0, 1.0, -3.0]), 150.0, 1e6,
                                                       0.251, G, w, 0.01))(ws)
    assert Ks.shape == (7, 3, 3)
    one = dsm.cable_dynamic_stiffness(jnp.zeros(3), jnp.array([5.0, 1.0, -3.0]), 150.0, 1e6, 0.251, G, ws[3], 0.01)
    assert np.allclose(Ks[3], one)


def test_taut_light_cable_resonances_are_string_series():
    """Light taut cable: DSM poles / clamped frequencies approach n/(2l) sqrt(T/ρ)."""
    L, T, rho, EA = 5.0, 2000.0, 1e-3, 1e6
    f1 = np.sqrt(T / rho) / (2 * L)
    c = dsm.dsm_coefficients(L, 1.0, T, EA, rho, 9.81, 0.0, 0.0)
    assert float(c.lambda2) < 1e-3
    fr = dsm.clamped_cable_frequencies(L, T, rho, c.lambda2, num=4)
    n = np.arange(1, 5)
    assert np.allclose(fr["out_of_plane"], n * f1)
    assert np.allclose(fr["in_plane_symmetric"], (2 * n - 1) * f1, rtol=1e-3)  # λ² → 0: odd string modes
    for k in (1, 2, 3):  # k_w and k_c change sign through a pole at every n f1
        lo = dsm.dsm_coefficients(L, 1.0, T, EA, rho, 9.81, 2 * np.pi * k * f1 * (1 - 1e-4), 0.0)
        hi = dsm.dsm_coefficients(L, 1.0, T, EA, rho, 9.81, 2 * np.pi * k * f1 * (1 + 1e-4), 0.0)
        assert lo.k_w.real < -1e3 * T / L and hi.k_w.real > 1e3 * T / L
        assert lo.k_c.real < -1e2 * T / L and hi.k_c.real > 1e2 * T / L


def test_clamped_count_matches_symmetric_roots():
    lam2 = 60.0
    fr = dsm.clamped_cable_frequencies(1.0, 1.0, 1.0, lam2, num=3)
    # Irvine's equation tan(Ω/2) = Ω/2 - (4/λ²)(Ω/2)³ at the returned roots
    O = 2 * np.pi * np.asarray(fr["in_plane_symmetric"])
    assert np.allclose(np.tan(O / 2), O / 2 - 4 / lam2 * (O / 2) ** 3, atol=1e-6)
    # λ² = 60 > 4π²: the first symmetric root lies in (2π, 3π), above the out-of-plane
    # modes π, 2π and the first antisymmetric one 2π
    assert 2 * np.pi < O[0] < 3 * np.pi
    counts = [int(dsm.clamped_mode_count(o, lam2)) for o in (0.5, O[0] - 1e-6, O[0] + 1e-6)]
    assert counts == [0, 3, 4]


def test_cable_point_response_ends():
    a, b = jnp.array([5.3, -2.2, 4.2]), jnp.array([3.0, 0.1, 0.5])
    d = jnp.array([1e-3, -2e-3, 0.5e-3]) * (1 + 0.3j)
    for w in (0.0, 15.0):
        end = dsm.cable_point_response(a, b, 150.0, 1e6, 0.251, G, w, 0.01, d, 1.0)
        start = dsm.cable_point_response(a, b, 150.0, 1e6, 0.251, G, w, 0.01, d, 0.0)
        assert np.allclose(end, d, atol=1e-12) and np.allclose(start, 0, atol=1e-12)


# ------------------------------------------------------------------ robot level
def test_massless_limit_equals_spring_stiffness_and_modes(massless):
    """ρ = 0: K_M(ω) = Cui et al.'s spring stiffness at every ω (lever-arm term included), the
    Wittrick-Williams frequencies equal the generalized eigenvalues, participation = 1."""
    robot, pose, t, st = massless
    Ks = np.asarray(stiffness(robot, pose, t).K)
    for w in (0.0, 40.0):
        K = np.asarray(dy.dynamic_stiffness(robot, pose, st, w, 0.02))
        assert np.allclose(K, Ks, rtol=0, atol=1e-10 * np.abs(Ks).max())
    f_ref = np.asarray(dy.spring_modes(robot, pose, t).frequencies)
    f = np.asarray(dy.natural_frequencies(robot, pose, st, 30.0, tol=1e-7))
    assert np.allclose(f, f_ref[f_ref < 30.0], atol=1e-6)
    assert np.allclose(dy.platform_modes(robot, pose, st, jnp.asarray(f)).participation, 1.0, atol=1e-6)


def test_mass_matrix_of_point_masses():
    """M equals Σ m_k [I, -hat(r_k)]ᵀ[I, -hat(r_k)] for a rigid cloud of point masses."""
    rng = np.random.default_rng(0)
    pts, ms = rng.normal(size=(7, 3)) * 0.2 + np.array([0.05, -0.02, 0.1]), rng.uniform(1, 3, 7)
    m = ms.sum()
    com = (ms[:, None] * pts).sum(0) / m
    q = pts - com
    inertia = sum(mk * (qk @ qk * np.eye(3) - np.outer(qk, qk)) for mk, qk in zip(ms, q))
    robot = load_robot(example_path("prototype_8mm.toml"))
    robot = eqx.tree_at(lambda r: (r.platform_mass, r.com, r.inertia), robot, (m, com, inertia))
    pose = jnp.array([0.3, -0.1, 0.5, 0.2, -0.4, 0.7])
    R = np.asarray(lie.exp(pose[3:]))
    ref = np.zeros((6, 6))
    for mk, pk in zip(ms, pts):
        r = R @ pk
        A = np.hstack([np.eye(3), -np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])])
        ref += mk * A.T @ A
    assert np.allclose(dy.mass_matrix(robot, pose), ref, atol=1e-12)


def test_KM_symmetric_at_equilibrium(proto8):
    robot, _t, st = proto8
    for w in (0.0, 11.0, 47.0):
        K = np.asarray(dy.dynamic_stiffness(robot, POSE3, st, w, 0.01))
        assert np.allclose(K, K.T, rtol=0, atol=1e-9 * np.abs(K).max())


def test_natural_frequencies_are_roots(proto8):
    """Every W-W frequency makes -ω²M + K_M singular (det changes sign across each simple
    root; the smallest eigenvalue there is far below its values between the roots)."""
    robot, _t, st = proto8
    f = np.asarray(dy.natural_frequencies(robot, POSE3, st, 6.0, tol=2e-8))
    assert f.size > 6 and np.all(np.diff(f) >= 0) and np.all((f >= 0.0) & (f < 6.0))
    Li = np.linalg.inv(np.linalg.cholesky(np.asarray(dy.mass_matrix(robot, POSE3))))

    def Dt(freq):
        D = np.real(np.asarray(dy.dynamic_matrix(robot, POSE3, st, 2 * np.pi * freq, 0.0)))
        return Li @ (0.5 * (D + D.T)) @ Li.T

    def smin(freq):
        return np.min(np.abs(np.linalg.eigvalsh(Dt(freq))))

    gaps = np.diff(f) > 1e-3
    roots = np.array([smin(x) for x in f])
    between = np.array([smin(x) for x in 0.5 * (f[:-1] + f[1:])[gaps]])
    assert np.max(roots) < 1e-2 * np.min(between)
    d = 1e-6
    isolated = np.concatenate([[True], np.diff(f) > 4 * d]) & np.concatenate([np.diff(f) > 4 * d, [True]])
    for x in f[isolated]:
        assert np.sign(np.linalg.det(Dt(x - d))) != np.sign(np.linalg.det(Dt(x + d)))


def test_frf_peaks_at_natural_frequencies_and_damping(proto8):
    """FRF peaks sit at the platform-dominated natural frequencies; ξ changes the peak
    height a lot and its frequency little."""
    robot, _t, st = proto8
    f = np.asarray(dy.natural_frequencies(robot, POSE3, st, 3.0, tol=1e-8))
    pm = dy.platform_modes(robot, POSE3, st, jnp.asarray(f))
    k = int(np.argmax(np.asarray(pm.participation)))
    fk = f[k]
    grid = np.linspace(fk - 0.03, fk + 0.03, 1201)
    wrench = jnp.concatenate([jnp.asarray(pm.shapes[k][:3]), jnp.asarray(pm.shapes[k][3:])])  # excite the mode
    peaks, heights = [], []
    for xi in (0.002, 0.02):
        X = np.asarray(dy.frf(robot, POSE3, st, grid, xi, wrench))
        amp = np.abs(X @ np.asarray(pm.shapes[k]))
        peaks.append(grid[np.argmax(amp)])
        heights.append(amp.max())
    assert abs(peaks[0] - fk) < 2e-3 * fk
    assert abs(peaks[1] - peaks[0]) < 5e-3 * fk
    assert heights[0] > 3 * heights[1]


@pytest.mark.slow
def test_KM_static_limit_equals_catenary_tangent_stiffness():
    """With the exact catenary state, K_M(0) equals -∂W/∂x of the catenary statics (autodiff
    through the elastic catenary) to the shallow-cable accuracy (measured 1e-3 of max)."""
    from cstiffjax.stiffness.matrix import stiffness_from_lengths

    robot = load_robot(example_path("prototype_8mm.toml"))
    l0 = dy.catenary_lengths(robot, POSE3).l0
    st = dy.cable_statics_from_lengths(robot, POSE3, l0)
    K0 = np.real(np.asarray(dy.dynamic_stiffness(robot, POSE3, st, 0.0)))
    Kc = np.asarray(stiffness_from_lengths(robot, POSE3, l0, law=CableLaw.catenary))
    assert np.max(np.abs(K0 - Kc)) < 3e-3 * np.abs(Kc).max()
    fs = np.asarray(dy.modal_analysis(jnp.asarray(K0), dy.mass_matrix(robot, POSE3)).frequencies)
    fc = np.asarray(dy.sagging_modes(robot, POSE3, l0).frequencies)
    assert np.allclose(fs, fc, rtol=1e-2)


def test_dynamic_stiffness_vmaps_over_poses(proto8):
    robot, _t, _st = proto8
    poses = jnp.array([[x, 0.1, 0.5, 0, 0, 0] for x in (-0.3, 0.0, 0.4)])

    def one(p):
        t = inverse_statics(robot, p, throw=False).tensions
        st = dy.CableStatics(t, t[:, None] * dy._unit_chords(robot, p))
        return dy._dynamic_stiffness(robot, p, st, 2 * jnp.pi * 3.0, 0.01)

    Ks = jax.jit(jax.vmap(one))(poses)
    t1 = inverse_statics(robot, poses[1]).tensions
    ref = dy.dynamic_stiffness(robot, poses[1], dy.cable_statics_from_tensions(robot, poses[1], t1), 2 * np.pi * 3.0,
                               0.01)
    assert Ks.shape == (3, 6, 6) and np.allclose(Ks[1], ref)


@pytest.mark.slow
def test_first_frequency_map_vmap_matches_single(proto8):
    robot, _t, _st = proto8
    poses = jnp.array([[x, y, 0.5, 0, 0, 0] for x in (-0.3, 0.4) for y in (-0.2, 0.3)])
    fm = np.asarray(dy.first_frequency_map(robot, poses, fmax=10.0, iters=30))
    for p, f in zip(poses, fm):
        t = inverse_statics(robot, p).tensions
        ref = dy.natural_frequencies(robot, p, dy.cable_statics_from_tensions(robot, p, t), 10.0, tol=1e-6)[0]
        assert abs(f - ref) < 2e-5


def test_derivative_used_for_participation_matches_fd(proto8):
    robot, _t, st = proto8

    def D(w):
        return jnp.real(dy.dynamic_matrix(robot, POSE3, st, w, 0.0))

    w, h = 9.0, 1e-5
    ad = np.asarray(jax.jacfwd(D)(w))
    fd = (np.asarray(D(w + h)) - np.asarray(D(w - h))) / (2 * h)
    assert np.allclose(ad, fd, rtol=1e-5, atol=1e-6 * np.abs(ad).max())


def test_frf_jit_and_cable_response_shapes(proto8):
    robot, _t, st = proto8
    f = jnp.linspace(0.5, 5.0, 9)
    X = dy.frf(robot, POSE3, st, f, 0.01)
    assert X.shape == (9, 6)
    D = dy.dynamic_matrix(robot, POSE3, st, 2 * np.pi * f[3], 0.01)
    assert np.allclose(D @ X[3], jnp.array([0, 0, 1.0, 0, 0, 0]), atol=1e-9)
    assert dy.cable_response(robot, POSE3, st, X, f, 0.01, cable=4, s=0.3).shape == (9, 3)
    # values: the platform point moves by δp + δθ × R b (Jacobian of its world position along
    # the twist by central differences with scipy rotations); acceleration -ω² Rᵀ(J X)
    from .helpers import np_fd, np_frame

    b = np.array([0.1, -0.05, 0.02])
    pose = np.asarray(POSE3)

    def world(tw):
        p, R = np_frame(pose, tw)
        return p + R @ b

    J = np_fd(world, 6, 1e-7)
    R0 = np_frame(pose)[1]
    w = 2 * np.pi * np.asarray(f)
    ref = -(w**2)[:, None] * ((np.asarray(X) @ J.T) @ R0)
    np.testing.assert_allclose(dy.point_acceleration(POSE3, X, f, b), ref, rtol=1e-7, atol=1e-9 * np.abs(ref).max())
    # cable points: the anchor end is fixed, the attachment end moves with the platform
    # (its chord-frame components are an orthonormal rotation of -ω² times that displacement)
    a_att = np.asarray(dy.cable_response(robot, POSE3, st, X, f, 0.01, cable=4, s=1.0))
    att_b = np.asarray(robot.attachments[4])
    J4 = np_fd(lambda tw: (lambda p, R: p + R @ att_b)(*np_frame(pose, tw)), 6, 1e-7)
    disp = np.asarray(X) @ J4.T
    np.testing.assert_allclose(np.linalg.norm(a_att, axis=1), w**2 * np.linalg.norm(disp, axis=1), rtol=1e-6)
    chord = np.asarray(robot.anchors[4]) - (pose[:3] + R0 @ att_b)
    e_u = -chord / np.linalg.norm(chord)  # anchor -> attachment
    np.testing.assert_allclose(np.abs(a_att[:, 0]), np.abs(w**2 * (disp @ e_u)), rtol=1e-6,
                               atol=1e-9 * np.abs(a_att).max())
    assert np.abs(np.asarray(dy.cable_response(robot, POSE3, st, X, f, 0.01, cable=4, s=0.0))).max() < 1e-9 * np.abs(
        a_att).max()


# ------------------------------------------------------------------ bad inputs
def test_bad_inputs(proto8):
    robot, t, st = proto8
    with pytest.raises(ValueError, match=r"frequencies = -1\.0 .*>= 0"):
        dy.frf(robot, POSE3, st, jnp.array([1.0, -1.0]))
    with pytest.raises(ValueError, match=r"xi = -0\.1 .*>= 0"):
        dy.frf(robot, POSE3, st, jnp.array([1.0]), xi=-0.1)
    with pytest.raises(ValueError, match=r"omega = -3\.0"):
        dy.dynamic_stiffness(robot, POSE3, st, -3.0)
    light = eqx.tree_at(lambda r: r.platform_mass, robot, 0.0)
    with pytest.raises(ValueError, match=r"platform_mass = 0\.0 .*> 0 kg"):
        dy.frf(light, POSE3, st, jnp.array([1.0]))
    with pytest.raises(ValueError, match=r"platform_mass"):
        dy.natural_frequencies(light, POSE3, st, 5.0)
    with pytest.raises(ValueError, match=r"tensions = 0\.0 .*> 0 N"):
        dy.cable_statics_from_tensions(robot, POSE3, t.at[2].set(0.0))
    with pytest.raises(ValueError, match=r"fmax = 1\.0 .*> fmin = 2\.0"):
        dy.natural_frequencies(robot, POSE3, st, 1.0, fmin=2.0)


def test_bad_inputs_under_jit(proto8):
    robot, _t, st = proto8
    f = jax.jit(lambda w: dy.dynamic_stiffness(robot, POSE3, st, w, 0.0))
    with pytest.raises(Exception, match="omega must be finite and >= 0"):
        jax.block_until_ready(f(-1.0))


# ------------------------------------------------------------------ command line
def test_cli_frf_rejects_bad_arguments(tmp_path, capsys):
    from cstiffjax.commands.cli import main

    base = ["frf", "prototype_8mm.toml", "--pose", "3", "0", "0.5", "0", "0", "0", "--out", str(tmp_path)]
    assert main([*base, "--cable", "9"]) == 1
    assert "--cable 9: allowed 1..6" in capsys.readouterr().err
    assert main([*base, "--fmin", "5", "--fmax", "2"]) == 1
    assert "--fmin < --fmax" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_frf_writes_figures_and_json(tmp_path):
    import json

    from cstiffjax.commands.cli import main

    rc = main(["frf", "prototype_8mm.toml", "--pose", "3", "0", "0.5", "0", "0", "0", "--fmax", "5", "--n", "200",
               "--sweep", "3", "--out", str(tmp_path)])
    assert rc == 0
    out = json.loads((tmp_path / "frf.json").read_text())
    assert len(out["frf"]["frequencies_hz"]) == 200 and (tmp_path / "frf_platform.png").exists()
    nat = np.array(out["dsm_natural_frequencies_hz"])
    assert nat.size > 5 and np.all(np.diff(nat) >= 0)
    assert np.array(out["sweep"]["first_frequency_hz"]).shape == (3, 3)
