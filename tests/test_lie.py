import hypothesis.extra.numpy as hnp
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cstiffjax.core import lie

from .helpers import central_difference

vectors = hnp.arrays(np.float64, 3, elements=st.floats(-1.0, 1.0))


def _rodrigues_reference(v):
    """Independent reference: matrix exponential by a long Taylor series in numpy."""
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    out, term = np.eye(3), np.eye(3)
    for k in range(1, 40):
        term = term @ K / k
        out = out + term
    return out


@settings(max_examples=60, deadline=None)
@given(vectors, st.floats(0.0, np.pi - 1e-6))
def test_log_exp_roundtrip_on_ball(direction, angle):
    n = np.linalg.norm(direction)
    v = direction / n * angle if n > 1e-3 else direction * angle
    np.testing.assert_allclose(lie.log(lie.exp(v)), v, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(hnp.arrays(np.float64, 3, elements=st.floats(-3.0, 3.0)))
def test_exp_matches_series_and_is_rotation(v):
    R = np.asarray(lie.exp(v))
    np.testing.assert_allclose(R, _rodrigues_reference(v), atol=1e-12)
    lie.as_rotation(R, atol=1e-12)


def test_hat_vee():
    v = jnp.array([0.1, -2.0, 3.0])
    w = jnp.array([1.0, 0.5, -0.2])
    np.testing.assert_allclose(lie.hat(v) @ w, jnp.cross(v, w))
    np.testing.assert_allclose(lie.vee(lie.hat(v)), v)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-7, 1e-4, 1e-3, 0.5, 2.0])
def test_gradients_finite_and_correct_near_zero(angle):
    v = angle * np.array([0.6, -0.8, 0.0]) + np.array([0.0, 0.0, angle / 3])
    J_exp = jax.jacfwd(lie.exp)(jnp.asarray(v))
    assert np.all(np.isfinite(J_exp))
    J_log = jax.jacfwd(lambda x: lie.log(lie.exp(x)))(jnp.asarray(v))
    np.testing.assert_allclose(J_log, np.eye(3), atol=1e-9)
    if angle >= 1e-4:  # FD is only meaningful when h << angle or on the smooth exp
        np.testing.assert_allclose(J_exp, central_difference(lie.exp, v, 1e-6), atol=1e-8)


def test_log_at_identity_has_finite_gradient():
    J = jax.jacfwd(lie.log)(jnp.eye(3))
    assert np.all(np.isfinite(J))
    # d log / dR at identity is the vee map on the skew part
    np.testing.assert_allclose(J[0, 2, 1], 0.5)
    np.testing.assert_allclose(J[0, 1, 2], -0.5)


@pytest.mark.parametrize("gap", [0.0, 1e-12, 1e-8, 1e-5, 1e-2])
def test_log_near_pi(gap):
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    v = (np.pi - gap) * axis
    out = np.asarray(lie.log(lie.exp(v)))
    if gap == 0.0:  # ±pi·axis are the same rotation
        assert min(np.abs(out - v).max(), np.abs(out + v).max()) < 1e-7
    else:
        np.testing.assert_allclose(out, v, atol=1e-7)
    np.testing.assert_allclose(lie.exp(out), lie.exp(v), atol=1e-12)


def test_rotation_distance():
    R1 = lie.exp(jnp.array([0.1, 0.2, -0.3]))
    d = jnp.array([0.0, 0.3, 0.4])
    R2 = R1 @ lie.exp(d)
    np.testing.assert_allclose(lie.rotation_distance(R1, R2), 0.5, atol=1e-14)
    # bi-invariance
    Q = lie.exp(jnp.array([1.0, -0.5, 0.2]))
    np.testing.assert_allclose(lie.rotation_distance(Q @ R1, Q @ R2), 0.5, atol=1e-13)


def test_as_rotation_errors():
    R = np.asarray(lie.exp(jnp.array([0.3, 0.1, 0.2])))
    np.testing.assert_array_equal(lie.as_rotation(R), R)
    with pytest.raises(ValueError, match="orthogonality error.*det"):
        lie.as_rotation(R * 1.01)
    with pytest.raises(ValueError, match=r"det = -1"):
        lie.as_rotation(-R)
    with pytest.raises(ValueError, match="shape"):
        lie.as_rotation(np.eye(2))
    with pytest.raises(ValueError, match="NaN"):
        lie.as_rotation(np.full((3, 3), np.nan))


def test_jit_vmap_grad():
    vs = jnp.array([[0.0, 0.0, 0.0], [0.1, 0.2, 0.3], [1.0, -1.0, 0.5]])
    Rs = jax.jit(jax.vmap(lie.exp))(vs)
    np.testing.assert_allclose(jax.jit(jax.vmap(lie.log))(Rs), vs, atol=1e-12)
    g = jax.grad(lambda v: lie.rotation_distance(jnp.eye(3), lie.exp(v)) ** 2)(vs[1])
    np.testing.assert_allclose(g, 2 * vs[1], atol=1e-12)  # d|v|^2/dv


def test_left_jacobians():
    v = jnp.array([0.4, -0.3, 0.9])
    Jl = lie.left_jacobian(v)
    np.testing.assert_allclose(Jl @ lie.left_jacobian_inverse(v), np.eye(3), atol=1e-12)
    dv = 1e-7 * jnp.array([1.0, 2.0, -1.0])
    lhs = lie.exp(v + dv)
    rhs = lie.exp(Jl @ dv) @ lie.exp(v)
    np.testing.assert_allclose(lhs, rhs, atol=1e-13)


@pytest.mark.parametrize("angle", [3e-5, 9e-5])
def test_log_small_angle_series_is_accurate(angle):
    """Below ``_SMALL = 1e-4`` the log uses ``θ / sin θ ≈ 1 + θ²/6 + 7θ⁴/360`` (Taylor; the
    next term is ~θ⁶). Its result must be exact to rounding (relative 1e-12), far below the
    θ²/6 ≈ 1.5e-10..1.4e-9 a wrong coefficient would leave."""
    v = angle * np.array([0.6, -0.8, 0.0])
    out = np.asarray(lie.log(lie.exp(jnp.asarray(v))))
    assert np.abs(out - v).max() <= 1e-12 * angle
