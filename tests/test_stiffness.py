import os
import subprocess
import sys
from pathlib import Path

import hypothesis.extra.numpy as hnp
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cstiffjax.core import lie
from cstiffjax.statics import geometry as statics
from cstiffjax.stiffness import matrix as stiffness

from .helpers import (
    central_difference,
    eight_cable_robot,
    lab_robot,
    np_cables,
    np_fd,
    np_frame,
    np_potential,
    np_spring_wrench,
)

ROBOT, REC = lab_robot("example02")
BOX = eight_cable_robot()
BOX_COM = eight_cable_robot(com=(0.05, -0.02, 0.1))


def closed_form_K1(robot, pose, t):
    """Independent numpy closed form of K1 = -sum t_i d[u_i; r_i x u_i]/dx (twist coordinates)."""
    p, R = (np.asarray(a) for a in statics.frame(pose))
    K1 = np.zeros((6, 6))
    for a, b, ti in zip(np.asarray(robot.anchors), np.asarray(robot.attachments), np.asarray(t), strict=True):
        r = R @ b
        d = a - p - r
        l = np.linalg.norm(d)
        u = d / l
        P = (np.eye(3) - np.outer(u, u)) / l
        hr, hu = np.asarray(lie.hat(r)), np.asarray(lie.hat(u))
        du = np.hstack([-P, P @ hr])  # du/d[dp, dtheta]
        dm = np.hstack([-hr @ P, hu @ hr + hr @ P @ hr])  # d(r x u)/d[dp, dtheta]
        K1 -= ti * np.vstack([du, dm])
    return K1


def test_stiffness_matches_fd_of_wrench():
    pose, l0, w = REC.pose[0], REC.l0[0], REC.wrench[0]
    K = stiffness.stiffness_from_lengths(ROBOT, pose, l0)
    fd = -central_difference(lambda d: statics.elastic_wrench(ROBOT, statics.apply_twist(pose, d), l0, w), np.zeros(6))
    np.testing.assert_allclose(K, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())


def test_split_against_closed_forms():
    pose = jnp.array([0.1, -0.2, 1.3, 0.1, 0.05, -0.2])
    t = jnp.linspace(50.0, 120.0, 8)
    sp = stiffness.stiffness_split(BOX, pose, t)
    np.testing.assert_allclose(sp.K1, closed_form_K1(BOX, pose, t), atol=1e-9)
    # Cui et al. 2019 eq. (19) with l0 the unstrained lengths
    S = np.asarray(statics.structure_matrix_closed_form(BOX, pose))
    l = np.asarray(statics.cable_lengths(BOX, pose))
    l0 = l * np.asarray(BOX.EA) / (np.asarray(BOX.EA) + np.asarray(t))
    np.testing.assert_allclose(sp.K2, S @ np.diag(np.asarray(BOX.EA) / l0) @ S.T, rtol=1e-12)
    np.testing.assert_allclose(sp.K_gravity, 0.0, atol=1e-12)  # com at the reference point
    np.testing.assert_allclose(sp.K, stiffness.stiffness(BOX, pose, t).K, rtol=1e-10, atol=1e-6)


def test_K1_is_linear_in_tensions():
    pose = jnp.array([0.0, 0.1, 1.5, 0.0, 0.1, 0.0])
    t1, t2 = jnp.linspace(10, 80, 8), jnp.linspace(90, 20, 8)
    k = lambda t: stiffness.stiffness_split(BOX, pose, t).K1  # noqa: E731
    np.testing.assert_allclose(k(2 * t1 + 3 * t2), 2 * k(t1) + 3 * k(t2), atol=1e-9)


@settings(max_examples=25, deadline=None)
@given(
    hnp.arrays(np.float64, 3, elements=st.floats(-0.4, 0.4)),
    hnp.arrays(np.float64, 3, elements=st.floats(-0.3, 0.3)),
)
def test_K_symmetric_at_equilibrium_without_external_load(dp, rot):
    """Spring cables in equilibrium with gravity only (com off the reference point too)."""
    pose = jnp.concatenate([jnp.asarray(dp) + jnp.array([0.0, 0.0, 1.5]), jnp.asarray(rot)])
    for robot in (BOX, BOX_COM):
        t = statics.inverse_statics(robot, pose, throw=False).tensions
        K = np.asarray(stiffness.stiffness_split(robot, pose, t).K)
        assert np.abs(K - K.T).max() <= 1e-10 * np.abs(K).max()


