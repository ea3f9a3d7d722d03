"""fitting.calibration.models: CDPR predictions, whitened residual layout and synthetic recordings."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.cable.laws import CableLaw
from cstiffjax.core import lie
from cstiffjax.core.status import Status
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.forward import StaticsProblem, forward_statics
from fitting.calibration.models import (
    cdpr_model_residuals,
    cdpr_residuals,
    num_effective,
    predict_cdpr,
    residual_channels,
    rotation_difference,
    synthetic_recordings,
)


@pytest.fixture(scope="module")
def robot():
    return load_robot(example_path("example01/robot.toml"))


@pytest.fixture(scope="module")
def clean(robot):
    return synthetic_recordings(robot, jax.random.PRNGKey(3), 8, noisy=False)


def test_channels():
    assert residual_channels(3) == ("x", "y", "z", "rx", "ry", "rz", "t_1", "t_2", "t_3")


@pytest.mark.slow
def test_predict_matches_single_forward_statics(robot, clean):
    pose, t, res = predict_cdpr(robot, clean.l0, clean.wrench, pose0=clean.pose)
    assert np.all(np.asarray(res == Status.successful))
    fs = forward_statics(StaticsProblem(robot, clean.l0[2], clean.wrench[2]))
    np.testing.assert_allclose(pose[2], fs.pose, atol=1e-9)
    np.testing.assert_allclose(t[2], fs.tensions, rtol=1e-8)


def test_noise_free_recordings_give_zero_residuals(robot, clean):
    r, _ = cdpr_model_residuals(robot, clean)
    assert r.shape == (8, 12)
    assert float(jnp.max(jnp.abs(r))) < 1e-6


def test_residual_signs_scales_and_mask(robot, clean):
    nz = robot.noise
    pose = clean.pose
    dtheta = jnp.array([1e-4, -2e-4, 3e-4])
    pred = pose.at[:, 0].add(-3 * nz.position)  # prediction 3 sigma below in x
    pred = pred.at[:, 3:].set(jax.vmap(lambda v: lie.log(lie.exp(-dtheta) @ lie.exp(v)))(pose[:, 3:]))
    t = clean.tensions - 2 * nz.tension
    mask = clean.tension_mask.at[:, 1].set(False)
    rec = eqx.tree_at(lambda r: r.tension_mask, clean, mask)
    r = cdpr_residuals(pred, t, rec, nz)
    np.testing.assert_allclose(r[:, 0], 3.0, rtol=1e-6)
    np.testing.assert_allclose(r[:, 1:3], 0.0, atol=1e-6)
    # rotation residual is the base-frame rotation from prediction to measurement
    np.testing.assert_allclose(r[:, 3:6], np.broadcast_to(dtheta / nz.rotation, (8, 3)), rtol=1e-6)
    np.testing.assert_allclose(r[:, 7], 0.0)
    np.testing.assert_allclose(r[:, 6], 2.0, rtol=1e-9)
    assert num_effective(rec) == 6 * 8 + 5 * 8


def test_rotation_difference_norm_is_geodesic_distance():
    a, b = jnp.array([0.3, -0.2, 0.1]), jnp.array([-0.1, 0.4, 0.2])
    d = rotation_difference(a, b)
    np.testing.assert_allclose(jnp.linalg.norm(d), lie.rotation_distance(lie.exp(a), lie.exp(b)), rtol=1e-12)


@pytest.mark.slow
def test_residual_gradient_wrt_EA_matches_finite_differences(robot, clean):
    def f(s):
        rb = eqx.tree_at(lambda r: r.EA, robot, robot.EA * s)
        return cdpr_model_residuals(rb, clean)[0][:3]

    g = jax.jacfwd(f)(1.0)
    h = 1e-5
    fd = (f(1.0 + h) - f(1.0 - h)) / (2 * h)
    np.testing.assert_allclose(g, fd, rtol=1e-4, atol=1e-4 * float(jnp.max(jnp.abs(fd))))


def test_synthetic_noise_level(robot):
    rec = synthetic_recordings(robot, jax.random.PRNGKey(4), 8)
    r, _ = cdpr_model_residuals(robot, rec)
    chi2 = float(jnp.sum(r**2))
    # chi-square with 96 dof: mean 96, sd √192 = 13.9; 3 sd window (noise-free or noise x 1.5 fail)
    assert 96 - 3 * np.sqrt(192) < chi2 < 96 + 3 * np.sqrt(192)


# ------------------------------------------------ calibration residuals: warm vs cold statics
def _residual_pair(robot, rec):
    from fitting.calibration.least_squares import CDPRResidual
    from fitting.calibration.parameters import cdpr_spec, cdpr_values

    spec = cdpr_spec(robot.num_cables, ("EA", "length_offset"))
    v0 = spec.check_values(cdpr_values(robot))
    args = (robot, rec, v0, {}, (rec.pose, None))
    fns = [eqx.filter_jit(CDPRResidual(spec, CableLaw.spring, method).checked) for method in ("newton", "statics")]
    return spec.to_theta(v0), args, fns


@pytest.mark.slow  # two cold-start compiles (~1 min)
def test_newton_and_optimistix_statics_give_the_same_residuals(robot):
    """The calibration's warm-started forward statics (bilateral springs) and its cold start
    (optimistix LM, one-sided springs) give the same whitened residuals at the nominal
    parameters and at a point 2 % / 1 mm away (the floor is the tension round-off,
    EA·(l - l0)/l0 with EA ~ 1e6 N: ~1e-9 N, i.e. ~3e-9 in units of sigma 0.3 N)."""
    rec = synthetic_recordings(robot, jax.random.PRNGKey(3), 8)
    th0, args, (newton, optx_statics) = _residual_pair(robot, rec)
    th1 = th0 + jnp.concatenate([0.02 * jnp.linspace(-1, 1, 6), 1e-3 * jnp.linspace(1, -1, 6)])
    for th in (th0, th1):
        (ra, oka), (rb, okb) = newton(th, args), optx_statics(th, args)
        assert bool(oka) and bool(okb)
        assert float(jnp.max(jnp.abs(ra))) > 1.0  # residuals are not trivially zero (noise, misfit)
        np.testing.assert_allclose(ra, rb, rtol=0, atol=1e-8)


def test_predict_method_and_law_errors(robot, clean):
    with pytest.raises(ValueError, match=r"method must be one of \('newton', 'statics'\), got 'lm'"):
        predict_cdpr(robot, clean.l0, clean.wrench, method="lm")
    with pytest.raises(ValueError, match="predict_cdpr\\(method='newton'\\) does not support the 'ideal' cable law; "
                                         "supported: 'spring', 'catenary'(?!,)"):
        predict_cdpr(robot, clean.l0, clean.wrench, law=CableLaw.ideal)
    with pytest.raises(TypeError, match="law must be a CableLaw member"):
        predict_cdpr(robot, clean.l0, clean.wrench, law="spring")


@pytest.mark.slow  # forward kinematics + Newton compile (~40 s)
def test_newton_without_start_pose_uses_ideal_pose(robot, clean):
    pose, t, res = predict_cdpr(robot, clean.l0[:3], clean.wrench[:3])
    assert np.all(np.asarray(res == Status.successful))
    np.testing.assert_allclose(pose, clean.pose[:3], atol=1e-10)
    np.testing.assert_allclose(t, clean.tensions[:3], rtol=1e-8)
