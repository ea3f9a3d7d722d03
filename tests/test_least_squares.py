"""solve_least_squares: closed-form linear least squares, nonlinear fits, status handling."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.core.status import Status
from fitting.calibration.least_squares import solve_least_squares


def _linear_problem(seed=0, n=40, p=3):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, p))
    sigma = 0.1 + rng.uniform(size=n)
    y = A @ np.array([1.0, -2.0, 0.5]) + sigma * rng.normal(size=n)
    return A, y, sigma


def _linear_residual(theta, args):
    A, y, sigma = args
    return (y - A @ theta) / sigma


def test_linear_matches_weighted_normal_equations():
    A, y, sigma = _linear_problem()
    out = solve_least_squares(_linear_residual, jnp.zeros(3), (A, y, sigma))
    Aw, yw = A / sigma[:, None], y / sigma
    theta_ref, *_ = np.linalg.lstsq(Aw, yw, rcond=None)
    cov_ref = np.linalg.inv(Aw.T @ Aw)
    np.testing.assert_allclose(out.theta, theta_ref, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(out.covariance, cov_ref, rtol=1e-8)
    np.testing.assert_allclose(out.jacobian, -Aw, rtol=1e-12)
    chi2 = np.sum((yw - Aw @ theta_ref) ** 2)
    assert abs(float(out.chi2) - chi2) < 1e-8 * chi2
    assert int(out.dof) == 37
    assert abs(float(out.chi2_per_dof) - chi2 / 37) < 1e-8
    assert out.result == Status.successful


def test_num_data_sets_dof():
    A, y, sigma = _linear_problem()
    out = solve_least_squares(_linear_residual, jnp.zeros(3), (A, y, sigma), num_data=20)
    assert int(out.dof) == 17
    out = solve_least_squares(_linear_residual, jnp.zeros(3), (A, y, sigma), num_data=3)
    assert int(out.dof) == 0 and np.isnan(float(out.chi2_per_dof))


def _exp_residual(theta, args):
    t, y, s = args
    return (y - theta[0] * jnp.exp(-theta[1] * t)) / s


def test_nonlinear_exponential_recovers_truth_and_fd_jacobian():
    rng = np.random.default_rng(1)
    t = np.linspace(0, 3, 50)
    y = 2.0 * np.exp(-1.3 * t) + 0.01 * rng.normal(size=t.size)
    args = (t, y, 0.01 * np.ones_like(t))
    out = solve_least_squares(_exp_residual, jnp.array([1.0, 1.0]), args)
    std = np.sqrt(np.diag(out.covariance))
    assert np.all(np.abs(np.asarray(out.theta) - [2.0, 1.3]) < 4 * std)
    # Jacobian at the optimum against central finite differences
    h = 1e-6
    fd = np.stack([(_exp_residual(out.theta + h * e, args) - _exp_residual(out.theta - h * e, args)) / (2 * h)
                   for e in np.eye(2)], 1)
    np.testing.assert_allclose(out.jacobian, fd, rtol=1e-6, atol=1e-6)
    assert 0.5 < float(out.chi2_per_dof) < 1.6


def test_not_converged_status_and_throw():
    args = (np.linspace(0, 3, 20), np.ones(20), np.ones(20))
    out = solve_least_squares(_exp_residual, jnp.array([1.0, 5.0]), args, max_steps=1, throw=False)
    assert out.result == Status.not_converged
    with pytest.raises(eqx.EquinoxRuntimeError, match="did not converge"):
        solve_least_squares(_exp_residual, jnp.array([1.0, 5.0]), args, max_steps=1)


def test_bad_theta0():
    A, y, sigma = _linear_problem()
    with pytest.raises(ValueError, match="theta0 contains NaN"):
        solve_least_squares(_linear_residual, jnp.array([0.0, jnp.nan, 0.0]), (A, y, sigma))
    with pytest.raises(ValueError, match="1-D"):
        solve_least_squares(_linear_residual, jnp.zeros((3, 1)), (A, y, sigma))


def test_vmappable_core_under_jit():
    """The result is an eqx.Module of arrays: it can be produced inside jit."""
    A, y, sigma = _linear_problem()
    f = jax.jit(lambda yy: solve_least_squares(_linear_residual, jnp.zeros(3), (A, yy, sigma), throw=False).theta)
    np.testing.assert_allclose(f(y), np.linalg.lstsq(A / sigma[:, None], y / sigma, rcond=None)[0], rtol=1e-7)


def test_vmap_over_data_sets():
    """The engine's while_loop under vmap: each data set reaches its own weighted least-squares optimum."""
    A, y, sigma = _linear_problem()
    Y = y + np.random.default_rng(5).normal(size=(3, y.size)) * sigma
    out = jax.vmap(lambda yy: solve_least_squares(_linear_residual, jnp.zeros(3), (A, yy, sigma), throw=False))(Y)
    ref = np.stack([np.linalg.lstsq(A / sigma[:, None], yy / sigma, rcond=None)[0] for yy in Y])
    np.testing.assert_allclose(out.theta, ref, rtol=1e-7, atol=1e-9)
    assert np.all(np.asarray(out.result == Status.successful))


