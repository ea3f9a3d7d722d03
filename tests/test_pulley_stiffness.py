"""The pose-minor kernel (css_kernel) on swivel pulleys: batched autodiff ``stiffness`` and the
CSS against references that do not use the kernel -- central differences of the statics
wrench (``statics.elastic_wrench`` through ``statics.cable_geometry`` / ``pulley.cable_path``),
the per-pose autodiff ``stiffness_from_lengths``, the hand contractions (no pulleys) -- and
the no-pulley path bit for bit against the straight-cable formulas the kernel had before."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.cable.path import vertical_axes
from cstiffjax.core.status import Status, code, to_codes
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics import geometry as statics
from cstiffjax.stiffness import css
from cstiffjax.stiffness import kernel as css_kernel
from cstiffjax.stiffness import matrix as st

from .helpers import central_difference, eight_cable_robot

BOX = eight_cable_robot(com=(0.05, -0.02, 0.1))
PULLEYS = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis), BOX,
                      (jnp.full(8, 0.06), vertical_axes(BOX.anchors)))
_AX = np.array(vertical_axes(BOX.anchors))
_AX[[1, 6]] = 0.0  # cables 2 and 7 straight
MIXED = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis), BOX, (jnp.full(8, 0.04), jnp.asarray(_AX)))


def _poses(n, seed):
    rng = np.random.default_rng(seed)
    return np.concatenate([rng.uniform(-0.3, 0.3, (n, 3)) + np.array([0, 0, 1.4]), rng.uniform(-0.2, 0.2, (n, 3))], 1)


P5 = _poses(5, 3)
T5 = np.random.default_rng(4).uniform(60.0, 300.0, (5, 8))
batch_k = jax.jit(lambda robot, p, t: st.stiffness(robot, p, t, throw=False))  # traced robot: layout "some"
twisted_wrench = jax.jit(lambda robot, pose, d, l0: statics.elastic_wrench(robot, statics.apply_twist(pose, d), l0))
status_jit = jax.jit(lambda robot, p, t: to_codes(st.pose_status(robot, p, t)))
TCPR8 = load_robot(example_path("tcpr8.toml"))
TCPR8_PULLEYS = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis), TCPR8,
                            (jnp.full(8, 0.02), vertical_axes(TCPR8.anchors)))
POSE0 = jnp.array([0.0, 0.0, 0.83, 0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def per_pose():
    return jax.jit(lambda robot, p, t: st.stiffness_from_lengths(robot, p, st.unstrained_lengths(robot, p, t)))


def test_layout_is_decided_before_tracing():
    assert (css_kernel.pulley_layout(BOX), css_kernel.pulley_layout(PULLEYS), css_kernel.pulley_layout(MIXED)) == (
        "none", "all", "some")
    assert jax.jit(lambda r: jnp.asarray(css_kernel.pulley_layout(r) == "some"))(BOX)  # traced: per-cable where


@pytest.mark.parametrize("robot", [PULLEYS, MIXED], ids=["pulleys", "mixed"])
def test_batch_stiffness_with_pulleys_matches_fd_of_statics_wrench_and_per_pose_path(robot, per_pose):
    K = np.asarray(st.stiffness(robot, jnp.asarray(P5), jnp.asarray(T5)).K)
    traced = batch_k(robot, jnp.asarray(P5), jnp.asarray(T5))
    K_traced, status = traced.K, traced.result
    assert np.all(np.asarray(status == Status.successful))
    np.testing.assert_allclose(K_traced, K, rtol=0, atol=1e-12 * np.abs(K).max())
    K_plain = np.asarray(st.stiffness(BOX, jnp.asarray(P5), jnp.asarray(T5)).K)
    assert np.abs(K - K_plain).max() > 1e-3 * np.abs(K_plain).max()  # the pulleys change K
    for i in (0, 3):
        l0 = st.unstrained_lengths(robot, P5[i], T5[i])
        fd = -central_difference(lambda d, i=i, l0=l0: twisted_wrench(robot, P5[i], d, l0), np.zeros(6))
        np.testing.assert_allclose(K[i], fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
    for i in range(5):
        ref = np.asarray(per_pose(robot, jnp.asarray(P5[i]), jnp.asarray(T5[i])))
        np.testing.assert_allclose(K[i], ref, rtol=0, atol=1e-11 * np.abs(ref).max())


def _old_frame_geometry(robot, p, R, nb, layout=None):
    """The kernel's straight-cable geometry before pulleys, verbatim (the bit-for-bit reference)."""
    att = css_kernel.trailing_axes(robot.attachments, nb)
    r = jnp.stack([sum(R[a, k][None] * att[:, k] for k in range(3)) for a in range(3)], axis=1)
    d = css_kernel.trailing_axes(robot.anchors, nb) - p[None] - r
    l = jnp.sqrt(css_kernel.axis_sum(d * d, axis=1))
    return r, d / l[:, None], l