@settings(max_examples=20, deadline=None)
@given(hnp.arrays(np.float64, 6, elements=st.floats(-20.0, 20.0)))
def test_asymmetry_is_the_external_moment_and_covariant_K_is_symmetric(ext):
    pose = jnp.array([0.1, 0.0, 1.4, 0.1, -0.1, 0.2])
    ext = jnp.asarray(ext)
    t = statics.inverse_statics(BOX_COM, pose, ext, throw=False).tensions
    K = stiffness.stiffness_split(BOX_COM, pose, t).K
    m_c = -ext[3:]  # at equilibrium the conservative moment balances the external one
    np.testing.assert_allclose(K - K.T, jnp.zeros((6, 6)).at[3:, 3:].set(lie.hat(m_c)), atol=1e-8)
    Kc = stiffness.covariant_stiffness(K, m_c)
    assert np.abs(Kc - Kc.T).max() <= 1e-10 * np.abs(K).max()


def test_euler_coordinates_against_fd():
    pose, l0, w = REC.pose[5], REC.l0[5], REC.wrench[5]
    Kq = stiffness.to_euler_coordinates(ROBOT, pose, l0, w)
    q0 = np.concatenate([np.asarray(pose[:3]), np.asarray(stiffness.euler_angles(pose))])

    def generalized_force(q):
        # independent route: virtual work with finite-difference B = d twist / dq
        def pose_of(qq):
            return jnp.concatenate([qq[:3], lie.log(stiffness._rpy_matrix(qq[3:]))])

        W = statics.elastic_wrench(ROBOT, pose_of(q), l0, w)
        R = np.asarray(stiffness._rpy_matrix(q[3:]))
        B = np.zeros((6, 6))
        B[:3, :3] = np.eye(3)
        for j in range(3):
            e = np.zeros(3)
            e[j] = 1e-6
            dR = (np.asarray(stiffness._rpy_matrix(q[3:] + e)) - np.asarray(stiffness._rpy_matrix(q[3:] - e))) / 2e-6
            B[3:, 3 + j] = np.asarray(lie.vee(dR @ R.T))
        return B.T @ np.asarray(W)

    fd = -central_difference(generalized_force, q0, 1e-6)
    np.testing.assert_allclose(Kq, fd, rtol=1e-4, atol=1e-4 * np.abs(fd).max())
    # at equilibrium and zero rotation, the Euler K equals the twist K to first order
    K = stiffness.stiffness_from_lengths(ROBOT, pose, l0)
    assert np.abs(Kq - K).max() < 1e-2 * np.abs(K).max()


def test_jit_vmap_grad_of_stiffness():
    poses = REC.pose[:4]
    t = jax.vmap(lambda p, w: statics.inverse_statics(ROBOT, p, w, throw=False).tensions)(poses, REC.wrench[:4])
    Ks = jax.jit(jax.vmap(lambda p, tt: stiffness.stiffness(ROBOT, p, tt).K))(poses, t)
    assert Ks.shape == (4, 6, 6)
    np.testing.assert_allclose(Ks[1], stiffness.stiffness(ROBOT, poses[1], t[1]).K, rtol=1e-12)
    f = lambda tt: jnp.trace(stiffness.stiffness(ROBOT, poses[0], tt).K)  # noqa: E731
    np.testing.assert_allclose(jax.grad(f)(t[0]), central_difference(f, np.asarray(t[0]), 1e-3), rtol=1e-6)