# ----------------------------------------------------------------------- CDPR calibration
from cstiffjax import CableLaw  # noqa: E402
from cstiffjax.examples import example_path  # noqa: E402
from cstiffjax.io.recordings import load_recordings  # noqa: E402
from cstiffjax.io.robot_io import load_robot  # noqa: E402
from fitting.calibration.least_squares import calibrate  # noqa: E402
from fitting.calibration.models import synthetic_recordings  # noqa: E402
from fitting.calibration.parameters import apply_to_robot, cdpr_values  # noqa: E402


@pytest.fixture(scope="module")
def nominal():
    return load_robot(example_path("example01/robot.toml"))


@pytest.fixture(scope="module")
def synth(nominal):
    return synthetic_recordings(nominal, jax.random.PRNGKey(7), 24)


def test_calibrate_input_errors(nominal, synth):
    four = eqx.tree_at(lambda r: [r.anchors, r.attachments, r.EA, r.mass_per_length], nominal,
                       [nominal.anchors[:4], nominal.attachments[:4], nominal.EA[:4], nominal.mass_per_length[:4]])
    with pytest.raises(ValueError, match="recordings have 6 cables .* robot 'example01' has 4"):
        calibrate(four, synth)
    with pytest.raises(ValueError, match=r"unknown free parameter\(s\) \['EI'\]; allowed: EA, mass_per_length"):
        calibrate(nominal, synth, free=("EI",))
    bad = eqx.tree_at(lambda r: r.pose, synth, synth.pose.at[3, 2].set(jnp.nan))
    with pytest.raises(ValueError, match=r"recordings.pose has a non-finite value \(nan\) at sample 4, column 3"):
        calibrate(nominal, bad)
    const = eqx.tree_at(lambda r: [r.l0, r.wrench], synth,
                        [jnp.broadcast_to(synth.l0[:1], synth.l0.shape), jnp.broadcast_to(synth.wrench[:1], (24, 6))])
    with pytest.raises(ValueError, match="all 24 samples have the same inputs"):
        calibrate(nominal, const)
    with pytest.raises(ValueError, match="calibrate does not support the 'ideal' cable law; supported: 'spring', "
                                         "'catenary'$"):
        calibrate(nominal, synth, law=CableLaw.ideal)
    with pytest.raises(ValueError, match=r"statics must be one of \('newton', 'statics'\), got 'lm'"):
        calibrate(nominal, synth, statics="lm")


def _offset_truth(nominal, kind, rng):
    m = nominal.num_cables
    v = cdpr_values(nominal)
    if kind == "EA":
        v["EA"] = nominal.EA * (1 + 0.1 * rng.uniform(-1, 1, m))
    elif kind == "length_offset":
        v["length_offset"] = 2e-3 * rng.uniform(-1, 1, m)
    elif kind == "tension_offset":
        v["tension_offset"] = 3.0 * rng.uniform(-1, 1, m)
    elif kind == "anchors":
        v["anchors"] = nominal.anchors + 5e-3 * rng.uniform(-1, 1, (m, 3))
    elif kind == "attachments":
        v["attachments"] = nominal.attachments + 2e-3 * rng.uniform(-1, 1, (m, 3))
    elif kind == "platform_mass":
        v["platform_mass"] = nominal.platform_mass * 1.05
    elif kind == "com":
        v["com"] = jnp.array([0.01, -0.005, 0.02])
    elif kind == "frame":
        v["frame_rotation"] = jnp.array([1e-3, -2e-3, 1.5e-3])
        v["frame_translation"] = jnp.array([2e-3, 1e-3, -3e-3])
    return v


def _simulate(nominal, v, key, n):
    """Recordings of the robot ``v`` as read by instruments with ``v``'s offsets."""
    from fitting.calibration.parameters import measured_outputs

    truth = apply_to_robot(nominal, v)
    rec = synthetic_recordings(truth, key, n, noisy=False)
    pose, t = measured_outputs(rec.pose, rec.tensions, v)
    rng = np.random.default_rng(int(key[-1]))
    nz = nominal.noise
    pose = pose + np.concatenate([nz.position * rng.normal(size=(n, 3)), nz.rotation * rng.normal(size=(n, 3))], 1)
    t = t + nz.tension * rng.normal(size=t.shape)
    return eqx.tree_at(lambda r: [r.l0, r.pose, r.tensions], rec, [rec.l0 - v["length_offset"], pose, t])