def test_no_pulleys_bit_for_bit_the_straight_kernel(monkeypatch):
    P, T = jnp.asarray(P5), jnp.asarray(T5)
    K = np.asarray(st.stiffness(BOX, P, T).K)
    R = css_kernel.rotation(P.T[3:])
    new = jax.jit(lambda p, R: css_kernel.frame_geometry(BOX, p, R, 1))(P.T[:3], R)
    monkeypatch.setattr(css_kernel, "frame_geometry", _old_frame_geometry)
    old = jax.jit(lambda p, R: css_kernel.frame_geometry(BOX, p, R, 1))(P.T[:3], R)
    K_old = jax.jit(lambda p, t: css_kernel.spring_stiffness(BOX, p, t, 1))(P.T, T.T)
    for a, b in zip(new, old, strict=True):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    assert np.array_equal(K, np.moveaxis(np.asarray(K_old), 2, 0))


@pytest.mark.slow  # compile-bound (~1 min)
def test_chunked_status_matches_per_pose_status():
    P, T = np.array(_poses(7, 8)), np.array(np.random.default_rng(9).uniform(60.0, 300.0, (7, 8)))
    P[2, :3] = np.asarray(BOX.anchors[3]) - np.asarray(statics.frame(P[2])[1]) @ np.asarray(BOX.attachments[3])
    P[4, 1] = np.nan
    T[5, 2] = np.inf
    for robot in (BOX, PULLEYS):
        status = batch_k(robot, jnp.asarray(P), jnp.asarray(T)).result
        ref = [int(status_jit(robot, P[i], T[i])) for i in range(7)]
        assert np.asarray(to_codes(status)).tolist() == ref
    assert ref[4] == ref[5] == code(Status.invalid_input) and ref.count(code(Status.successful)) >= 4
    with pytest.raises(Exception, match="(?i)invalid"):
        st.stiffness(PULLEYS, jnp.asarray(P), jnp.asarray(T))


