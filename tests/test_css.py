"""Constant stiffness space: affine stiffness, exact membership vs LP, Cui et al. 2019 reproduction."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import linprog

from cstiffjax.core import lie
from cstiffjax.core.status import Status, to_codes
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.geometry import cable_lengths, gravity_wrench, structure_matrix_closed_form
from cstiffjax.stiffness import css
from cstiffjax.stiffness import tensions as T
from cstiffjax.stiffness.matrix import _rpy_matrix, stiffness, stiffness_split

POSE0 = jnp.array([0.0, 0.0, 0.83, 0.0, 0.0, 0.0])
LOAD1 = jnp.array([5.0, 5, 5, 0.5, 0.5, 0.5])  # Cui et al. 2019 Table 4 case 1

# Cui et al. 2019 eq. (26): K at POSE0, zero load, Table 3 tensions (N/m, N, N·m/rad)
EQ26 = np.array([
    [6055.06, 0.0, 0.0, 0.0, -267.81, 0.0],
    [0.0, 3226.71, 0.0, 137.46, 0.0, 0.0],
    [0.0, 0.0, 8379.21, 0.0, 0.0, 0.0],
    [0.0, 137.46, 0.0, 150.83, 0.0, 0.0],
    [-267.81, 0.0, 0.0, 0.0, 177.17, 0.0],
    [0.0, 0.0, 0.0, 0.0, 0.0, 162.21],
])


@pytest.fixture(scope="module")
def robot():
    return load_robot(example_path("tcpr8.toml"))


@pytest.fixture(scope="module")
def target(robot):
    return css.target_stiffness(robot, POSE0, inherent="paper")


@pytest.fixture(scope="module")
def member_fn(robot, target):
    return jax.jit(jax.vmap(lambda p, w: css.css_point(robot, p, target.K, 0.05, w, inherent="paper")))


def _poses(n, seed, rot=0.05):
    rng = np.random.default_rng(seed)
    return jnp.asarray(np.column_stack([rng.uniform(-0.15, 0.15, n), rng.uniform(-0.12, 0.12, n),
                                        rng.uniform(0.7, 1.0, n), rng.uniform(-rot, rot, (n, 3))]))


def test_affine_stiffness_matches_autodiff(robot):
    t = jnp.linspace(40.0, 320.0, 8)
    affine = eqx.filter_jit(css.affine_stiffness)
    for pose in _poses(2, 0, rot=0.3):
        aff = affine(robot, pose)
        np.testing.assert_allclose(aff(t), stiffness(robot, pose, t).K, rtol=1e-10, atol=1e-8)
        split = stiffness_split(robot, pose, t)
        np.testing.assert_allclose(aff.controllable(t), split.K1, atol=1e-9)
        S = np.asarray(structure_matrix_closed_form(robot, pose))
        K2 = (S * np.asarray(robot.EA / cable_lengths(robot, pose))) @ S.T  # Cui et al. 2019 eq. 19 with l0 = l
        paper = affine(robot, pose, inherent="paper")
        np.testing.assert_allclose(paper(t), split.K1 + K2 + split.K_gravity, atol=1e-8)


def test_stiffness_is_affine_in_phi_by_autodiff(robot):
    """Hessian of φ -> K(t_p + Nφ) (autodiff stiffness, spring law) vanishes; the φ part is symmetric.

    (Inside the CTFR only: the spring law is one-sided, a slack cable has no stiffness.)"""
    pose = jnp.array([0.08, -0.05, 0.9, 0.03, -0.02, 0.05])
    load = jnp.array([3.0, -4, 2, 0.4, -0.3, 0.2])
    sp = T.tension_space(robot, pose, load)
    region = T.ctfr_from_space(sp, robot.tension_min, robot.tension_max)
    assert region.result == Status.successful

    def K_of_phi(phi):
        return stiffness(robot, pose, sp.particular + sp.null_basis @ phi).K

    phi0 = region.centroid  # taut cables (t >= 10 N)
    H = jax.jacfwd(jax.jacfwd(K_of_phi))(phi0)
    J = jax.jacfwd(K_of_phi)(phi0)
    assert np.max(np.abs(H)) < 1e-9 * np.max(np.abs(J))
    np.testing.assert_allclose(J, np.swapaxes(J, 0, 1), atol=1e-9)  # φ-dependent part symmetric
    h = 1e-3  # finite-difference check of the autodiff slope
    fd = (K_of_phi(phi0 + jnp.array([h, 0])) - K_of_phi(phi0 - jnp.array([h, 0]))) / (2 * h)
    np.testing.assert_allclose(J[..., 0], fd, rtol=1e-7, atol=1e-7)


def test_eq26_reproduced_with_paper_inherent_stiffness(robot, target):
    """Reconstructed TCPR-8 + K2 = S diag(EA/l) Sᵀ reproduces Cui et al. 2019 eq. (26) (< 0.5%)."""
    K = np.asarray(target.K)
    big = np.abs(EQ26) > 1
    np.testing.assert_allclose(K[big], EQ26[big], rtol=5e-3)
    assert np.all(np.abs(K[~big]) < 1e-8)  # the 28 zeros of eq. (26) are structural zeros
    np.testing.assert_allclose(target.tensions, [193.7] * 4 + [210.3] * 4, atol=0.05)
    spring = css.target_stiffness(robot, POSE0).K  # exact spring law: stiffer by ~t/EA in K2
    ratio = np.diag(np.asarray(spring))[:3] / np.diag(K)[:3]
    assert np.all((ratio > 1.05) & (ratio < 1.12))


def test_srcc_increases_with_tension_max(robot):
    """Seed 004 Fig. 5: ψ grows with t_max (centroid tensions grow). Our ψ is 0.14 at 400 N
    (the paper reports 0.362; see cstiffjax/README.md)."""
    psis = []
    for tmax in (100.0, 200.0, 400.0, 800.0):
        r = eqx_tree_replace(robot, tmax)
        psis.append(float(css.target_stiffness(r, POSE0, inherent="paper").srcc))
    assert np.all(np.diff(psis) > 0) and 0 < psis[0] < psis[-1] < 1


def eqx_tree_replace(robot, tmax):
    return eqx.tree_at(lambda r: r.tension_max, robot, jnp.asarray(tmax))


def _lp_data(robot):
    """(t_p, N, K(t_p), dK/dφ) per pose by autodiff of the autodiff stiffness (independent of css)."""

    def one(pose, load):
        sp = T.tension_space(robot, pose, load)

        def K_of(ph):
            return stiffness_paper(robot, pose, sp.particular + sp.null_basis @ ph)

        return sp.particular, sp.null_basis, K_of(jnp.zeros(2)), jax.jacfwd(K_of)(jnp.zeros(2))

    return jax.jit(jax.vmap(one))


def _lp_margin(tp, N, K0, dK, kc, eps, norm="scaled"):
    """Independent reference: largest slack s with all constraints satisfied (scipy LP)."""
    tp, N, K0 = np.asarray(tp), np.asarray(N), np.asarray(K0)
    A = np.asarray(dK).reshape(36, 2)
    tol = np.asarray(css.tolerance(kc, eps, norm)).ravel()
    c0 = K0.ravel() - np.asarray(kc).ravel()
    rows = [N, -N, A, -A]
    rhs = [400.0 - tp, tp - 10.0, tol - c0, tol + c0]
    scale = [np.full(8, 1.0), np.full(8, 1.0), tol + 1e-9, tol + 1e-9]  # slack relative to each tolerance
    G = np.vstack([np.column_stack([r, s]) for r, s in zip(rows, scale)])
    res = linprog([0, 0, -1], A_ub=G, b_ub=np.concatenate(rhs), bounds=[(None, None)] * 2 + [(None, 1.0)])
    return -res.fun


def stiffness_paper(robot, pose, t):
    split = stiffness_split(robot, pose, t)
    S = structure_matrix_closed_form(robot, pose)
    return split.K1 + (S * (robot.EA / cable_lengths(robot, pose))) @ S.T + split.K_gravity


def test_membership_agrees_with_lp_on_random_poses(robot, target, member_fn):
    rng = np.random.default_rng(3)
    n = 40
    poses = jnp.asarray(np.column_stack([rng.uniform(-0.1, 0.1, n), rng.uniform(-0.08, 0.08, n),
                                         rng.uniform(0.75, 0.92, n), rng.uniform(-0.01, 0.01, (n, 3))]))
    loads = jnp.asarray(rng.uniform(-3, 3, (n, 6)) * [1, 1, 1, 0.1, 0.1, 0.1])
    out = member_fn(poses, loads)
    data = _lp_data(robot)(poses, loads)
    n_in = n_out = 0
    for k in range(n):
        margin = _lp_margin(*(d[k] for d in data), target.K, 0.05)
        if abs(margin) < 1e-6:
            continue  # on the boundary: either answer is right
        assert bool(out.member[k]) == (margin > 0), (k, margin)
        if out.member[k]:  # the chosen tensions really give K within tolerance, inside the CTFR
            n_in += 1
            t = out.tensions[k]
            K = stiffness_paper(robot, poses[k], t)
            assert np.all(np.abs(K - target.K) <= css.tolerance(target.K, 0.05) * (1 + 1e-9))
            assert np.all(t >= 10 - 1e-9) and np.all(t <= 400 + 1e-9)
            w = structure_matrix_closed_form(robot, poses[k]) @ t + gravity_wrench(robot, poses[k]) + loads[k]
            assert np.max(np.abs(w)) < 1e-8
        else:
            n_out += 1
            assert jax.tree.map(lambda a, k=k: a[k], out).result == Status.infeasible
    assert n_in >= 5 and n_out >= 5  # the sample straddles the CSS boundary


def test_slab_feasibility_against_brute_force_grid():
    rng = np.random.default_rng(5)
    fn = jax.jit(css.slab_feasible_point)
    g = np.linspace(-2, 2, 401)
    P = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    agree = 0
    for _ in range(30):
        a = rng.normal(size=(6, 2))
        c = rng.uniform(-1, 1, 6)
        w = rng.uniform(0.05, 1.0, 6)
        ok, phi = fn(jnp.asarray(a), jnp.asarray(c - w), jnp.asarray(c + w))
        v = P @ a.T
        grid_ok = np.all((v >= c - w) & (v <= c + w), 1)
        if grid_ok.any():
            assert ok
        if ok:
            vv = a @ np.asarray(phi)
            assert np.all(vv >= c - w - 1e-12) and np.all(vv <= c + w + 1e-12)
            agree += grid_ok.any()
    assert agree >= 3


def test_reference_pose_is_member_and_zero_load_css_is_mirror_symmetric(robot, target, member_fn):
    rng = np.random.default_rng(6)
    xyz = np.column_stack([rng.uniform(-0.2, 0.2, 40), rng.uniform(-0.15, 0.15, 40), rng.uniform(0.6, 1.1, 40)])
    flips = [np.array([1, 1, 1]), np.array([-1, 1, 1]), np.array([1, -1, 1])]
    batch = jnp.asarray(np.concatenate([np.column_stack([xyz * f, np.zeros((40, 3))]) for f in flips]))
    out = member_fn(batch, jnp.zeros((120, 6)))
    m = np.asarray(out.member).reshape(3, 40)
    assert np.array_equal(m[0], m[1]) and np.array_equal(m[0], m[2])
    mu = np.asarray(out.stability).reshape(3, 40)
    np.testing.assert_allclose(mu[0][m[0]], mu[1][m[0]], atol=1e-9)
    ref = member_fn(POSE0[None], jnp.zeros((1, 6)))
    assert bool(ref.member[0])


@pytest.mark.slow
def test_posture_shrinks_css(robot):
    """Table 7 structure: with k_c from eq. (27) (load case 1), more rotation -> fewer members."""
    kc = css.target_stiffness(robot, POSE0, LOAD1, inherent="paper").K
    rng = np.random.default_rng(7)
    xyz = np.column_stack([rng.uniform(-0.3, 0.3, 300), rng.uniform(-0.2, 0.2, 300), rng.uniform(0.5, 1.2, 300)])
    f = jax.jit(jax.vmap(lambda p: css.css_point(robot, p, kc, 0.05, LOAD1, inherent="paper", norm="max").member))
    counts = []
    for deg in (0.0, 2.0, 4.0):
        rv = lie.log(_rpy_matrix(jnp.deg2rad(jnp.full(3, deg))))
        counts.append(int(f(jnp.asarray(np.column_stack([xyz, np.tile(rv, (300, 1))]))).sum()))
    assert counts[0] > counts[1] > counts[2] > 0


def test_pose_change_and_singular_status(target):
    W = jnp.array([10.0, 0, 0, 0, 0, 0])
    pc = css.pose_change(target.K, W)
    np.testing.assert_allclose(target.K @ pc.delta, W, atol=1e-10)
    assert 1e-3 < float(pc.delta[0]) < 3e-3  # ~ 10 N / 6000 N/m: mm, as in Cui et al. 2019 Table 10
    bad = css.pose_change(jnp.zeros((6, 6)), W, throw=False)
    assert bad.result == Status.singular and np.all(np.isfinite(bad.delta))
    with pytest.raises(Exception, match="rank deficient"):
        css.pose_change(jnp.zeros((6, 6)), W)


def test_singular_pose_gives_status(robot, target):
    flat = eqx.tree_at(lambda r: r.attachments, robot, jnp.zeros((8, 3)))
    out = eqx.filter_jit(css.css_point)(flat, POSE0, target.K, 0.05)
    assert out.result == Status.singular and not bool(out.member)
    assert np.all(np.isfinite(out.tensions)) and np.isfinite(out.stability)


def test_bad_arguments(robot, target):
    with pytest.raises(ValueError, match="norm='l2' is not allowed; allowed: 'scaled', 'max', 'paper'"):
        css.css_point(robot, POSE0, target.K, 0.05, norm="l2")
    with pytest.raises(ValueError, match="inherent='x' is not allowed"):
        css.affine_stiffness(robot, POSE0, inherent="x")
    r9 = eqx.tree_at(lambda r: (r.anchors, r.attachments, r.EA, r.mass_per_length), robot,
                     (jnp.concatenate([robot.anchors, robot.anchors[:1]]),
                      jnp.concatenate([robot.attachments, robot.attachments[:1]]),
                      jnp.concatenate([robot.EA, robot.EA[:1]]), jnp.zeros(9)))
    with pytest.raises(ValueError, match="m = 9 cables \\(r = 3\\)"):
        css.css_point(r9, POSE0, target.K, 0.05)


def test_summary():
    s = css.summarize(jnp.array([True, False, True]), jnp.array([0.2, 5.0, 0.4]), 1e-6)
    assert int(s.count) == 2 and float(s.volume) == pytest.approx(2e-6) and float(s.stability) == pytest.approx(0.3)
    e = css.summarize(jnp.array([False]), jnp.array([1.0]), 1.0)
    assert float(e.stability) == 0.0 and float(e.volume) == 0.0


@pytest.mark.slow
def test_cli_css_writes_results(tmp_path, capsys):
    from cstiffjax.commands.cli import main

    rc = main(["css", "tcpr8.toml", "--pose-grid", "-0.04", "0.04", "3", "-0.03", "0.03", "3", "0.8", "0.86", "2",
               "--stiffness-at", "0", "0", "0.83", "0", "0", "0", "--eps", "0.05", "--inherent", "paper",
               "--load", "1", "0", "0", "0", "0", "0", "--no-progress", "--out", str(tmp_path)])
    assert rc == 0
    res = np.load(tmp_path / "results.npz")
    assert res["member"].shape == (3, 3, 2) and res["tensions"].shape == (3, 3, 2, 8)
    assert res["member"].all()  # 4 cm around the reference pose is inside the CSS
    np.testing.assert_allclose(res["kc"][[0, 1, 2], [0, 1, 2]], EQ26[[0, 1, 2], [0, 1, 2]], rtol=5e-3)
    assert float(res["volume"]) == pytest.approx(0.08 * 0.06 * 0.06, rel=1e-12)  # the whole grid box
    for f in ("css_3d.png", "css_section.png", "ctfr.png", "summary.json"):
        assert (tmp_path / f).stat().st_size > 0
    assert "CSS: 18 of 18 poses" in capsys.readouterr().out
    assert main(["css", "tcpr8.toml", "--pose-grid", "0", "1", "2.5", "0", "1", "2", "0", "1", "2",
                 "--stiffness-at", "0", "0", "0.83", "0", "0", "0", "--out", str(tmp_path)]) == 1
    assert "NX = 2.5 must be a positive integer" in capsys.readouterr().err


@pytest.mark.slow
def test_membership_with_one_degree_of_redundancy_against_brute_force(robot):
    """r = 1 (7 cables, signed tension range to make it feasible): padded 2-D problem vs a 1-D scan."""
    names = ("anchors", "attachments", "EA", "mass_per_length", "pulley_radius", "pulley_axis", "length_gain",
             "tension_gain")  # every per-cable field
    r7 = eqx.tree_at(lambda r: (*(getattr(r, k) for k in names), r.tension_min), robot,
                     (*(getattr(robot, k)[:7] for k in names), jnp.asarray(-300.0)))
    pose = jnp.array([0.02, -0.01, 0.84, 0.0, 0.0, 0.0])
    sp = T.tension_space(r7, pose)
    aff = css.affine_stiffness(r7, pose, inherent="paper")
    s = np.linspace(-3000, 3000, 60001)
    t = np.asarray(sp.particular)[None] + s[:, None] * np.asarray(sp.null_basis)[:, 0][None]
    ok_t = np.all((t >= -300) & (t <= 400), 1)
    K = np.asarray(aff.K0)[None] + np.einsum("ni,ijk->njk", t, np.asarray(aff.M))
    point = eqx.filter_jit(css.css_point)
    seen = set()
    for eps, factor in ((0.02, 0.25), (0.02, 2.0), (0.2, 0.25), (0.2, 2.0)):
        kc = aff(jnp.asarray(t[np.flatnonzero(ok_t)[len(np.flatnonzero(ok_t)) // 3]])) * (1 + factor * eps)
        tol = np.asarray(css.tolerance(kc, eps))
        ok = ok_t & np.all(np.abs(K - np.asarray(kc)[None]) <= tol[None], axis=(1, 2))
        out = point(r7, pose, kc, eps, inherent="paper")
        assert bool(out.member) == bool(ok.any()), (eps, factor)
        seen.add(bool(out.member))
        if out.member:
            assert np.all(np.asarray(out.tensions) >= -300 - 1e-9)
            assert np.all(np.abs(np.asarray(aff(out.tensions)) - np.asarray(kc)) <= tol * (1 + 1e-9))
    assert seen == {True, False}


# ------------------------------------------------------------- pose-minor batch kernel
def test_batch_form_equals_vmapped_one_pose_form(robot, target, member_fn):
    """css_point on (6, B) (pose-minor kernel, FM skipped for fully rejected batches) equals
    vmap of the one-pose form, field by field, for members, non-members and far poses."""
    rng = np.random.default_rng(11)
    near = _poses(48, 12, rot=0.02)
    far = jnp.asarray(np.column_stack([rng.uniform(-0.7, 0.7, 48), rng.uniform(-0.5, 0.5, 48),
                                       rng.uniform(0.05, 0.3, 48), np.zeros((48, 3))]))
    batch = jax.jit(lambda P: css.css_point(robot, P, target.K, 0.05, LOAD1, inherent="paper"))
    for P in (near, far):
        a, b = member_fn(P, jnp.tile(LOAD1, (48, 1))), batch(P.T)
        assert np.array_equal(a.member, b.member) and np.array_equal(to_codes(a.result), to_codes(b.result))
        np.testing.assert_allclose(b.tensions.T, a.tensions, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(b.phi.T, a.phi, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(b.stability, a.stability, rtol=1e-12, atol=1e-14)
    assert int(member_fn(near, jnp.tile(LOAD1, (48, 1))).member.sum()) >= 3
    assert not np.any(b.member)  # far: the whole batch is rejected without Fourier-Motzkin


def test_kernel_null_space_and_rotation_match_references(robot):
    """Kernel geometry vs lie.exp / cable_lengths; null space vs numpy pinv/SVD, canonical basis."""
    from cstiffjax.stiffness import kernel as ck

    P = _poses(6, 13, rot=2.0)
    P = P.at[0, 3:].set(jnp.array([1e-9, -2e-9, 0.0]))  # small-angle branch
    for p in P:
        R, r, u, l = ck.geometry(robot, p, 0)
        np.testing.assert_allclose(R, lie.exp(p[3:]), atol=1e-15)
        np.testing.assert_allclose(l, cable_lengths(robot, p), rtol=1e-14)
        tp, N, singular = ck.null_space(ck.structure_rows(r, u), ck.load_wrench(robot, R, LOAD1, 0))
        S = np.asarray(structure_matrix_closed_form(robot, p))
        w = np.asarray(gravity_wrench(robot, p) + LOAD1)
        assert not bool(singular)
        np.testing.assert_allclose(tp, np.linalg.pinv(S) @ -w, rtol=1e-9, atol=1e-9)
        proj = np.eye(8) - np.linalg.pinv(S) @ S
        np.testing.assert_allclose(N @ N.T, proj, atol=1e-10)
        np.testing.assert_allclose(N.T @ N, np.eye(2), atol=1e-12)
        n1 = proj @ np.ones(8)
        np.testing.assert_allclose(N[:, 0], n1 / np.linalg.norm(n1), atol=1e-10)
        assert np.sum(np.asarray(N[:, 1]) ** 3) >= 0


def test_disc_test_never_rejects_a_member(robot, target):
    """The cheap certificate is exact: a rejected pose has no feasible φ (checked by FM)."""
    from cstiffjax.stiffness import kernel as ck

    rng = np.random.default_rng(14)
    P = jnp.asarray(np.column_stack([rng.uniform(-0.25, 0.25, 400), rng.uniform(-0.2, 0.2, 400),
                                     rng.uniform(0.5, 1.2, 400), rng.uniform(-0.01, 0.01, (400, 3))])).T
    R, r, u, l = ck.geometry(robot, P, 1)
    s = ck.structure_rows(r, u)
    tp, N, _ = ck.null_space(s, ck.load_wrench(robot, R, None, 1))
    K0, K_lin = ck.contractions(robot, R, r, u, l, jnp.concatenate([tp[:, None], N], axis=1), "paper")
    a, lo, hi = ck.slabs(robot, tp, N, K0, K_lin, target.K, css.tolerance(target.K, 0.05))
    rejected, (ok, _) = jax.jit(lambda *x: (ck.disc_reject(*x, tp, robot), ck.feasible_point(*x)))(a, lo, hi)
    assert 0.2 < float(rejected.mean()) < 0.95 and int(ok.sum()) > 5
    assert not np.any(np.asarray(rejected & ok))


def test_slab_feasibility_degenerate_slabs_against_brute_force():
    """Vertical slabs (a2 = 0), exactly parallel pairs and zero normals, vs a grid."""
    fn = jax.jit(css.slab_feasible_point)
    g = np.linspace(-2, 2, 401)
    G = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    rng = np.random.default_rng(15)
    seen = {True: 0, False: 0}
    for _ in range(30):
        a = rng.normal(size=(7, 2))
        a[0, 1] = 0.0  # vertical
        a[1, 0] = 0.0  # horizontal
        a[2] = a[3] * rng.choice([-2.0, 0.5])  # exactly parallel pair
        c = rng.uniform(-0.8, 0.8, 7)
        w = rng.uniform(0.1, 1.0, 7)
        lo, hi = c - w, c + w
        ok, phi = fn(jnp.asarray(a), jnp.asarray(lo), jnp.asarray(hi))
        v = G @ a.T
        grid_ok = np.all((v >= lo) & (v <= hi), 1)
        margin = np.max(np.min(np.minimum(v - lo, hi - v), 1))  # depth of the deepest grid point
        if abs(margin) > 0.02:
            assert bool(ok) == grid_ok.any()
            seen[bool(ok)] += 1
        if ok:
            vv = a @ np.asarray(phi)
            assert np.all(vv >= lo - 1e-12) and np.all(vv <= hi + 1e-12)
    assert seen[True] >= 3 and seen[False] >= 3
    zero = jnp.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])  # a zero normal and the box |φ| <= 1
    assert bool(fn(zero, -jnp.ones(3), jnp.ones(3))[0])  # 0·φ in [-1, 1]: no constraint
    assert not bool(fn(zero, jnp.array([0.5, -1.0, -1.0]), jnp.ones(3))[0])  # 0·φ in [0.5, 1]: empty
    ok, phi = fn(zero[1:], -jnp.ones(2), jnp.array([1.0, jnp.inf]))  # unbounded in φ2: feasible, finite point
    assert bool(ok) and np.allclose(phi, [0.0, 0.0])
    ok, phi = fn(zero[1:], jnp.array([-jnp.inf, 2.0]), jnp.array([1.0, jnp.inf]))  # a quadrant
    assert bool(ok) and np.allclose(phi, [0.0, 3.0])


# ------------------------------------- membership under N·m moments, near the boundary
def _scaled_tolerance(kc, eps):
    """Seed 004 Fig. 7 step 5, |k(T) - k_c| / k_c <= ε, read unit-consistently (cstiffjax/README.md,
    css module docstring): |K_ij - k_c,ij| <= ε sqrt(|k_c,ii k_c,jj|); on the diagonal it
    is the paper's relative error exactly. Written here, not taken from css.tolerance."""
    d = np.sqrt(np.abs(np.diag(np.asarray(kc))))
    return eps * np.outer(d, d)