def _check_recovery(fit, v, names):
    for n in names:
        z = (np.asarray(fit.values[n]) - np.asarray(v[n])) / np.asarray(fit.std[n])
        assert np.all(np.abs(z) < 3.5), (n, z)  # 3 sd per entry; 3.5 allows for many entries


@pytest.fixture(scope="module")
def ea_offset(nominal):
    v = _offset_truth(nominal, "EA", np.random.default_rng(0))
    v["length_offset"] = _offset_truth(nominal, "length_offset", np.random.default_rng(1))["length_offset"]
    rec = _simulate(nominal, v, jax.random.PRNGKey(11), 24)
    return v, rec, calibrate(nominal, rec, free=("EA", "length_offset"))


def test_recover_EA_and_length_offsets(nominal, ea_offset):
    v, _, fit = ea_offset
    assert fit.result == Status.successful
    _check_recovery(fit, v, ("EA", "length_offset"))
    dof = 24 * 12 - 12  # chi2/dof has sd √(2/dof) = 0.085: 3 sd window
    assert abs(float(fit.chi2_per_dof) - 1.0) < 3 * np.sqrt(2 / dof), float(fit.chi2_per_dof)
    assert fit.residuals.shape == (24, 12) and fit.channels[6] == "t_1"
    # the nominal robot is rejected by the data: the fit moved the parameters by many sigma
    assert np.max(np.abs((np.asarray(fit.values["EA"]) - np.asarray(nominal.EA)) / np.asarray(fit.std["EA"]))) > 5
    assert "EA[1]" in fit.summary()


def test_cdpr_jacobian_matches_finite_differences(ea_offset):
    """The Jacobian through the Newton statics (stop-gradient steps + one implicit step)
    against central differences of the residual, every column (EA log-scale and offsets)."""
    _, _, fit = ea_offset
    r = eqx.filter_jit(lambda th: fit.residual_fn(th, fit.args))
    theta = fit.ls.theta
    J = np.asarray(fit.ls.jacobian)
    for j in range(theta.shape[0]):
        h = 1e-5 if j < 6 else 1e-7  # log EA (dimensionless) / offset (m, sigma_position 2e-5 m)
        e = jnp.zeros_like(theta).at[j].set(h)
        fd = np.asarray((r(theta + e) - r(theta - e)) / (2 * h))
        np.testing.assert_allclose(J[:, j], fd, rtol=0, atol=1e-5 * np.max(np.abs(fd)), err_msg=fit.names[j])


@pytest.mark.slow
def test_newton_fit_matches_optimistix_statics_fit(nominal, ea_offset):
    """calibrate with the Newton statics (default) and with cstiffjax.statics.geometry.forward_statics
    (optimistix LM) on the same data: same optimum, chi2 and covariance (slow: ~30 s to
    compile the optimistix path; the default suite checks the residuals agree,
    tests/test_models.py::test_newton_and_optimistix_statics_give_the_same_residuals)."""
    _, rec, fit = ea_offset
    ref = calibrate(nominal, rec, free=("EA", "length_offset"), statics="statics")
    assert ref.result == Status.successful
    for name in ("EA", "length_offset"):
        dz = (np.asarray(fit.values[name]) - np.asarray(ref.values[name])) / np.asarray(ref.std[name])
        assert np.max(np.abs(dz)) < 1e-6, (name, dz)
    np.testing.assert_allclose(fit.chi2, ref.chi2, rtol=1e-9)
    np.testing.assert_allclose(fit.covariance, ref.covariance, rtol=1e-6, atol=1e-9 * float(jnp.max(ref.covariance)))
    np.testing.assert_allclose(fit.residuals, ref.residuals, rtol=0, atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["tension_offset", "anchors", "attachments", "platform_mass", "com", "frame"])
def test_recover_each_parameter_kind(nominal, kind):
    v = _offset_truth(nominal, kind, np.random.default_rng(3))
    rec = _simulate(nominal, v, jax.random.PRNGKey(13), 40)
    names = ("frame_rotation", "frame_translation") if kind == "frame" else (kind,)
    free = ("EA", *names)
    fit = calibrate(nominal, rec, free=free)
    _check_recovery(fit, v, names)
    assert 0.6 < float(fit.chi2_per_dof) < 1.5


