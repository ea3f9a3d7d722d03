"""Tension distribution: null space, CTFR polygon (vs brute force), centroid, feasibility."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import minimize

from cstiffjax.core.status import Status, code, to_codes
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.geometry import gravity_wrench, structure_matrix_closed_form
from cstiffjax.stiffness import tensions as T

POSE0 = jnp.array([0.0, 0.0, 0.83, 0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def robot():
    return load_robot(example_path("tcpr8.toml"))


def _subset(robot, idx, **kw):
    idx = np.asarray(idx)
    fields = dict(anchors=robot.anchors[idx], attachments=robot.attachments[idx], EA=robot.EA[idx],
                  mass_per_length=robot.mass_per_length[idx])
    fields.update(kw)
    return eqx_replace(robot, **fields)


def eqx_replace(robot, **kw):
    names = ["anchors", "attachments", "EA", "mass_per_length", "platform_mass", "com", "inertia", "gravity",
             "noise", "tension_min", "tension_max"]
    args = {k: getattr(robot, k) for k in names}
    args.update(kw)
    return type(robot)(**args, name=robot.name)


def random_poses(n, seed=0, rot=0.1):
    rng = np.random.default_rng(seed)
    p = np.column_stack([rng.uniform(-0.25, 0.25, n), rng.uniform(-0.2, 0.2, n), rng.uniform(0.6, 1.1, n),
                         rng.uniform(-rot, rot, (n, 3))])
    return jnp.asarray(p)


def test_tension_space_matches_pinv(robot):
    for pose in random_poses(5, rot=0.2):
        sp = T.tension_space(robot, pose, jnp.array([3.0, -2, 5, 0.3, 0.1, -0.2]))
        S = np.asarray(structure_matrix_closed_form(robot, pose))
        w = np.asarray(gravity_wrench(robot, pose)) + np.array([3.0, -2, 5, 0.3, 0.1, -0.2])
        np.testing.assert_allclose(sp.particular, np.linalg.pinv(S) @ -w, rtol=1e-10, atol=1e-9)
        N = np.asarray(sp.null_basis)
        np.testing.assert_allclose(N.T @ N, np.eye(2), atol=1e-12)
        np.testing.assert_allclose(S @ N, 0, atol=1e-12)
        assert sp.result == Status.successful


def test_singular_structure_matrix_is_a_status(robot):
    flat = eqx_replace(robot, attachments=jnp.zeros((8, 3)))  # all cables meet in one point: rank 3
    sp = T.tension_space(flat, POSE0)
    assert sp.result == Status.singular
    assert np.all(np.isfinite(sp.particular)) and np.all(np.isfinite(sp.null_basis))
    out = T.ctfr(flat, POSE0, throw=False)
    assert out.result == Status.singular and np.all(np.isfinite(out.tensions))
    with pytest.raises(Exception, match="rank deficient"):
        T.feasible_tensions(flat, POSE0)


def test_clip_and_centroid_closed_forms():
    sq = T.box_polygon(1.0, 8)  # [-1, 1]^2
    area, c = T.polygon_area_centroid(sq)
    assert float(area) == pytest.approx(4.0) and np.allclose(c, 0)
    tri = T.clip_polygon(sq, jnp.array([1.0, 1.0]), 0.0)  # x + y <= 0: triangle (-1,-1), (1,-1), (-1,1)
    area, c = T.polygon_area_centroid(tri)
    assert int(tri.count) == 3
    assert float(area) == pytest.approx(2.0)
    np.testing.assert_allclose(c, [-1 / 3, -1 / 3], atol=1e-14)
    cut = T.clip_polygon(sq, jnp.array([1.0, 0.0]), 0.5)  # x <= 0.5: rectangle 1.5 x 2
    area, c = T.polygon_area_centroid(cut)
    assert float(area) == pytest.approx(3.0)
    np.testing.assert_allclose(c, [-0.25, 0.0], atol=1e-14)
    empty = T.clip_polygon(sq, jnp.array([1.0, 0.0]), -2.0)
    assert int(empty.count) == 0 and float(T.polygon_area_centroid(empty)[0]) == 0.0


def _brute_force(sp, tmin, tmax, half, n=801):
    g = np.linspace(-half, half, n)
    P1, P2 = np.meshgrid(g, g, indexing="ij")
    phi = np.stack([P1.ravel(), P2.ravel()], 1)
    t = np.asarray(sp.particular)[None] + phi @ np.asarray(sp.null_basis).T
    ok = np.all((t >= tmin) & (t <= tmax), 1)
    return phi, ok, (g[1] - g[0]) ** 2


def _inside(poly, pts):
    v = np.asarray(poly.vertices)[: int(poly.count)]
    w = np.roll(v, -1, 0)
    cr = (w[:, 0] - v[:, 0])[None] * (pts[:, 1:2] - v[None, :, 1]) - (w[:, 1] - v[:, 1])[None] * (
        pts[:, 0:1] - v[None, :, 0])
    return np.all(cr >= 0, 1)


def test_ctfr_polygon_matches_brute_force_grid(robot):
    poses = random_poses(4, seed=1)
    batch = jax.vmap(lambda p: T.ctfr(robot, p, jnp.array([2.0, 1, -3, 0.2, 0, 0.1]), throw=False))(poses)
    for k in range(len(poses)):
        out = jax.tree.map(lambda a, k=k: a[k], batch)
        assert out.result == Status.successful
        half = float(np.max(np.abs(np.asarray(out.polygon.vertices)[: int(out.polygon.count)]))) * 1.05
        phi, ok, cell = _brute_force(out.space, 10.0, 400.0, half)
        inside = _inside(out.polygon, phi)
        # grid points strictly inside/outside agree; disagreements only within one cell of the boundary
        assert np.mean(inside != ok) < 0.01
        assert float(out.area) == pytest.approx(ok.sum() * cell, rel=0.01)
        np.testing.assert_allclose(out.centroid, phi[ok].mean(0), atol=0.01 * half)
        t = np.asarray(out.tensions)
        assert np.all(t >= 10) and np.all(t <= 400)
        assert int(out.polygon.count) <= 16


def test_table3_centroid_tensions(robot):
    """Seed 004 Table 3: 193.7 N on cables 1-4 and 210.3 N on cables 5-8 at (0, 0, 0.83)."""
    out = T.ctfr(robot, POSE0)
    np.testing.assert_allclose(out.tensions, [193.7] * 4 + [210.3] * 4, atol=0.05)


def test_infeasible_load_gives_status_not_nan(robot):
    load = jnp.array([0.0, 0.0, -5000.0, 0, 0, 0])
    out = T.ctfr(robot, POSE0, load, throw=False)
    assert out.result == Status.infeasible and np.all(np.isfinite(out.tensions))
    ft = T.feasible_tensions(robot, POSE0, load, throw=False)
    assert ft.result == Status.infeasible and np.all(np.isfinite(ft.tensions))
    with pytest.raises(Exception, match="no cable tensions"):
        T.ctfr(robot, POSE0, load)


def _np_ctfr_centroid(S, w, tmin, tmax, n=801):
    """Independent reference: null space by numpy SVD, the feasible set {φ : tmin <= t_p + Nφ
    <= tmax} on a grid sized by LP (scipy linprog: extent of the region along φ1, φ2), its
    centroid mapped back to tensions (basis-independent)."""
    from scipy.optimize import linprog

    tp = np.linalg.lstsq(S, -w, rcond=None)[0]
    N = np.linalg.svd(S)[2][6:].T  # (8, 2)
    A, b = np.vstack([N, -N]), np.concatenate([tmax - tp, tp - tmin])
    ext = [linprog(c, A_ub=A, b_ub=b, bounds=[(None, None)] * 2).x[k] for k in (0, 1) for c in
           (np.eye(2)[k], -np.eye(2)[k])]
    g1, g2 = np.linspace(ext[0], ext[1], n), np.linspace(ext[2], ext[3], n)
    P = np.stack(np.meshgrid(g1, g2, indexing="ij"), -1).reshape(-1, 2)
    inside = np.all(P @ A.T <= b, axis=1)
    return tp + N @ P[inside].mean(0), (ext[1] - ext[0], ext[3] - ext[2])


def test_feasible_tensions_r2_is_ctfr_centroid_by_brute_force_and_vmaps(robot):
    """r = 2: feasible_tensions is the CTFR centroid (Cui et al. 2019 Table 3), here against a
    numpy/scipy reference (SVD null space, LP-sized grid), under a load with N·m moments."""
    poses = random_poses(3, seed=2)
    load = jnp.array([3.0, -2.0, 4.0, 2.0, -1.5, 1.0])
    ft = jax.vmap(lambda p: T.feasible_tensions(robot, p, load, throw=False))(poses)
    for k, p in enumerate(poses):
        S = np.asarray(structure_matrix_closed_form(robot, p))
        w = np.asarray(gravity_wrench(robot, p)) + np.asarray(load)
        ref, widths = _np_ctfr_centroid(S, w, 10.0, 400.0)
        np.testing.assert_allclose(ft.tensions[k], ref, atol=2e-3 * max(widths))  # grid: 800 cells per width
        assert to_codes(ft.result)[k] == code(Status.successful)
        np.testing.assert_allclose(S @ np.asarray(ft.tensions[k]) + w, 0, atol=1e-9)
        np.testing.assert_allclose(ft.residual[k], 0, atol=1e-9)


def test_feasible_tensions_r1_is_midpoint_of_segment(robot):  # fast (~4 s): the r = 1 rule's only value check
    # 7 cables cannot hold the platform with positive tensions; a signed range tests the algorithm
    r7 = _subset(robot, range(7), tension_min=-300.0)
    pose = jnp.array([0.05, -0.02, 0.8, 0.02, 0.0, 0.01])
    ft = T.feasible_tensions(r7, pose)
    sp = T.tension_space(r7, pose)
    s = np.linspace(-2000, 2000, 400001)
    t = np.asarray(sp.particular)[None] + s[:, None] * np.asarray(sp.null_basis)[:, 0][None]
    ok = np.all((t >= -300) & (t <= 400), 1)
    assert 100 < ok.sum() < len(s) - 100
    mid = 0.5 * (s[ok].min() + s[ok].max())
    np.testing.assert_allclose(ft.tensions, np.asarray(sp.particular) + mid * np.asarray(sp.null_basis)[:, 0],
                               atol=0.02)


@pytest.mark.slow
def test_feasible_tensions_r3_qp_against_scipy(robot):
    extra = _subset(robot, [0, 1, 2, 3, 4, 5, 6, 7, 0])
    r9 = eqx_replace(extra, attachments=extra.attachments.at[8].set(jnp.array([0.0, 0.05, -0.04])),
                     anchors=extra.anchors.at[8].set(jnp.array([0.0, 0.9, 1.2])))
    pose = jnp.array([0.02, 0.01, 0.85, 0.0, 0.02, 0.0])
    ft = T.feasible_tensions(r9, pose)
    S = np.asarray(structure_matrix_closed_form(r9, pose))
    w = np.asarray(gravity_wrench(r9, pose))
    ref = minimize(lambda t: 0.5 * np.sum((t - 205.0) ** 2), np.full(9, 205.0), jac=lambda t: t - 205.0,
                   constraints=[{"type": "eq", "fun": lambda t: S @ t + w, "jac": lambda t: S}],
                   bounds=[(10, 400)] * 9, method="SLSQP", options={"ftol": 1e-12, "maxiter": 500})
    np.testing.assert_allclose(ft.tensions, ref.x, atol=1e-3)


def test_midpoint_and_local_stability(robot):
    tbar = float(T.tension_midpoint(robot))
    assert tbar == pytest.approx(205.0)  # (400 + 10)/2, not the paper's (400 - 10)/2 = 195
    assert float(T.local_stability(robot, jnp.full(8, 205.0))) == 0.0
    hi = float(T.local_stability(robot, jnp.full(8, 400.0)))
    lo = float(T.local_stability(robot, jnp.full(8, 10.0)))
    assert hi == pytest.approx(195 / 205) and lo == pytest.approx(195 / 205) and hi < 1
    assert abs(400 - 195) / 195 > 1  # the paper's half-range would break its own bound mu <= 1
    t = jnp.asarray(np.random.default_rng(0).uniform(10, 400, (100, 8)))
    mu = jax.vmap(lambda x: T.local_stability(robot, x))(t)
    assert np.all(mu <= 195 / 205 + 1e-15) and np.all(mu >= 0)
    np.testing.assert_allclose(mu, np.mean(np.abs(np.asarray(t) - 205), 1) / 205)


def test_ctfr_rejects_wrong_redundancy(robot):
    with pytest.raises(ValueError, match="2 degrees of redundancy.*r = 1"):
        T.ctfr(_subset(robot, range(7)), POSE0)
    few = T.tension_space(_subset(robot, range(5)), POSE0)  # no null space: the least-squares tensions
    assert few.null_basis.shape == (5, 0) and few.particular.shape == (5,)


def test_infeasible_answer_below_the_lower_limit_is_not_ok(robot):
    """A load whose best tensions (CTFR empty) dip a few hundred N below ``tension_min`` while
    none exceeds ``tension_max``: only the lower-limit check can flag it, and it must
    (status ``infeasible``, not ``successful``)."""
    load = jnp.array([391.2, 284.1, -211.1, -38.0, -18.7, 1.2])
    ft = T.feasible_tensions(robot, POSE0, load, throw=False)
    t = np.asarray(ft.tensions)
    assert 10.0 - 500.0 < t.min() < 10.0 - 1.0 and t.max() <= 400.0  # the case is what it says
    assert ft.result == Status.infeasible
