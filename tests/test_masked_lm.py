"""The diagnosis's masked Levenberg-Marquardt (:func:`fitting.effects.fit.levenberg_marquardt`)
against scipy's least squares on the free subset, and its failed-sample handling.

Pure numpy residuals (milliseconds): the loop is model-agnostic, the diagnosis tests
exercise it on the compiled CDPR model."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from fitting.effects.fit import levenberg_marquardt

T = np.linspace(0.0, 4.0, 25)
TRUE = np.array([2.0, -0.7, 0.3, 0.05])  # amplitude, log-rate, offset, slope


def _model(th):
    return th[0] * np.exp(np.exp(th[1]) * -T) + th[2] + th[3] * T


def _data(seed=0):
    return _model(TRUE) + 0.01 * np.random.default_rng(seed).standard_normal(T.size)


def _fun(y, sigma=0.01, fail=None):
    """``θ -> (r (n, 1), J (n, 4), ok (n,))``; ``fail(θ) -> (n,) bool`` marks failed samples
    (their residuals NaN, as a failed forward solve would give)."""

    def fun(th):
        th = np.asarray(th, float)
        e = np.exp(np.exp(th[1]) * -T)
        r = (y - _model(th)) / sigma
        J = -np.stack([e, th[0] * e * (-T * np.exp(th[1])), np.ones_like(T), T], axis=1) / sigma
        ok = np.ones(T.size, bool) if fail is None else ~fail(th)
        r = np.where(ok, r, np.nan)
        return r[:, None], np.where(ok[:, None], J, np.nan), ok

    return fun


@pytest.mark.parametrize("free", [[True, True, True, True], [True, True, False, True], [False, True, True, False]])
def test_masked_fit_matches_scipy_on_the_free_subset(free):
    y = _data()
    free = np.array(free)
    theta0 = np.array([1.5, -0.2, 0.1, 0.0])
    fit = levenberg_marquardt(_fun(y), theta0, free)
    assert fit.converged and fit.steps > 0

    def res(x):
        th = theta0.copy()
        th[free] = x
        return _fun(y)(th)[0].ravel()

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
    unconstrained = levenberg_marquardt(_fun(y), theta0, free)
    limit = 0.5 * (theta0[0] + unconstrained.theta[0])  # sample 0 fails beyond this amplitude

    def fail(th):
        out = np.zeros(T.size, bool)
        out[0] = th[0] > limit
        out[5] = True  # never converges
        return out

    need = np.ones(T.size, bool)
    need[5] = False
    fit = levenberg_marquardt(_fun(y, fail=fail), theta0, free, must_succeed=need)
    assert fit.theta[0] <= limit and fit.ok[0] and not fit.ok[5]
    assert np.all(np.isfinite(fit.r)) and np.all(np.isfinite(fit.J)) and np.all(fit.r[5] == 0)
    assert fit.chi2 > unconstrained.chi2 * (1 + 1e-6)


def test_failed_start_is_a_status():
    y = _data()
    fail = lambda th: np.arange(T.size) == 3  # noqa: E731
    fit = levenberg_marquardt(_fun(y, fail=fail), np.array([1.5, -0.2, 0.1, 0.0]), np.ones(4, bool))
    assert not fit.converged and fit.steps == 0 and "[3]" in fit.message
    assert not fit.ok[3] and np.all(np.isfinite(fit.r))
