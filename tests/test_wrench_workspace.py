"""Wrench-feasible and wrench-closure workspaces against brute-force references.

Membership: a linear program per extreme wrench (scipy linprog, HiGHS): is there t in
[tmin, tmax] with S t = -(w + W_g)? Solved as max δ with tmin + δ <= t <= tmax - δ, so
δ* also says how far the case is from the boundary (in tension, N). Margin: every
5-column combination's normal by numpy SVD (a second implementation of hyperplane
shifting). Closure: an LP positive-spanning check. S and W_g come from the statics module.
"""

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import linprog

from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics import geometry as statics
from cstiffjax.workspace.wrench_closure import wrench_closure
from cstiffjax.workspace.wrench_feasible import WrenchSet, wrench_feasible

LP_OPTIONS = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}  # the reference's own
BOUNDARY = 1e-9  # N: cases with |δ*| below this are on the boundary (not asserted)
B = 16  # poses per jitted batch (one compile)


@pytest.fixture(scope="module")
def robot():
    return load_robot(example_path("tcpr8.toml"))


@pytest.fixture(scope="module")
def feasible_fn(robot):
    return jax.jit(lambda P, ws: wrench_feasible(robot, P, ws, length_scale=0.5))


@pytest.fixture(scope="module")
def closure_fn(robot):
    return jax.jit(lambda P: wrench_closure(robot, P))


def random_poses(rng, n, rot=0.1):
    return np.column_stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.3, 0.3, n), rng.uniform(0.3, 1.5, n),
                            rng.uniform(-rot, rot, (n, 3))])


def random_box(rng):
    c = rng.normal(size=6) * np.r_[4, 4, 4, 0.4, 0.4, 0.4]
    h = rng.uniform(0, 1, 6) * np.r_[8, 8, 8, 0.8, 0.8, 0.8]
    return WrenchSet.box(c - h, c + h)


def lp_delta(S, q, tmin, tmax):
    """max δ s.t. S t = q, tmin + δ <= t <= tmax - δ (δ* >= 0 iff q is available)."""
    m = S.shape[1]
    A_ub = np.block([[-np.eye(m), np.ones((m, 1))], [np.eye(m), np.ones((m, 1))]])
    b_ub = np.r_[np.full(m, -tmin), np.full(m, tmax)]
    res = linprog(np.r_[np.zeros(m), -1.0], A_ub=A_ub, b_ub=b_ub, A_eq=np.c_[S, np.zeros(6)], b_eq=q,
                  bounds=[(None, None)] * m + [(-(tmax - tmin), tmax - tmin)], method="highs", options=LP_OPTIONS)
    assert res.status == 0, res.message
    return -res.fun


def reference_delta(robot, pose, ws):
    S = np.asarray(statics.structure_matrix_closed_form(robot, pose))
    Wg = np.asarray(statics.gravity_wrench(robot, pose))
    tmin, tmax = float(robot.tension_min), float(robot.tension_max)
    return min(lp_delta(S, -(w + Wg), tmin, tmax) for w in ws.extreme_points())


def reference_margin(robot, pose, ws, L):
    """Capacity margin by brute force: SVD normal of every independent 5-column set."""
    S = np.asarray(statics.structure_matrix_closed_form(robot, pose))
    Wg = np.asarray(statics.gravity_wrench(robot, pose))
    tmin, tmax = float(robot.tension_min), float(robot.tension_max)
    c, h = S.sum(1) * (tmin + tmax) / 2, (tmax - tmin) / 2
    q = -(ws.extreme_points() + Wg)
    best = np.inf
    for J in itertools.combinations(range(S.shape[1]), 5):
        _, sv, vt = np.linalg.svd(S[:, J].T)
        if sv[-1] < 1e-10 * sv[0]:
            continue
        n = vt[-1]
        d = h * np.abs(n @ S).sum()
        scale = np.sqrt(n[:3] @ n[:3] + L**2 * n[3:] @ n[3:])
        best = min(best, (d - np.abs((q - c) @ n)).min() / scale)
    return best


def test_membership_matches_lp_on_random_poses_and_sets(robot, feasible_fn):
    rng = np.random.default_rng(11)
    agree, members = 0, 0
    for _ in range(2):
        P = random_poses(rng, B)
        ws = random_box(rng)
        out = feasible_fn(jnp.asarray(P.T), ws)
        for k in range(B):
            delta = reference_delta(robot, P[k], ws)
            if abs(delta) < BOUNDARY:
                continue
            assert bool(out.member[k]) == (delta > 0), (P[k], delta, float(out.margin[k]))
            assert (float(out.margin[k]) > 0) == (delta > 0)
            agree += 1
            members += bool(out.member[k])
    assert agree >= 30 and 5 <= members <= agree - 5  # both outcomes exercised


