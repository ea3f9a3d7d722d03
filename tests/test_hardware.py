"""Every law sees the cable path of :mod:`cstiffjax.cable.path`: no-pulley robots give the
straight-cable numbers exactly; with pulleys, physical checks (finite differences,
symmetry of K at equilibrium, the w -> 0 limit of the catenary, agreement of the two
statics solvers)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import linprog

from cstiffjax.cable.laws import CableLaw
from cstiffjax.cable.path import vertical_axes
from cstiffjax.core.status import Status
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics import forward as fwd
from cstiffjax.statics import geometry as statics
from cstiffjax.statics.forward import StaticsProblem
from cstiffjax.stiffness import matrix as stiffness
from tests.helpers import central_difference

POSE = jnp.array([0.02, -0.01, 0.83, 0.01, -0.02, 0.03])


@pytest.fixture(scope="module")
def robots():
    """The 8-cable TCPR8 (fully constrained around POSE) with stiffer cables, without and
    with 2 cm swivel pulleys (vertical axes, formats.md: +z at the top, -z at the bottom)."""
    plain = eqx.tree_at(lambda r: r.EA, load_robot(example_path("tcpr8.toml")), jnp.full(8, 2e5))
    pul = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis), plain,
                      (jnp.full(8, 0.02), vertical_axes(plain.anchors)))
    return plain, pul


def _old_lengths(robot, pose):
    """The straight-cable formula before pulleys (statics.lengths_at at v1)."""
    p, R = statics.frame(pose)
    return jnp.linalg.norm(robot.anchors - (p + robot.attachments @ R.T), axis=-1)


def test_vertical_axes_up_above_down_below(robots):
    plain, _ = robots
    ax = np.asarray(vertical_axes(plain.anchors))
    np.testing.assert_array_equal(ax[:, 2], np.where(np.asarray(plain.anchors)[:, 2] > 0.89, 1.0, -1.0))
    np.testing.assert_array_equal(ax[:, :2], 0.0)


def test_no_pulley_is_the_straight_cable(robots):
    """Against the version-1 straight formulas, to the last bits (a compiled function and
    an eager one may round a sum differently, hence the ulp-level tolerance; the exact
    bit-for-bit comparison against the previous code is in the hardware report)."""
    plain, _ = robots
    l = jax.jit(statics.cable_lengths)(plain, POSE)
    np.testing.assert_allclose(l, jax.jit(_old_lengths)(plain, POSE), rtol=4e-16, atol=0)
    S = jax.jit(statics.structure_matrix)(plain, POSE)
    S_old = jax.jit(lambda x: -statics.twist_jacobian(lambda p, R: jnp.linalg.norm(
        plain.anchors - (p + plain.attachments @ R.T), axis=-1), x).T)(POSE)
    np.testing.assert_allclose(S, S_old, rtol=0, atol=1e-15)
    att = statics.attachment_points(plain, POSE)
    l0 = 0.99 * l
    cf = jax.jit(statics.elastic_cable_forces)(plain, POSE, l0)
    d = plain.anchors - att
    n = jnp.sqrt(jnp.sum(d * d, axis=-1))
    t = plain.EA * (n - l0) / l0
    np.testing.assert_allclose(cf.on_platform, t[:, None] * (d / n[:, None]), rtol=1e-13, atol=0)


def test_structure_matrix_with_pulleys_finite_differences(robots):
    _, pul = robots
    S = jax.jit(statics.structure_matrix)(pul, POSE)
    Sc = jax.jit(statics.structure_matrix_closed_form)(pul, POSE)
    np.testing.assert_allclose(S, Sc, atol=1e-12)
    fd = central_difference(jax.jit(lambda tw: statics.cable_lengths(pul, statics.apply_twist(POSE, tw))),
                            np.zeros(6))
    np.testing.assert_allclose(S, -fd.T, atol=1e-8)
    # the pulleys change the geometry measurably (not the straight numbers in disguise)
    plain_S = statics.structure_matrix_closed_form(robots[0], POSE)
    assert np.max(np.abs(np.asarray(S) - np.asarray(plain_S))) > 1e-3


@pytest.fixture(scope="module")
def equilibrium_pulleys(robots):
    """Cables cut so that POSE is the equilibrium by construction: tensions in the
    equilibrium set (S t = -W_g with S of the pulley paths) maximizing the smallest
    tension, all tensions <= 500 N (LP, scipy)."""
    _, pul = robots
    S = np.asarray(statics.structure_matrix_closed_form(pul, POSE))
    w = np.asarray(statics.gravity_wrench(pul, POSE))
    # variables (t_1..t_8, s): max s  s.t.  S t = -w,  s <= t_i <= 500
    lp = linprog(np.r_[np.zeros(8), -1.0], A_ub=np.c_[-np.eye(8), np.ones(8)], b_ub=np.zeros(8),
                 A_eq=np.c_[S, np.zeros(6)], b_eq=-w, bounds=[(0, 500)] * 8 + [(None, None)])
    t = lp.x[:8]
    assert lp.success and t.min() > 20.0
    l0 = stiffness.unstrained_lengths(pul, POSE, jnp.asarray(t))
    return l0, fwd.forward_statics(StaticsProblem(pul, l0)), t


@pytest.mark.slow  # cold pulley statics compiles (~1 min)
def test_forward_statics_and_newton_agree_with_pulleys(robots, equilibrium_pulleys):
    _, pul = robots
    l0, fs, t_true = equilibrium_pulleys
    assert bool(fs.result == Status.successful)
    np.testing.assert_allclose(fs.pose, POSE, atol=1e-9)
    np.testing.assert_allclose(fs.tensions, t_true, rtol=1e-7)
    near = POSE + jnp.array([3e-3, -2e-3, 4e-3, 5e-3, -4e-3, 3e-3])
    warm = fwd.forward_statics(StaticsProblem(pul, l0, jnp.zeros(6), CableLaw.bilateral), pose0=near, start="warm",
                               throw=False)
    pose, t = warm.pose, warm.tensions
    assert bool(warm.result == Status.successful)
    np.testing.assert_allclose(pose, POSE, atol=1e-9)
    np.testing.assert_allclose(t, t_true, rtol=1e-7)
    # the residual wrench is zero on the pulley path: S(pose) t + W_g = 0 with S from autodiff
    S = statics.structure_matrix(pul, fs.pose)
    np.testing.assert_allclose(S @ fs.tensions + statics.gravity_wrench(pul, fs.pose), 0.0, atol=1e-7)


@pytest.mark.slow
def test_stiffness_with_pulleys_symmetric_and_fd(robots, equilibrium_pulleys):
    _, pul = robots
    l0, fs, _ = equilibrium_pulleys
    K = stiffness.stiffness_from_lengths(pul, fs.pose, l0)
    np.testing.assert_allclose(K, K.T, atol=1e-6 * np.max(np.abs(K)))
    fd = central_difference(jax.jit(lambda tw: statics.elastic_wrench(pul, statics.apply_twist(fs.pose, tw), l0)),
                            np.zeros(6), h=1e-7)
    np.testing.assert_allclose(K, -fd, rtol=1e-5, atol=1e-3)
    # the pulley's geometric term: K differs from the straight-cable K at the same tensions
    K_straight = stiffness.stiffness(robots[0], fs.pose, fs.tensions).K
    assert np.max(np.abs(np.asarray(K) - np.asarray(K_straight))) > 1e-3 * np.max(np.abs(K))


@pytest.mark.slow
def test_catenary_over_pulley_tends_to_spring(robots, equilibrium_pulleys):
    """w -> 0: the catenary from T with the free span's unstrained length is the spring on
    the whole path (same force on the platform)."""
    _, pul = robots
    l0, fs, _ = equilibrium_pulleys
    light = eqx.tree_at(lambda r: r.mass_per_length, pul, jnp.full(8, 1e-7))
    cat = jax.jit(statics.elastic_cable_forces, static_argnums=3)(light, fs.pose, l0, CableLaw.catenary)
    spr = statics.elastic_cable_forces(pul, fs.pose, l0, CableLaw.spring)
    np.testing.assert_allclose(cat.on_platform, spr.on_platform, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(cat.tension_anchor, spr.tension_anchor, rtol=1e-5)
    # the engine's joint pose + end-force catenary solve sees the same free span
    near = fs.pose + jnp.array([2e-3, -1e-3, 2e-3, 2e-3, -1e-3, 1e-3])
    fc = fwd.forward_statics(StaticsProblem(light, l0, law=CableLaw.catenary), pose0=near, start="warm", throw=False)
    assert bool(fc.result == Status.successful)
    np.testing.assert_allclose(fc.pose, POSE, atol=1e-6)