def _lp_margin_tol(tp, N, K0, dK, kc, tol, tmin=10.0, tmax=400.0):
    """Largest slack s (relative to each tolerance) over φ of all 8 tension limits and all
    36 stiffness entries (K is asymmetric under a moment: (i, j) and (j, i) separately)."""
    A = np.asarray(dK).reshape(36, 2)
    c0 = np.asarray(K0).ravel() - np.asarray(kc).ravel()
    tol = np.asarray(tol).ravel()
    N, tp = np.asarray(N), np.asarray(tp)
    G = np.vstack([np.column_stack([N, np.ones(8)]), np.column_stack([-N, np.ones(8)]),
                   np.column_stack([A, tol]), np.column_stack([-A, tol])])
    h = np.concatenate([tmax - tp, tp - tmin, tol - c0, tol + c0])
    res = linprog([0, 0, -1], A_ub=G, b_ub=h, bounds=[(None, None)] * 2 + [(None, 1.0)])
    assert res.status == 0
    return -res.fun


def test_membership_under_moments_near_the_boundary_agrees_with_lp(robot):
    """3 load cases with 2-4 N·m moments (K - Kᵀ = hat(m): the (i, j) and (j, i) entries have
    different offsets), k_c = the centroid stiffness at the reference pose under that load
    (Cui et al. 2019 eq. 27 style). Along 8 random 6-D rays per case the LP boundary is found by
    bisection; poses 3% inside and 3% outside it must be members / non-members, and every
    member's tensions must meet all 36 entries of the tolerance written above."""
    rng = np.random.default_rng(21)
    loads = np.array([[4.0, -3.0, 5.0, 3.0, -2.0, 4.0], [-5.0, 2.0, -4.0, -4.0, 3.0, -2.0],
                      [2.0, 5.0, 3.0, 2.0, 4.0, -3.0]])
    eps, n_rays = 0.02, 8  # ε = 2%: the rotational tolerance (~3 N·m/rad) is below the asymmetry hat(m) (~4)
    dirs = rng.normal(size=(3 * n_rays, 6))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs *= np.array([0.3, 0.3, 0.3, 0.2, 0.2, 0.2])  # s = 1: 30 cm / 0.2 rad away (outside)
    load_of = np.repeat(loads, n_rays, axis=0)
    kcs = [np.asarray(css.target_stiffness(robot, POSE0, jnp.asarray(w), inherent="paper").K) for w in loads]
    kc_of = np.repeat(np.stack(kcs), n_rays, axis=0)
    assert max(np.abs(k - k.T).max() for k in kcs) > 3.9  # the targets themselves are asymmetric
    data_fn = _lp_data(robot)

    def margins(s, dirs=dirs, load_of=load_of, kc_of=kc_of):
        P = np.asarray(POSE0)[None] + s[:, None] * dirs
        data = data_fn(jnp.asarray(P), jnp.asarray(load_of))
        return np.array([_lp_margin_tol(*(np.asarray(d[k]) for d in data), kc_of[k],
                                        _scaled_tolerance(kc_of[k], eps)) for k in range(len(s))])

    lo, hi = np.zeros(len(dirs)), np.ones(len(dirs))
    assert np.all(margins(lo) > 0.5) and np.all(margins(hi) < 0)
    for _ in range(10):  # s* to 1e-3
        mid = 0.5 * (lo + hi)
        inside = margins(mid) > 0
        lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
    s_star = 0.5 * (lo + hi)
    s_test = np.concatenate([0.97 * s_star, 1.03 * s_star])
    W, KC = np.concatenate([load_of, load_of]), np.concatenate([kc_of, kc_of])
    m_ref = np.concatenate([margins(0.97 * s_star), margins(1.03 * s_star)])
    P = np.asarray(POSE0)[None] + s_test[:, None] * np.concatenate([dirs, dirs])
    for k in range(len(s_test)):  # one compiled one-pose function (k_c and the load are arguments)
        out = _member_one(robot, jnp.asarray(P[k]), jnp.asarray(KC[k]), eps, jnp.asarray(W[k]))
        assert bool(out.member) == (m_ref[k] > 0), (k, m_ref[k])
        if out.member:
            K = np.asarray(stiffness_paper(robot, jnp.asarray(P[k]), out.tensions))
            assert np.all(np.abs(K - KC[k]) <= _scaled_tolerance(KC[k], eps) * (1 + 1e-9) + 1e-9)
            assert np.all(np.asarray(out.tensions) >= 10 - 1e-9) and np.all(np.asarray(out.tensions) <= 400 + 1e-9)
            tbar = 0.5 * (400 + 10)  # Cui et al. 2019 eq. 25a with the midpoint of the limits
            assert float(out.stability) == pytest.approx(np.mean(np.abs(np.asarray(out.tensions) - tbar)) / tbar)
    assert np.sum(m_ref > 0) == len(dirs) and np.sum(m_ref < 0) == len(dirs)


