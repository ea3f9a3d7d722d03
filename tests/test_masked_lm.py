"""The least-squares engine's masked fits (:func:`fitting.effects.fit.fit_masked` over
:func:`fitting.calibration.lm.masked_levenberg_marquardt`) against scipy's least squares on the
free subset, and its failed-sample handling, both drivers (the jitted ``lax.while_loop`` and the host
loop of the grammar-term models).

Small jnp residuals: the engine is model-agnostic, the diagnosis tests exercise it on the
compiled CDPR model."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import least_squares

from fitting.effects.fit import fit_masked


def _fit(fun, theta0, free, must_succeed=None, on_host=False):
    """The engine on ``fun(θ) -> (r, J, ok)``: traced (``fun`` wrapped as ``(θ, args)``) or host-driven."""
    if on_host:
        return fit_masked(lambda th: fun(jnp.asarray(th)), theta0, None, free, must_succeed=must_succeed, on_host=True)
    return fit_masked(lambda th, _: fun(th), theta0, None, free, must_succeed=must_succeed)

T = np.linspace(0.0, 4.0, 25)
TRUE = np.array([2.0, -0.7, 0.3, 0.05])  # amplitude, log-rate, offset, slope


def _model(th):
    return th[0] * np.exp(np.exp(th[1]) * -T) + th[2] + th[3] * T


def _jmodel(th):
    return th[0] * jnp.exp(jnp.exp(th[1]) * -T) + th[2] + th[3] * T


def _data(seed=0):
    return _model(TRUE) + 0.01 * np.random.default_rng(seed).standard_normal(T.size)


def _fun(y, sigma=0.01, fail=None):
    """``θ -> (r (n, 1), J (n, 4), ok (n,))``; ``fail(θ) -> (n,) bool`` marks failed samples
    (their residuals NaN, as a failed forward solve would give)."""

    def fun(th):
        e = jnp.exp(jnp.exp(th[1]) * -T)
        r = (y - _jmodel(th)) / sigma
        J = -jnp.stack([e, th[0] * e * (-T * jnp.exp(th[1])), jnp.ones_like(T), T], axis=1) / sigma
        ok = jnp.ones(T.size, bool) if fail is None else ~fail(th)
        r = jnp.where(ok, r, jnp.nan)
        return r[:, None], jnp.where(ok[:, None], J, jnp.nan), ok

    return fun


@pytest.mark.parametrize("on_host", [False, True])
@pytest.mark.parametrize("free", [[True, True, True, True], [True, True, False, True], [False, True, True, False]])
def test_masked_fit_matches_scipy_on_the_free_subset(free, on_host):
    y = _data()
    free = np.array(free)
    theta0 = np.array([1.5, -0.2, 0.1, 0.0])
    fit = _fit(_fun(y), theta0, free, on_host=on_host)
    assert fit.converged and fit.steps > 0

    def res(x):
        th = theta0.copy()
        th[free] = x
        return np.asarray(_fun(y)(jnp.asarray(th))[0]).ravel()

    ref = least_squares(res, theta0[free], method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14)
    cov_ref = np.linalg.inv(ref.jac.T @ ref.jac)  # Gauss-Newton covariance of the free entries
    # the loop stops when χ² decreases by < 1e-9 relative: θ within 1e-3 standard errors
    assert np.all(np.abs(fit.theta[free] - ref.x) < 1e-3 * np.sqrt(np.diag(cov_ref)))
    np.testing.assert_array_equal(fit.theta[~free], theta0[~free])  # fixed entries untouched
    np.testing.assert_allclose(fit.chi2, 2 * ref.cost, rtol=1e-8)
    np.testing.assert_allclose(fit.covariance, cov_ref, rtol=1e-3)


def test_failed_samples_never_accepted_and_never_nan():
    """A required sample that would fail at the unconstrained optimum stops the fit short
    of it (the optimum sits in the success region); a sample that is not required and
    always fails contributes zero rows and ``ok = False``, never NaN."""
    y = _data()
    theta0 = np.array([1.5, -0.2, 0.1, 0.0])
    free = np.ones(4, bool)
    unconstrained = _fit(_fun(y), theta0, free)
    limit = 0.5 * (theta0[0] + unconstrained.theta[0])  # sample 0 fails beyond this amplitude

    def fail(th):  # sample 0 beyond the limit; sample 5 never converges
        return (jnp.arange(T.size) == 0) & (th[0] > limit) | (jnp.arange(T.size) == 5)

    need = np.ones(T.size, bool)
    need[5] = False
    fit = _fit(_fun(y, fail=fail), theta0, free, must_succeed=need)
    assert fit.theta[0] <= limit and fit.ok[0] and not fit.ok[5]
    assert np.all(np.isfinite(fit.r)) and np.all(np.isfinite(fit.J)) and np.all(fit.r[5] == 0)
    assert fit.chi2 > unconstrained.chi2 * (1 + 1e-6)


def test_failed_start_is_a_status():
    y = _data()
    fail = lambda th: jnp.arange(T.size) == 3  # noqa: E731
    fit = _fit(_fun(y, fail=fail), np.array([1.5, -0.2, 0.1, 0.0]), np.ones(4, bool))
    assert not fit.converged and fit.steps == 0 and "[3]" in fit.message
    assert not fit.ok[3] and np.all(np.isfinite(fit.r))


def test_host_and_traced_drivers_take_the_same_steps():
    """Both drivers run the same kernels: same steps, same optimum to rounding."""
    y = _data(1)
    free = np.array([True, True, False, True])
    theta0 = np.array([1.5, -0.2, 0.1, 0.0])
    a = _fit(_fun(y), theta0, free)
    b = _fit(_fun(y), theta0, free, on_host=True)
    assert a.steps == b.steps and a.message == b.message
    np.testing.assert_allclose(a.theta, b.theta, rtol=1e-12, atol=1e-14)
