"""Winch and load-cell gains in the measurement model (formats.md §1 v2) and the new
calibration parameters (pulley radius, gains)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.cable.path import vertical_axes
from cstiffjax.core.status import Status
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from fitting.calibration.least_squares import calibrate
from fitting.calibration.models import commanded_lengths, synthetic_recordings, tension_readings, true_lengths
from fitting.calibration.parameters import known_trade_offs


@pytest.fixture(scope="module")
def nominal():
    return load_robot(example_path("example01/robot.toml"))


def test_gain_formulas_follow_formats(nominal):
    rng = np.random.default_rng(0)
    l0 = 5.0 + rng.uniform(-0.3, 0.3, (5, 6))
    g = 1.0 + rng.uniform(-0.03, 0.03, 6)
    robot = eqx.tree_at(lambda r: (r.length_gain, r.tension_gain), nominal, (jnp.asarray(g), jnp.asarray(g[::-1])))
    # formats.md: true = l0_ref + length_gain (l0_i - l0_ref), l0_ref the first recorded l0_i
    np.testing.assert_allclose(true_lengths(robot, l0), l0[0] + g * (l0 - l0[0]), rtol=1e-15)
    np.testing.assert_allclose(true_lengths(robot, commanded_lengths(robot, l0)), l0, rtol=1e-15)
    # reading = tension_gain x true tension
    t = rng.uniform(50, 300, (5, 6))
    np.testing.assert_allclose(tension_readings(robot, t), g[::-1] * t, rtol=1e-15)
    # unit gains change nothing, to the bit
    np.testing.assert_array_equal(true_lengths(nominal, l0), l0)
    np.testing.assert_array_equal(commanded_lengths(nominal, l0), l0)
    np.testing.assert_array_equal(tension_readings(nominal, t), t)


@pytest.mark.slow  # two compiles of a 12-parameter Newton-statics fit: long on a shared 2-core machine
def test_gains_recovered_by_calibration(nominal):
    rng = np.random.default_rng(4)
    lg = 1.0 + rng.uniform(-0.02, 0.02, 6)
    tg = 1.0 + rng.uniform(-0.015, 0.015, 6)
    truth = eqx.tree_at(lambda r: (r.length_gain, r.tension_gain), nominal, (jnp.asarray(lg), jnp.asarray(tg)))
    rec = synthetic_recordings(truth, jax.random.PRNGKey(3), 20, method="newton")
    fit = calibrate(nominal, rec, free=("length_gain", "tension_gain"))
    assert fit.result == Status.successful
    for name, true in (("length_gain", lg), ("tension_gain", tg)):
        z = (np.asarray(fit.values[name]) - true) / np.asarray(fit.std[name])
        assert np.all(np.abs(z) < 3.5), (name, z)
    assert 0.5 < float(fit.chi2_per_dof) < 1.6
    # the data reject unit gains (the nominal model) by many sigma
    for name in ("length_gain", "tension_gain"):
        assert np.max(np.abs((np.asarray(fit.values[name]) - 1.0) / np.asarray(fit.std[name]))) > 5.0


@pytest.mark.slow
def test_pulley_radius_recovered_by_calibration(nominal):
    axes = vertical_axes(nominal.anchors)
    truth = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis), nominal, (jnp.full(6, 0.025), axes))
    rec = synthetic_recordings(truth, jax.random.PRNGKey(5), 20, method="newton")
    start = eqx.tree_at(lambda r: r.pulley_axis, nominal, axes)  # axes known, radius 0
    fit = calibrate(start, rec, free=("shared_pulley_radius",))
    assert fit.result == Status.successful
    r, sd = float(fit.values["shared_pulley_radius"]), float(fit.std["shared_pulley_radius"])
    assert abs(r - 0.025) < 3.5 * sd and sd < 1e-3
    assert 0.5 < float(fit.chi2_per_dof) < 1.6


def test_known_trade_offs_name_the_pairs():
    msgs = known_trade_offs(("pulley_radius", "anchors", "EA"))
    assert len(msgs) == 1 and "pulley_radius trades off against anchors" in msgs[0]
    msgs = known_trade_offs(("shared_length_gain", "length_offset", "tension_gain", "platform_mass"))
    assert any("shared_length_gain trades off against length_offset" in m for m in msgs)
    assert any("tension_gain trades off against platform_mass" in m for m in msgs)
    assert known_trade_offs(("EA", "anchors")) == []


@pytest.mark.slow  # diagnosis model compile (~1 min)
def test_diagnosis_model_honours_stated_gains():
    """The diagnosis' measurement model (fitting.effects.model.predict) applies the
    description's gains exactly as fitting.calibration.models.predict_cdpr does."""
    from cstiffjax.io.recordings import load_recordings
    from fitting.calibration.models import predict_cdpr
    from fitting.effects import build_data, make_model
    from fitting.effects import model as M

    rb = load_robot(example_path("example02/robot.toml"))
    rec = load_recordings(example_path("example02/recordings.csv"), rb).select(np.arange(4))
    g = jnp.linspace(0.98, 1.02, rb.num_cables)
    geared = eqx.tree_at(lambda r: (r.length_gain, r.tension_gain), rb, (g, g[::-1]))
    data = build_data(rec)
    empty = make_model(geared, data, [])
    pose, t, ok = eqx.filter_jit(M.predict)(empty, jnp.zeros(empty.size), geared, data)
    pose_ref, t_ref, res = predict_cdpr(geared, rec.l0, rec.wrench, pose0=rec.pose)
    assert bool(jnp.all(ok)) and bool(jnp.all(res == Status.successful))
    np.testing.assert_allclose(pose, pose_ref, atol=1e-10)
    np.testing.assert_allclose(t, t_ref, rtol=1e-9)
    # and the gains matter: the ungeared robot predicts other tensions
    t_plain = predict_cdpr(rb, rec.l0, rec.wrench, pose0=rec.pose)[1]
    assert np.max(np.abs(np.asarray(t) - np.asarray(t_plain))) > 0.5