_member_one = eqx.filter_jit(lambda robot, p, kc, eps, w: css.css_point(robot, p, kc, eps, w, inherent="paper"))


def test_asymmetric_pair_decides_membership_like_the_lp(robot):
    """Under a moment K is asymmetric, and K_ij - K_ji = δ does not depend on the tensions
    (the null-space directions carry no net wrench). Target k_c: the symmetric part of
    K(centroid), except that the most asymmetric pair (i < j) gets k_c,ij = k_c,ji = K_ij.
    Then (i, j) is exact at the centroid and (j, i) is off by -δ, and no tensions meet both
    unless tol >= |δ| / 2: at ε = ε_low < ε* = |δ| / (2 sqrt(k_c,ii k_c,jj)) the pose is
    not a member although every entry but (j, i) is met at the centroid; at 3 ε* it is. The
    membership must follow the LP over all 36 entries separately (tolerance written here,
    Cui et al. 2019 Fig. 7 step 5). The two loads give both signs of δ: the lower bound of the
    (j, i) slab decides one case, the upper bound the other."""
    signs = set()
    for w in (np.array([3.0, -2.0, 4.0, 4.0, -3.0, 2.5]), -np.array([3.0, -2.0, 4.0, 4.0, -3.0, 2.5])):
        K = np.asarray(css.target_stiffness(robot, POSE0, jnp.asarray(w), inherent="paper").K)
        kc = 0.5 * (K + K.T)
        d = np.sqrt(np.abs(np.diag(kc)))
        ratio = np.triu(np.abs(K - K.T) / (2 * np.outer(d, d)), 1)
        i, j = np.unravel_index(np.argmax(ratio), ratio.shape)
        kc[i, j] = kc[j, i] = K[i, j]
        r = np.sort(ratio.ravel())[::-1]
        assert r[0] > 1e-3  # the load makes K visibly asymmetric
        signs.add(np.sign(K[i, j] - K[j, i]))
        eps_low = max(0.5 * (r[0] + r[1]), 0.9 * r[0])  # every other pair's own asymmetry still within tol
        data = [np.asarray(a[0]) for a in _lp_data(robot)(POSE0[None], jnp.asarray(w)[None])]
        for eps, member in ((eps_low, False), (3 * r[0], True)):
            ref = _lp_margin_tol(*data, kc, _scaled_tolerance(kc, eps))
            assert (ref > 0) == member and abs(ref) > 1e-3  # the LP agrees with the construction
            out = _member_one(robot, POSE0, jnp.asarray(kc), eps, jnp.asarray(w))
            assert bool(out.member) == member, (w, eps, ref)
    assert signs == {-1.0, 1.0}


def test_paper_tolerance_is_relative_to_each_entry():
    """Seed 004 Fig. 7 step 5 read literally ("paper"): |k_ij(T) - k_c,ij| / |k_c,ij| <= ε, so
    the allowed deviation is ε |k_c,ij| entry by entry and exactly 0 where k_c,ij = 0."""
    kc = jnp.asarray(EQ26)
    np.testing.assert_array_equal(np.asarray(css.tolerance(kc, 0.02, "paper")), 0.02 * np.abs(EQ26))
    assert float(css.tolerance(kc, 0.02, "paper")[0, 1]) == 0.0