@pytest.mark.slow  # 144 s at load 10 (compile-bound: target and CSS kernel on the pulley path)
def test_css_with_pulleys_is_checked_by_the_statics_and_the_autodiff_stiffness():
    """Target and members on a pulley robot: the target K equals ``stiffness`` at the centroid
    tensions; every member's tensions balance the weight through the pulley structure matrix
    (statics, per pose), lie in the limits, and give ``stiffness`` within the tolerance of k_c."""
    robot, pose0 = TCPR8_PULLEYS, POSE0
    tgt = css.target_stiffness(robot, pose0)
    np.testing.assert_allclose(tgt.K, st.stiffness(robot, pose0, tgt.tensions).K, rtol=0,
                               atol=1e-10 * float(jnp.abs(tgt.K).max()))
    rng = np.random.default_rng(2)
    P = np.concatenate([rng.uniform(-0.08, 0.08, (24, 3)) + np.asarray(pose0[:3]),
                        rng.uniform(-0.02, 0.02, (24, 3))], 1)
    out = css.css_point(robot, jnp.asarray(P.T), tgt.K, 0.05)
    tol = np.asarray(css.tolerance(tgt.K, 0.05))
    members = np.flatnonzero(np.asarray(out.member))
    assert 3 <= len(members) < 24
    t = np.asarray(out.tensions[:, members]).T
    S = np.asarray(jax.vmap(statics.structure_matrix_closed_form, in_axes=(None, 0))(robot, P[members]))
    w = np.asarray(jax.vmap(statics.gravity_wrench, in_axes=(None, 0))(robot, P[members]))
    np.testing.assert_allclose(np.einsum("bij,bj->bi", S, t), -w, atol=1e-8)
    assert np.all(t >= float(robot.tension_min) - 1e-7) and np.all(t <= float(robot.tension_max) + 1e-7)
    K = np.asarray(st.stiffness(robot, jnp.asarray(P[members]), jnp.asarray(t)).K)
    assert np.all(np.abs(K - np.asarray(tgt.K)) <= tol * (1 + 1e-9))


@pytest.mark.slow
@pytest.mark.parametrize("inherent", ["spring", "paper"])
def test_css_membership_autodiff_agrees_with_hand_contractions_without_pulleys(inherent):
    """No pulleys: ``membership`` (autodiff stiffness, :func:`css_kernel.membership_stiffness`)
    and the membership through the hand-derived contractions (the test reference) give
    the same members, tensions and stability."""
    robot, pose0 = TCPR8, POSE0
    kc = css.target_stiffness(robot, pose0, inherent=inherent).K
    tol = css.tolerance(kc, 0.05)
    rng = np.random.default_rng(6)
    P = jnp.asarray(np.concatenate([rng.uniform(-0.08, 0.08, (32, 3)) + np.asarray(pose0[:3]),
                                    rng.uniform(-0.02, 0.02, (32, 3))], 1).T)

    def by_hand(P):
        R, r, u, l = css_kernel.geometry(robot, P, 1)
        tp, N, sing = css_kernel.null_space(css_kernel.structure_rows(r, u), css_kernel.load_wrench(robot, R, None, 1))
        K0, KL = css_kernel.contractions(robot, R, r, u, l, jnp.concatenate([tp[:, None], N], axis=1), inherent)
        return css_kernel.membership_from_stiffness(robot, tp, N, sing, K0, KL, kc, tol)

    ref = jax.jit(by_hand)(P)
    got = jax.jit(lambda P: css_kernel.membership(robot, P, kc, tol, None, inherent))(P)
    assert np.array_equal(got[0], ref[0]) and 3 <= int(np.sum(got[0])) < 32
    for a, b in zip(got[1:], ref[1:], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("inherent", ["spring", "paper"])
def test_membership_stiffness_merges_the_particular_set_into_K0(inherent):
    """``membership_stiffness`` (one autodiff set for ``K0`` and the particular solution's
    ``K_lin[0]``, as the slabs add them) equals ``affine_stiffness_sets`` summed, on
    pulleys with a mixed layout, at random tensions (not an equilibrium: ``K`` is linear
    in them either way)."""
    P = jnp.asarray(P5.T)
    V = jnp.asarray(np.random.default_rng(8).uniform(-50.0, 300.0, (8, 3, 5)))
    K0, KL = jax.jit(lambda p, v: css_kernel.affine_stiffness_sets(MIXED, p, v, inherent, 1))(P, V)
    C0, KL2 = jax.jit(lambda p, v: css_kernel.membership_stiffness(MIXED, p, v, inherent, 1))(P, V)
    scale = np.max(np.abs(K0))
    np.testing.assert_allclose(C0, K0 + KL[0], rtol=0, atol=1e-12 * scale)
    assert np.all(np.asarray(KL2[0]) == 0)
    np.testing.assert_allclose(KL2[1:], KL[1:], rtol=0, atol=1e-12 * np.max(np.abs(KL[1:])))