# ---------------- com offset, turned attachments, external moments: independent references
def _loaded_equilibrium():
    """tcpr8 with its com moved off the reference point, a pose with rotation, several N·m
    of external moment, CTFR-centroid tensions (from tests/test_statics.py's design)."""
    from .test_statics import EXT_M, POSE_M, TCPR_COM, _designed_lengths

    l0, t = _designed_lengths(TCPR_COM, POSE_M, EXT_M)
    return TCPR_COM, POSE_M, EXT_M, l0, t


def test_K_with_com_offset_and_moments_matches_fd_of_numpy_wrench_and_energy_hessian():
    """K = -∂W/∂x by central differences of a numpy wrench written from scratch (scipy
    rotations); its antisymmetric part is hat(-m_ext); the covariant stiffness
    K - ½ hat(m_c) is the Hessian of the numpy potential energy in twist coordinates."""
    robot, pose, ext, l0, t = _loaded_equilibrium()
    K = np.asarray(stiffness.stiffness(robot, jnp.asarray(pose), jnp.asarray(t)).K)
    fd = -np_fd(lambda d: np_spring_wrench(robot, l0, ext, pose, d), 6, 1e-7)
    np.testing.assert_allclose(K, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
    m_c = -ext[3:]
    asym = np.zeros((6, 6))
    asym[3:, 3:] = np.array([[0, -m_c[2], m_c[1]], [m_c[2], 0, -m_c[0]], [-m_c[1], m_c[0], 0]])
    np.testing.assert_allclose(K - K.T, asym, atol=1e-6 * np.abs(K).max())
    assert np.abs(asym).max() > 50 * 1e-6 * np.abs(K).max()  # the asymmetry is well resolved
    H = np_fd(lambda d: np_fd(lambda e: np_potential(robot, l0, ext, pose, d + e), 6, 1e-5), 6, 1e-5)
    Kc = np.asarray(stiffness.covariant_stiffness(jnp.asarray(K), jnp.asarray(m_c)))
    np.testing.assert_allclose(Kc, 0.5 * (H + H.T), rtol=1e-4, atol=1e-4 * np.abs(H).max())
    # gravity part of the split with the com offset: -[[0, 0], [0, hat(f) hat(R c)]]
    _, R = np_frame(pose)
    f = float(robot.platform_mass) * np.asarray(robot.gravity)
    Kg = np.zeros((6, 6))
    Kg[3:, 3:] = -np.asarray(lie.hat(f)) @ np.asarray(lie.hat(R @ np.asarray(robot.com)))
    np.testing.assert_allclose(stiffness.stiffness_split(robot, jnp.asarray(pose), jnp.asarray(t)).K_gravity, Kg,
                               atol=1e-10)


def test_K2_is_fd_of_the_tension_magnitudes():
    """K2 = S diag(EA/l0) Sᵀ is the part of -∂W/∂x from the change of the tension
    magnitudes at fixed directions: K2 = -S0 ∂t/∂x with t = EA (l - l0)/l0, S0 = [u; r × u]
    written in numpy, ∂t/∂x by central differences of numpy lengths (no structure matrix
    of the code)."""
    robot, pose, _ext, l0, t = _loaded_equilibrium()
    p, R = np_frame(pose)
    r, d, l = np_cables(robot, p, R)
    u = d / l[:, None]
    S0 = np.vstack([u.T, np.cross(r, u).T])
    dt = np_fd(lambda tw: np.asarray(robot.EA) * (np_cables(robot, *np_frame(pose, tw))[2] - l0) / l0, 6, 1e-7)
    K2 = -S0 @ dt
    sp = stiffness.stiffness_split(robot, jnp.asarray(pose), jnp.asarray(t))
    np.testing.assert_allclose(sp.K2, K2, rtol=1e-6, atol=1e-6 * np.abs(K2).max())
def test_batch_stiffness_matches_fd_and_the_per_pose_path():
    """``stiffness`` on a (n, 6) batch (pose-minor autodiff) = finite differences of the
    spring wrench at ``l0 = l EA/(EA + t)`` (com off the reference point) = the per-pose
    twist-Jacobian path; shapes (6,), (n, 6) and (2, 2, 6) all work."""
    rng = np.random.default_rng(4)
    poses = np.concatenate([rng.uniform(-0.3, 0.3, (4, 3)) + np.array([0, 0, 1.4]), rng.uniform(-0.2, 0.2, (4, 3))], 1)
    t = rng.uniform(20.0, 150.0, (4, 8))
    K = stiffness.stiffness(BOX_COM, poses, t).K
    assert K.shape == (4, 6, 6)
    for i in range(4):
        l0 = stiffness.unstrained_lengths(BOX_COM, poses[i], t[i])
        fd = -central_difference(lambda d, i=i, l0=l0: statics.elastic_wrench(
            BOX_COM, statics.apply_twist(poses[i], d), l0), np.zeros(6))
        np.testing.assert_allclose(K[i], fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
        np.testing.assert_allclose(K[i], stiffness.stiffness_from_lengths(BOX_COM, poses[i], l0), atol=1e-9)
    np.testing.assert_allclose(stiffness.stiffness(BOX_COM, poses[2], t[2]).K, K[2], rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(stiffness.stiffness(BOX_COM, poses.reshape(2, 2, 6), t.reshape(2, 2, 8)).K,
                               K.reshape(2, 2, 6, 6), rtol=1e-13, atol=1e-9)


def test_css_kernel_autodiff_stiffness_matches_hand_contractions():
    """The CSS kernel's K0 and K_lin (autodiff, pose-minor) against the hand-derived
    contractions (the test reference), both inherent laws, com off the reference point."""
    from cstiffjax.stiffness import kernel as ck

    rng = np.random.default_rng(5)
    P = jnp.asarray(np.concatenate([rng.uniform(-0.3, 0.3, (5, 3)) + np.array([0, 0, 1.4]),
                                    rng.uniform(-0.2, 0.2, (5, 3))], 1).T)
    V = jnp.asarray(rng.normal(0.0, 50.0, (8, 3, 5)))
    R, r, u, l = ck.geometry(BOX_COM, P, 1)
    for inherent in ("spring", "paper"):
        K0, KL = ck.affine_stiffness_sets(BOX_COM, P, V, inherent, 1)
        K0_ref, KL_ref = ck.contractions(BOX_COM, R, r, u, l, V, inherent)
        np.testing.assert_allclose(K0, K0_ref, atol=1e-9 * float(jnp.abs(K0_ref).max()))
        np.testing.assert_allclose(KL, KL_ref, atol=1e-9 * float(jnp.abs(KL_ref).max()))


_SHARDED = """
import numpy as np
from cstiffjax.stiffness import matrix as S
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
import jax
assert len(jax.devices()) == 2
robot = load_robot(example_path("tcpr8.toml"))
rng = np.random.default_rng(5)
n = 64 * 2 * S.SHARD_MIN + 7  # sharded over both devices, padded
P = np.column_stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.15, 0.15, n), rng.uniform(0.6, 1.1, n),
                     rng.uniform(-0.05, 0.05, (n, 3))])
T = rng.uniform(60.0, 300.0, (n, 8))
P[3, 1] = np.nan
from cstiffjax.core.status import Status, to_codes
out = S.stiffness(robot, P, T, throw=False)
K, status = out.K, out.result
vm = jax.vmap(lambda p, t: S.stiffness(robot, p, t, throw=False))(P, T)  # one pose at a time: never sharded
Kv, sv = vm.K, vm.result
ok = np.asarray(sv == Status.successful)
assert np.array_equal(np.asarray(to_codes(status)), np.asarray(to_codes(sv))) and ok.sum() == n - 1
err = np.abs(np.asarray(K)[ok] - np.asarray(Kv)[ok]).max() / np.abs(np.asarray(Kv)[ok]).max()
assert err < 1e-13, err
print("ok")
"""


@pytest.mark.slow  # a fresh process with two host devices (compiles twice)
def test_batch_split_over_two_host_devices_matches_one_pose_at_a_time():
    """With two CPU devices a large batch's chunks go to both (``shard_map``); K and the status
    must equal the one-pose path (vmapped, never split), padding and a NaN pose included."""
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
           "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", _SHARDED], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-3000:]