@pytest.mark.slow
def test_recover_mass_per_length_with_catenary(nominal):
    v = cdpr_values(nominal)
    v["mass_per_length"] = jnp.full(6, 0.25)
    truth = apply_to_robot(nominal, v)
    rec = synthetic_recordings(truth, jax.random.PRNGKey(17), 20, law=CableLaw.catenary)
    fit = calibrate(nominal, rec, free=("mass_per_length",), law=CableLaw.catenary,
                    initial={"mass_per_length": jnp.full(6, 0.1)})
    _check_recovery(fit, v, ("mass_per_length",))


@pytest.mark.slow
def test_example02_EA_only_explains_clean_data():
    robot = load_robot(example_path("example02/robot.toml"))
    rec = load_recordings(example_path("example02/recordings.csv"), robot)
    fit = calibrate(robot, rec, free="EA")
    # 90 samples x 12 channels: chi2/dof has sd ~ sqrt(2/1074) = 0.043: 3 sd window
    assert abs(float(fit.chi2_per_dof) - 1.0) < 3 * np.sqrt(2 / 1074)


def test_csjm_tensions_and_drive_stiffness_from_identified_matrices():
    """Seed 000 eq. (45): recover T and k_s from noisy K_D matrices at 5 poses, within 3 std,
    and the model matches a central-difference stiffness of the cable-moment model."""
    from cstiffjax.csjm import model as csjm
    from fitting.calibration.least_squares import calibrate_csjm_stiffness
    from fitting.calibration.models import csjm_stiffness_model

    robot = load_robot(example_path("csjm.toml"))
    m = robot.num_cables
    T, k = jnp.linspace(50.0, 120.0, m), jnp.linspace(2e4, 5e4, m)
    rot = 0.2 * jax.random.normal(jax.random.PRNGKey(0), (5, 3))
    K = csjm_stiffness_model(robot, quantity="K")({"T": T, "k": k}, rot)
    # independent check of one matrix: K = -∂m/∂θ by central differences of the moment
    mfun = csjm.moment_function(robot, rot[0], T, k)
    h = 1e-6
    fd = -np.stack([(mfun(h * e) - mfun(-h * e)) / (2 * h) for e in np.eye(3)], 1)
    np.testing.assert_allclose(K[0], fd, rtol=1e-5, atol=1e-6 * float(jnp.max(jnp.abs(K[0]))))
    sig = 0.01 * float(jnp.max(jnp.abs(K)))
    Kn = K + sig * jax.random.normal(jax.random.PRNGKey(1), K.shape)
    fit = calibrate_csjm_stiffness(robot, rot, Kn, sig, T0=jnp.full(m, 80.0), k0=jnp.full(m, 3e4), quantity="K")
    for name, true in (("T", T), ("k", k)):
        assert np.all(np.abs((np.asarray(fit.values[name]) - np.asarray(true)) / np.asarray(fit.std[name])) < 3.5)
    assert np.all(np.asarray(fit.values["T"]) > 0)


def _execute_notebook(name, monkeypatch, size):
    from pathlib import Path

    import nbformat
    from nbclient import NotebookClient

    monkeypatch.setenv("CSTIFFJAX_NOTEBOOK_SIZE", size)  # inherited by the kernel
    path = Path(__file__).parent.parent / "notebooks" / f"{name}.ipynb"
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
    return "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []))


@pytest.mark.parametrize("name", ["gradient_based_calibration",
                                  pytest.param("uncertainty_analysis", marks=pytest.mark.slow)])  # ~3 min: catenary
def test_notebook_executes_small(name, monkeypatch):
    """Both notebooks run at the small size, asserting the conclusions they state at full
    size (with the small sample's tolerances) on data simulated by the cold-start statics,
    not the Newton solve the fit uses. The catenary posterior notebook is a slow test."""
    out = _execute_notebook(name, monkeypatch, "small")
    assert "max |error|/std" in out


@pytest.mark.slow
@pytest.mark.parametrize("name", ["gradient_based_calibration", "uncertainty_analysis"])
def test_notebook_executes_full(name, monkeypatch):
    _execute_notebook(name, monkeypatch, "full")


@pytest.mark.parametrize("name", ["gradient_based_calibration", "uncertainty_analysis"])
def test_saved_notebook_outputs_carry_no_machine_paths(name):
    """Saved outputs must not name a path of one machine: no /tmp/ipykernel_...,
    /work/..., /home/... or /Users/... anywhere in the stored notebook."""
    import re
    from pathlib import Path

    text = (Path(__file__).parent.parent / "notebooks" / f"{name}.ipynb").read_text()
    hits = re.findall(r"(/tmp/ipykernel_\d+|/work/[\w./-]+|/home/\w+|/Users/\w+)", text)
    assert not hits, hits[:3]