def test_membership_at_the_boundary_scaled_sets(robot, feasible_fn):
    """Boxes scaled about their centre to (1 ± 1e-6) of the largest feasible size λ*
    (one joint LP over all 64 vertices) must be in / out."""
    rng = np.random.default_rng(5)
    P = random_poses(rng, B, rot=0.05)
    tmin, tmax = float(robot.tension_min), float(robot.tension_max)
    c = np.r_[1.0, -2.0, 3.0, 0.1, 0.0, -0.1]
    h = np.r_[6, 5, 4, 0.5, 0.6, 0.4]
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=6)))
    lam = np.empty(B)
    for k in range(B):
        S = np.asarray(statics.structure_matrix_closed_form(robot, P[k]))
        Wg = np.asarray(statics.gravity_wrench(robot, P[k]))
        V, m = len(signs), S.shape[1]
        # variables: t_v (V*m), λ; S t_v + λ S0 (signs_v * h) = -(c + Wg) ... written as equality rows
        A_eq = np.zeros((6 * V, V * m + 1))
        b_eq = np.zeros(6 * V)
        for v in range(V):
            A_eq[6 * v:6 * v + 6, v * m:(v + 1) * m] = S
            A_eq[6 * v:6 * v + 6, -1] = signs[v] * h
            b_eq[6 * v:6 * v + 6] = -(c + Wg)
        res = linprog(np.r_[np.zeros(V * m), -1.0], A_eq=A_eq, b_eq=b_eq,
                      bounds=[(tmin, tmax)] * (V * m) + [(0, 1e3)], method="highs", options=LP_OPTIONS)
        lam[k] = -res.fun if res.status == 0 else np.nan
    ok = np.isfinite(lam) & (lam > 1e-3)
    assert ok.sum() >= B // 2
    for f, expect in ((1 - 1e-6, True), (1 + 1e-6, False)):
        for k in np.flatnonzero(ok):
            ws = WrenchSet.box(c - f * lam[k] * h, c + f * lam[k] * h)
            out = feasible_fn(jnp.asarray(P[k:k + 1].T.repeat(B, 1)), ws)  # same compiled shape
            assert bool(out.member[0]) == expect, (k, lam[k], f, float(out.margin[0]))
            assert abs(float(out.margin[0])) < 1e-3 * max(1.0, lam[k])  # the margin vanishes there too


def test_margin_matches_brute_force_box_and_vertices(robot, feasible_fn):
    rng = np.random.default_rng(3)
    P = random_poses(rng, B)
    box = random_box(rng)
    verts = WrenchSet.vertices(rng.normal(size=(5, 6)) * np.r_[6, 6, 6, 0.6, 0.6, 0.6])
    for ws in (box, verts):
        out = feasible_fn(jnp.asarray(P.T), ws)
        for k in range(0, B, 3):
            ref = reference_margin(robot, P[k], ws, 0.5)
            np.testing.assert_allclose(float(out.margin[k]), ref, rtol=1e-9, atol=1e-9)


def test_pseudo_inverse_rows_from_the_qr_match_numpy_pinv(robot):
    """``P = S⁺ᵀ`` rows by triangular solves with the null space's QR factor (replacing the
    Gram/Cholesky route) against numpy's SVD pseudo-inverse: ``P[i] = row i of pinv(S)``."""
    from cstiffjax.stiffness import kernel as css_kernel
    from cstiffjax.workspace.wrench_feasible import pseudo_inverse_rows

    def rows(X):
        _, r, u, _ = css_kernel.geometry(robot, X, 1)
        s = css_kernel.structure_rows(r, u)
        _, _, singular, R = css_kernel.qr_null_space(s, jnp.zeros((6, X.shape[1])))
        return pseudo_inverse_rows(s, R), singular

    P = random_poses(np.random.default_rng(9), 4, rot=0.3)
    Pm, singular = jax.jit(rows)(jnp.asarray(P.T))
    assert not np.any(np.asarray(singular))
    for k in range(4):
        ref = np.linalg.pinv(np.asarray(statics.structure_matrix_closed_form(robot, P[k])))  # (m, 6)
        np.testing.assert_allclose(np.asarray(Pm[..., k]), ref, rtol=0, atol=1e-10 * np.abs(ref).max())


