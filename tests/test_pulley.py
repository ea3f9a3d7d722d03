"""Swivel-pulley kinematics (formats.md §1 v2) against references independent of
:mod:`cstiffjax.cable.path`: planar closed forms worked by hand, finite differences, and a
re-implementation of cdpyr's pulley kinematics conventions (read, not copied)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cstiffjax.cable.path import cable_path, swivel_angle

path_jit = jax.jit(cable_path)
swivel_jit = jax.jit(swivel_angle)
grad_jit = jax.jit(jax.grad(lambda a, p, r, e: cable_path(a, p, r, e).length, argnums=(0, 1, 2)))
R, A, E = 0.025, np.zeros(3), np.array([0.0, 0.0, 1.0])


def _by_hand(a, zp, r):
    """Planar case: anchor at 0, axis +z, P = (a, 0, zp) with a > r. The cable rises,
    runs clockwise (seen from +y) over the pulley of centre (r, 0, 0) and leaves towards P.
    With phi the angle of C->P below the horizontal and alpha = acos(r/rho) the angle
    between C->P and C->T: T sits at polar angle theta_T = alpha - phi, and the wrap,
    swept clockwise from the entry point (polar angle pi), is pi - theta_T."""
    rho = np.hypot(a - r, zp)
    phi = np.arctan2(-zp, a - r)
    alpha = np.arccos(r / rho)
    theta_t = alpha - phi
    beta = np.pi - theta_t
    tangent = np.array([r + r * np.cos(theta_t), 0.0, r * np.sin(theta_t)])
    return beta, tangent, r * beta + np.sqrt(rho**2 - r**2)


@pytest.mark.parametrize(("a", "zp"), [(1.0, -2.0), (2.0, 0.0), (0.5, 1.5), (0.03, -3.0), (1.2, -0.01)])
def test_planar_closed_form(a, zp):
    path = path_jit(A, jnp.array([a, 0.0, zp]), R, E)
    beta, tangent, length = _by_hand(a, zp, R)
    np.testing.assert_allclose(path.wrap, beta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(path.tangent_point, tangent, rtol=0, atol=1e-12)
    np.testing.assert_allclose(path.length, length, rtol=1e-14)
    np.testing.assert_allclose(path.centre, [R, 0, 0], atol=1e-15)
    d = path.tangent_point - np.array([a, 0.0, zp])
    np.testing.assert_allclose(path.direction, d / np.linalg.norm(d), atol=1e-12)
    np.testing.assert_allclose(path.free_length, np.linalg.norm(d), rtol=1e-12)


def test_spec_example_over_the_top():
    """formats.md: axis +z above the platform takes the cable up, over the top, down to P."""
    path = path_jit(A, jnp.array([0.4, 0.3, -2.0]), R, E)
    assert np.pi / 2 < float(path.wrap) < np.pi + 0.1
    assert float(path.tangent_point[2]) > 0.0  # T above the entry point
    assert float(path.direction[2]) > 0.9  # the force on the platform points up


def test_invariant_under_rigid_motion_and_swivel():
    rng = np.random.default_rng(0)
    Q = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    shift = rng.normal(size=3)
    p0 = np.array([0.7, 0.0, -1.3])
    ref = path_jit(A, jnp.array(p0), R, E)
    for psi in (0.3, 2.0, -2.8):
        Rz = Rotation.from_rotvec([0.0, 0.0, psi]).as_matrix()
        P = Q @ Rz @ p0 + shift
        path = path_jit(jnp.array(shift), jnp.array(P), R, jnp.array(Q @ E))
        np.testing.assert_allclose(path.length, ref.length, rtol=1e-13)
        np.testing.assert_allclose(path.wrap, ref.wrap, atol=1e-12)
        np.testing.assert_allclose(path.tangent_point, Q @ Rz @ np.asarray(ref.tangent_point) + shift, atol=1e-12)
        ang = swivel_jit(path, jnp.array(Q @ E), jnp.array(Q @ [1.0, 0, 0]))
        np.testing.assert_allclose(ang, psi, atol=1e-12)


def test_zero_radius_is_the_straight_cable():
    P = jnp.array([0.3, -0.2, -1.7])
    path = path_jit(A, P, 0.0, jnp.array([0.0, 0.6, 0.8]))
    np.testing.assert_allclose(path.length, np.linalg.norm(P), rtol=1e-15)
    np.testing.assert_allclose(path.direction, -np.asarray(P) / np.linalg.norm(P), atol=1e-15)
    np.testing.assert_allclose(path.tangent_point, A, atol=1e-15)
    straight = path_jit(jnp.array([1.0, 2.0, 3.0]), P, 0.0, jnp.zeros(3))
    d = np.array([1.0, 2.0, 3.0]) - np.asarray(P)
    assert float(straight.length) == float(jnp.sqrt(jnp.sum(jnp.asarray(d) ** 2)))
    assert not bool(straight.pulley) and float(straight.wrap) == 0.0


@pytest.mark.parametrize("axis", [[0.0, 0.0, 1.0], [0.0, 0.6, -0.8], [0.48, 0.6, 0.64]])
def test_length_gradient_is_minus_direction_finite_differences(axis):
    """dl/dP = -(unit vector from P towards T), by central differences (independent of
    autodiff), and the autodiff gradients w.r.t. P, anchor, radius agree with them."""
    anchor, P, axis = np.array([0.2, -0.1, 0.3]), np.array([1.1, 0.4, -1.5]), np.array(axis)

    def length(a, p, r):
        return float(path_jit(jnp.array(a), jnp.array(p), r, jnp.array(axis)).length)

    h = 1e-6
    fd_p = np.array([(length(anchor, P + h * e, R) - length(anchor, P - h * e, R)) / (2 * h) for e in np.eye(3)])
    fd_a = np.array([(length(anchor + h * e, P, R) - length(anchor - h * e, P, R)) / (2 * h) for e in np.eye(3)])
    fd_r = (length(anchor, P, R + h) - length(anchor, P, R - h)) / (2 * h)
    path = path_jit(jnp.array(anchor), jnp.array(P), R, jnp.array(axis))
    np.testing.assert_allclose(fd_p, -np.asarray(path.direction), atol=1e-8)
    g = grad_jit(jnp.array(anchor), jnp.array(P), jnp.asarray(R), jnp.array(axis))
    np.testing.assert_allclose(g[1], fd_p, atol=1e-8)
    np.testing.assert_allclose(g[0], fd_a, atol=1e-8)
    np.testing.assert_allclose(g[2], fd_r, atol=1e-7)
    # radius derivative at r = 0 is finite (a fit may start a radius at zero)
    g0 = grad_jit(jnp.array(anchor), jnp.array(P), jnp.asarray(0.0), jnp.array(axis))[2]
    fd0 = (length(anchor, P, h) - length(anchor, P, -h)) / (2 * h)
    np.testing.assert_allclose(g0, fd0, atol=1e-7)


def _cdpyr_convention(anchor, P, r, axis, reference):
    """Swivel and wrap angles as cdpyr's ``analysis/kinematics/pulley.py`` defines them
    (re-derived here): the pulley frame has z along the swivel axis and x along the zero
    of the swivel; swivel = atan2(y, x) of P in that frame; in the frame swivelled by it
    the roller centre is at (r, 0, 0); the leave point q (unit, in the x-z plane of the
    roller) solves [[r, L], [-L, r]] q = (X, Z) of P relative to the roller centre, with
    L = sqrt(|P - centre|^2 - r^2); wrap = pi - atan2(q_z, q_x)."""
    z = axis / np.linalg.norm(axis)
    x = reference - reference @ z * z
    x /= np.linalg.norm(x)
    frame = np.stack([x, np.cross(z, x), z])  # rows: pulley axes in the base frame
    v = frame @ (P - anchor)
    swivel = np.arctan2(v[1], v[0])
    c, s = np.cos(swivel), np.sin(swivel)
    w = np.array([c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2]]) - np.array([r, 0.0, 0.0])
    L = np.sqrt(w @ w - r * r)
    q = np.linalg.solve(np.array([[r, L], [-L, r]]), w[[0, 2]])
    return swivel, np.pi - np.arctan2(q[1], q[0]), L


def test_swivel_and_wrap_match_cdpyr_convention():
    rng = np.random.default_rng(3)
    for _ in range(6):
        anchor = rng.normal(size=3)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        P = anchor + rng.normal(size=3) * 1.5
        ref = np.cross(axis, rng.normal(size=3))
        path = path_jit(jnp.array(anchor), jnp.array(P), 0.04, jnp.array(axis))
        swivel, wrap, free = _cdpyr_convention(anchor, P, 0.04, axis, ref)
        np.testing.assert_allclose(swivel_jit(path, jnp.array(axis), jnp.array(ref)), swivel, atol=1e-12)
        np.testing.assert_allclose(path.wrap, wrap, atol=1e-12)
        np.testing.assert_allclose(path.free_length, free, rtol=1e-12)


def test_all_cables_at_once_equal_the_one_cable_path_bit_for_bit():
    """``cable_paths`` (``(m,)`` components, what every robot-level call uses) equals
    ``vmap(cable_path)`` exactly, fields and the length's gradient, on mixed cables: pulleys
    of several radii (one 0), straight cables, a zero-length straight cable and an
    attachment on the swivel axis."""
    from cstiffjax.cable.path import cable_paths

    rng = np.random.default_rng(7)
    m = 8
    anchors = rng.normal(size=(m, 3)) * 2.0
    attachments = rng.normal(size=(m, 3)) * 0.3
    axis = rng.normal(size=(m, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    radius = np.abs(rng.normal(size=m)) * 0.03
    radius[1] = 0.0  # a pulley of radius 0
    axis[2] = axis[3] = 0.0  # straight cables, the second of zero length
    attachments[3] = anchors[3]
    attachments[4] = anchors[4] + 0.7 * axis[4]  # on the swivel axis
    args = tuple(jnp.asarray(a) for a in (anchors, attachments, radius, axis))
    one = jax.jit(jax.vmap(cable_path))(*args)
    many = jax.jit(cable_paths)(*args)
    for name in ("length", "free_length", "tangent_point", "direction", "wrap", "swivel_direction", "centre",
                 "pulley"):
        a, b = getattr(one, name), getattr(many, name)
        assert a.shape == b.shape and a.dtype == b.dtype, name
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)
    grad = lambda f: jax.jit(jax.grad(lambda P: jnp.sum(f(args[0], P, args[2], args[3]).length)))(args[1])  # noqa: E731
    np.testing.assert_array_equal(np.asarray(grad(jax.vmap(cable_path))), np.asarray(grad(cable_paths)))
