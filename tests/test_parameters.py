"""fitting.calibration.parameters: transforms, flattening, robot/input/output corrections, errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.core import lie
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from fitting.calibration.least_squares import calibrate_model, identifiability
from fitting.calibration.parameters import (
    CDPR_PARAMETERS,
    ParameterSpec,
    apply_to_robot,
    cdpr_spec,
    cdpr_values,
    corrected_inputs,
    measured_outputs,
)


@pytest.fixture(scope="module")
def robot():
    return load_robot(example_path("example01/robot.toml"))


def _spec():
    return ParameterSpec(("k", "c", "s"), ((2,), (), (3,)), ("log", ("bounded", -1.0, 2.0), "identity"),
                         ("N", "", "m"), ("k", "c", "s"))


def test_round_trip_and_domains():
    spec = _spec()
    vals = {"k": jnp.array([3.0, 0.2]), "c": jnp.array(1.5), "s": jnp.array([-1.0, 0.0, 4.0])}
    th = spec.to_theta(vals)
    assert th.shape == (6,) and spec.num_free == 6
    back = spec.from_theta(th, vals)
    for n in vals:
        np.testing.assert_allclose(back[n], vals[n], rtol=1e-12, atol=1e-12)
    # any θ maps into the domains
    far = spec.from_theta(jnp.array([-50.0, 40.0, 30.0, 1.0, 2.0, 3.0]), vals)
    assert np.all(np.asarray(far["k"]) > 0)
    assert -1.0 <= float(far["c"]) <= 2.0
    assert spec.flat_names() == ["k[1]", "k[2]", "c", "s[1]", "s[2]", "s[3]"]


def test_value_jacobian_and_log_det_against_finite_differences():
    spec = _spec()
    th = jnp.array([0.3, -0.4, 0.7, 1.0, 2.0, 3.0])
    G = spec.value_jacobian(th)
    dummy = {"k": jnp.zeros(2), "c": jnp.zeros(()), "s": jnp.zeros(3)}
    h = 1e-6
    fd = np.stack([(spec.free_vector(spec.from_theta(th + h * e, dummy))
                    - spec.free_vector(spec.from_theta(th - h * e, dummy))) / (2 * h) for e in np.eye(6)], 1)
    np.testing.assert_allclose(G, fd, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(spec.log_abs_det_jacobian(th), np.log(abs(np.linalg.det(fd))), rtol=1e-7)


def test_unknown_free_lists_allowed():
    with pytest.raises(ValueError, match=r"unknown free parameter\(s\) \['stiffness'\]; allowed: EA, mass_per_length"):
        cdpr_spec(6, ("EA", "stiffness"))
    with pytest.raises(ValueError, match="no free parameter"):
        cdpr_spec(6, ())


def test_log_parameter_must_start_positive(robot):
    spec = cdpr_spec(6, "mass_per_length")
    with pytest.raises(ValueError, match=r"'mass_per_length' must be > 0 \(log transform\)"):
        spec.check_values(cdpr_values(robot))  # example01 cables are massless


def test_spec_from_string_and_shapes(robot):
    spec = cdpr_spec(6, "EA, anchors,frame_rotation")
    assert spec.free == ("EA", "anchors", "frame_rotation")
    assert spec.num_free == 6 + 18 + 3
    assert spec.flat_names()[6:8] == ["anchors[1].x", "anchors[1].y"]
    assert set(CDPR_PARAMETERS) == set(cdpr_values(robot))


def test_apply_and_corrections(robot):
    v = cdpr_values(robot)
    v["EA"] = robot.EA * 2
    v["anchors"] = robot.anchors + 0.01
    rb = apply_to_robot(robot, v)
    np.testing.assert_allclose(rb.EA, 2 * robot.EA)
    np.testing.assert_allclose(rb.anchors, robot.anchors + 0.01)
    v["length_offset"] = jnp.arange(6.0)
    np.testing.assert_allclose(corrected_inputs(jnp.ones((2, 6)), v), 1 + np.arange(6.0)[None].repeat(2, 0))
    # frame offset: p_meas = Rf p + c, R_meas = Rf R
    rho, c = jnp.array([0.01, -0.02, 0.03]), jnp.array([0.1, 0.2, -0.3])
    v.update(frame_rotation=rho, frame_translation=c, tension_offset=jnp.full(6, 2.0))
    pose = jnp.array([[1.0, 2.0, 3.0, 0.1, 0.0, -0.2]])
    pm, tm = measured_outputs(pose, jnp.zeros((1, 6)), v)
    Rf = np.asarray(lie.exp(rho))
    np.testing.assert_allclose(pm[0, :3], Rf @ np.array([1.0, 2.0, 3.0]) + np.asarray(c), rtol=1e-12)
    np.testing.assert_allclose(lie.exp(pm[0, 3:]), Rf @ np.asarray(lie.exp(pose[0, 3:])), atol=1e-12)
    np.testing.assert_allclose(tm, 2.0)


def test_identifiability_names_the_combination():
    J = np.array([[1.0, 1.0, 0.0], [2.0, 2.0, 1.0], [0.5, 0.5, 3.0]])
    msgs = identifiability(J, ["a", "b", "c"])
    assert len(msgs) == 1 and "non-identifiable" in msgs[0] and "a" in msgs[0] and "b" in msgs[0]
    assert identifiability(np.eye(3), ["a", "b", "c"]) == []


def test_calibrate_model_errors_and_warning():
    x = np.linspace(0, 1, 10)
    y = 1 + 2 * x
    f = lambda p, x: p["a"] + p["b"] * x  # noqa: E731
    with pytest.raises(ValueError, match=r"unknown free parameter\(s\) \['c'\]; allowed: a, b"):
        calibrate_model(f, {"a": 0.0, "b": 0.0}, x, y, 0.1, free=("c",))
    with pytest.raises(ValueError, match="measurements contain NaN"):
        calibrate_model(f, {"a": 0.0, "b": 0.0}, x, np.where(np.arange(10) == 3, np.nan, y), 0.1)
    with pytest.raises(ValueError, match="all 10 samples have the same inputs"):
        calibrate_model(f, {"a": 0.0, "b": 0.0}, np.full(10, 0.5), y, 0.1)
    with pytest.raises(ValueError, match="sigma must be > 0"):
        calibrate_model(f, {"a": 0.0, "b": 0.0}, x, y, 0.0)
    # a redundant parametrisation is reported, naming the combination
    g = lambda p, x: p["a"] + p["a2"] + p["b"] * x  # noqa: E731
    with pytest.warns(UserWarning, match=r"identifiable parameter combination .*a.*a2"):
        fit = calibrate_model(g, {"a": 0.0, "a2": 0.0, "b": 0.0}, x, y, 0.1)
    assert len(fit.weak) == 1


def test_priors_enter_as_residuals():
    """A Gaussian prior on the intercept of a line is the same as one extra data point."""
    x = np.linspace(0, 1, 10)
    y = 1 + 2 * x + 0.05 * np.sin(7 * x)
    f = lambda p, x: p["a"] + p["b"] * x  # noqa: E731
    fit = calibrate_model(f, {"a": 0.0, "b": 0.0}, x, y, 0.1, priors={"a": (0.8, 0.05)})
    A = np.concatenate([np.stack([np.ones(10), x], 1) / 0.1, [[1 / 0.05, 0.0]]])
    yy = np.concatenate([y / 0.1, [0.8 / 0.05]])
    ref = np.linalg.lstsq(A, yy, rcond=None)[0]
    np.testing.assert_allclose([fit.values["a"], fit.values["b"]], ref, rtol=1e-7)
    np.testing.assert_allclose(fit.covariance, np.linalg.inv(A.T @ A), rtol=1e-7)
    assert int(fit.dof) == 11 - 2
    with pytest.raises(ValueError, match="prior on unknown parameter 'z'"):
        calibrate_model(f, {"a": 0.0, "b": 0.0}, x, y, 0.1, priors={"z": (0.0, 1.0)})


def test_jit_through_spec():
    spec = _spec()
    vals = {"k": jnp.array([3.0, 0.2]), "c": jnp.array(1.5), "s": jnp.array([-1.0, 0.0, 4.0])}
    f = jax.jit(lambda t: spec.free_vector(spec.from_theta(t, vals)))
    np.testing.assert_allclose(f(spec.to_theta(vals)), spec.free_vector(vals), rtol=1e-12)


def test_per_session_parameters_are_named_by_the_recordings_session_ids():
    """Rows of the per-session zeros carry the file's session ids (not 1..S), and a
    3-cable robot's (sessions, 3) length zeros are not named like xyz vectors."""
    from fitting.calibration.parameters import cdpr_spec

    spec = cdpr_spec(3, ("length_zero", "yaw_zero"), sessions=2, session_ids=(-7, 9))
    assert spec.flat_names() == [f"length_zero[session {s}][{i}]" for s in (-7, 9) for i in (1, 2, 3)] + [
        "yaw_zero[session -7]", "yaw_zero[session 9]"]
    assert cdpr_spec(2, ("yaw_zero",), sessions=1).flat_names() == ["yaw_zero[session 0]"]  # no column: session 0