def test_margin_of_every_pose_and_both_signs_match_brute_force(robot, feasible_fn):
    """The signed-square minimum over the facets (one square root per pose) gives the
    brute-force capacity margin on every pose of a batch, feasible and infeasible."""
    rng = np.random.default_rng(21)
    P = random_poses(rng, B)
    ws = WrenchSet.box(-np.r_[9, 9, 9, 0.9, 0.9, 0.9], np.r_[9, 9, 9, 0.9, 0.9, 0.9])
    out = feasible_fn(jnp.asarray(P.T), ws)
    ref = np.array([reference_margin(robot, P[k], ws, 0.5) for k in range(B)])
    np.testing.assert_allclose(np.asarray(out.margin), ref, rtol=1e-9, atol=1e-9)
    assert np.any(ref > 1e-6) and np.any(ref < -1e-6)  # both signs exercised
    np.testing.assert_array_equal(np.asarray(out.member), ref >= 0)


@pytest.mark.slow  # two more compiles (6 and 7 cables); the 8-cable margin is checked in the fast tests
def test_six_and_seven_cable_facets_match_brute_force(robot):
    rng = np.random.default_rng(4)
    P = random_poses(rng, 3, rot=0.05)
    ws = WrenchSet.box(-np.r_[2, 2, 2, 0.2, 0.2, 0.2], np.r_[2, 2, 2, 0.2, 0.2, 0.2])
    names = ("anchors", "attachments", "EA", "mass_per_length", "pulley_radius", "pulley_axis", "length_gain",
             "tension_gain")  # every per-cable field
    for m in (6, 7):
        sub = eqx.tree_at(lambda r: tuple(getattr(r, k) for k in names), robot,
                          tuple(getattr(robot, k)[:m] for k in names))
        out = jax.jit(lambda P, sub=sub: wrench_feasible(sub, P, ws))(jnp.asarray(P.T))
        for k in range(3):
            np.testing.assert_allclose(float(out.margin[k]), reference_margin(sub, P[k], ws, 1.0),
                                       rtol=1e-9, atol=1e-9)


def test_bad_wrench_sets_and_limits_are_refused(robot):
    with pytest.raises(ValueError, match="component 2: need finite lower <= upper"):
        WrenchSet.box(np.zeros(6), np.r_[1, 1, -1, 1, 1, 1])
    with pytest.raises(ValueError, match="row 1 is not finite"):
        WrenchSet.vertices([[0] * 6, [0, 0, np.nan, 0, 0, 0]])
    unbounded = eqx.tree_at(lambda r: r.tension_max, robot, jnp.asarray(np.inf))
    with pytest.raises(ValueError, match="needs finite tension limits"):
        wrench_feasible(unbounded, jnp.zeros(6).at[2].set(0.9), WrenchSet.box(np.zeros(6), np.zeros(6)))


def lp_positive_span(S):
    """max s s.t. S t = 0, t_i >= s, Σ t = 1: s* > 0 iff a strictly positive null vector exists."""
    m = S.shape[1]
    res = linprog(np.r_[np.zeros(m), -1.0], A_ub=np.c_[-np.eye(m), np.ones(m)], b_ub=np.zeros(m),
                  A_eq=np.vstack([np.c_[S, np.zeros(6)], np.r_[np.ones(m), 0.0]]), b_eq=np.r_[np.zeros(6), 1.0],
                  bounds=[(None, None)] * (m + 1), method="highs", options=LP_OPTIONS)
    assert res.status == 0
    return -res.fun


def test_wrench_closure_matches_lp_and_dense_margin(robot, closure_fn):
    from scipy.linalg import null_space

    rng = np.random.default_rng(8)
    P = np.vstack([random_poses(rng, B // 2, rot=0.2),
                   np.column_stack([rng.uniform(-1.5, 1.5, B // 2), rng.uniform(-1, 1, B // 2),
                                    rng.uniform(-0.5, 2.3, B // 2), rng.uniform(-1, 1, (B // 2, 3))])])
    out = closure_fn(jnp.asarray(P.T))
    theta = np.linspace(0, 2 * np.pi, 200001)
    circle = np.stack([np.cos(theta), np.sin(theta)])
    seen = set()
    for k in range(B):
        S = np.asarray(statics.structure_matrix_closed_form(robot, P[k]))
        s_lp = lp_positive_span(S)
        if abs(s_lp) > BOUNDARY:
            assert bool(out.member[k]) == (s_lp > 0), (P[k], s_lp)
            seen.add(s_lp > 0)
        dense = np.max(np.min(null_space(S) @ circle, axis=0))  # basis-independent
        mu = float(out.margin[k])
        assert dense - 1e-12 <= mu <= dense + 1e-4
    assert seen == {True, False}
