"""fitting.posterior.sampler on linear-Gaussian models, where the posterior is known exactly."""

import time

import jax.numpy as jnp
import numpy as np
import pytest

from fitting.calibration.least_squares import calibrate_model
from fitting.posterior.sampler import ChainTooShortError, posterior_predictive_check, sample_posterior

TRUE = {"a": 0.7, "b": -1.2}
X = np.linspace(-1.0, 2.0, 25)
SIGMA = 0.3


def line(params, x):
    return params["a"] + params["b"] * x


def _data(rng):
    return TRUE["a"] + TRUE["b"] * X + SIGMA * rng.normal(size=X.size)


@pytest.fixture(scope="module")
def fit():
    y = _data(np.random.default_rng(0))
    return calibrate_model(line, {"a": 0.0, "b": 0.0}, X, y, SIGMA)


@pytest.fixture(scope="module")
def post(fit):
    return sample_posterior(fit, nwalkers=16, nsteps=3000, seed=1)


def test_ls_matches_closed_form(fit):
    A = np.stack([np.ones_like(X), X], 1) / SIGMA
    y = np.asarray(fit.args[1]) / SIGMA
    cov = np.linalg.inv(A.T @ A)
    np.testing.assert_allclose(fit.covariance, cov, rtol=1e-8)
    np.testing.assert_allclose([fit.values["a"], fit.values["b"]], cov @ A.T @ y, rtol=1e-8)


def test_posterior_matches_ls_covariance(fit, post):
    s = post.summary()
    cov = np.asarray(fit.covariance)
    sd = np.sqrt(np.diag(cov))
    mean_ls = np.array([fit.values["a"], fit.values["b"]])
    # Monte Carlo error of the mean ~ sd / sqrt(ESS); ESS is in the thousands
    assert np.all(np.abs(s["mean"] - mean_ls) < 5 * sd / np.sqrt(s["ess"]))
    np.testing.assert_allclose(s["std"], sd, rtol=0.08)
    corr_mc = s["covariance"][0, 1] / np.prod(s["std"])
    corr_ls = cov[0, 1] / np.prod(sd)
    assert abs(corr_mc - corr_ls) < 0.05
    assert 0.2 < s["acceptance_fraction"] < 0.9
    assert post.samples.shape == (3000, 16, 2)


def test_too_short_chain_refused(fit):
    short = sample_posterior(fit, nwalkers=16, nsteps=200, seed=2)
    with pytest.raises(ChainTooShortError, match=r"nsteps >= \d+"):
        short.summary()
    s = short.summary(check=False)  # explicit opt-out still works
    assert np.all(np.isfinite(s["mean"]))


def test_bad_walkers(fit):
    with pytest.raises(ValueError, match=r"nwalkers must be at least 2 x \(number of free parameters\) = 4, got 3"):
        sample_posterior(fit, nwalkers=3, nsteps=10)


def test_seeded_reproducible(fit):
    a = sample_posterior(fit, nwalkers=8, nsteps=50, seed=5)
    b = sample_posterior(fit, nwalkers=8, nsteps=50, seed=5)
    np.testing.assert_array_equal(a.samples, b.samples)


def test_posterior_predictive_check(post):
    ppc = posterior_predictive_check(post, ndraws=400, seed=0)
    assert ppc["num_data"] == X.size
    assert 0.02 < ppc["p_value"] < 0.98
    # a model that misses the slope is flagged
    y = _data(np.random.default_rng(9)) + 1.5 * X**2
    bad = calibrate_model(line, {"a": 0.0, "b": 0.0}, X, y, SIGMA)
    pb = posterior_predictive_check(sample_posterior(bad, nwalkers=8, nsteps=300, seed=0), ndraws=200)
    assert pb["p_value"] < 0.01


def test_positive_parameter_posterior_uses_log_jacobian():
    """With a log transform the sampler must still target a density flat in the value k.

    Four data y ~ N(k, 1) with k = 1: the likelihood's width (0.5) is half the value, so the
    log-Jacobian matters. Flat in k > 0, the posterior is the normal N(ȳ, 1/4) truncated at
    0 (scipy truncnorm, independent of the code). Without the Jacobian the density in k is
    L(k)/k (improper at 0: the chain drifts to k -> 0); with it doubled, L(k)·k (mean
    higher by ≈ 0.25): both are more than 10 Monte-Carlo standard errors away."""
    from scipy import stats

    rng = np.random.default_rng(3)
    x = np.arange(4.0)
    y = 1.0 + rng.normal(size=4)
    f = calibrate_model(lambda p, x: p["k"] * jnp.ones_like(x), {"k": 1.0}, x, y, 1.0, transforms={"k": "log"})
    s = sample_posterior(f, nwalkers=8, nsteps=3000, seed=0).summary()
    exact = stats.truncnorm((0 - y.mean()) / 0.5, np.inf, loc=y.mean(), scale=0.5)
    se = exact.std() / np.sqrt(s["ess"][0])  # Monte-Carlo standard error of the mean
    assert 0.03 < exact.mean() - y.mean() < 0.3  # the truncation itself is visible
    assert abs(s["mean"][0] - exact.mean()) < 4 * se and 4 * se < 0.1
    np.testing.assert_allclose(s["std"][0], exact.std(), rtol=0.12)  # ~3 sd of a sample std at this ESS
    np.testing.assert_allclose(s["lower"][0], exact.ppf(0.05), atol=6 * se)


def test_posterior_intervals_match_exact_gaussian_intervals(fit, post):
    """The posterior of a linear-Gaussian model with a flat prior is N(θ̂, (AᵀA)⁻¹):
    the sampled 90% interval ends must match θ̂ ± 1.645 σ to Monte Carlo error."""
    s = post.summary()
    sd = np.sqrt(np.diag(np.asarray(fit.covariance)))
    mean = np.array([fit.values["a"], fit.values["b"]])
    tol = 6 * sd / np.sqrt(s["ess"])  # quantile MC error is ~2 sd/sqrt(ESS) at the 5% level
    np.testing.assert_allclose(s["lower"], mean - 1.6449 * sd, atol=float(np.max(tol)))
    np.testing.assert_allclose(s["upper"], mean + 1.6449 * sd, atol=float(np.max(tol)))


def test_least_squares_90_percent_intervals_cover_85_to_95_percent():
    """Over 500 data sets (1000 intervals, binomial sd 0.95%) θ̂ ± 1.645 std covers."""
    rng = np.random.default_rng(12)
    hits = []
    truth = np.array([TRUE["a"], TRUE["b"]])
    for _ in range(500):
        f = calibrate_model(line, {"a": 0.0, "b": 0.0}, X, _data(rng), SIGMA)
        v = np.array([f.values["a"], f.values["b"]])
        sd = np.array([f.std["a"], f.std["b"]])
        hits.append(np.abs(v - truth) <= 1.6449 * sd)
    assert 0.85 <= np.mean(hits) <= 0.95


@pytest.mark.slow
def test_coverage_of_90_percent_intervals():
    """Over 120 synthetic data sets the 90% posterior intervals of a and b (240 intervals)
    cover the truth 85-95% of the time (binomial sd 1.9%)."""
    rng = np.random.default_rng(11)
    hits, t0 = [], time.time()
    for _ in range(120):
        f = calibrate_model(line, {"a": 0.0, "b": 0.0}, X, _data(rng), SIGMA)
        s = sample_posterior(f, nwalkers=8, nsteps=1200, seed=int(rng.integers(1 << 30))).summary(check=False)
        truth = np.array([TRUE["a"], TRUE["b"]])
        hits.append((s["lower"] <= truth) & (truth <= s["upper"]))
    cover = np.mean(hits)
    assert 0.85 <= cover <= 0.95, (cover, time.time() - t0)


# ------------------------------------------------------------ CDPR posterior (warm-started statics)
@pytest.fixture(scope="module")
def cdpr_fit():
    import jax

    from cstiffjax.examples import example_path
    from cstiffjax.io.robot_io import load_robot
    from fitting import calibrate, synthetic_recordings

    robot = load_robot(example_path("example01/robot.toml"))
    rec = synthetic_recordings(robot, jax.random.PRNGKey(21), 12)
    return calibrate(robot, rec, free=("EA", "length_offset"))


@pytest.mark.slow  # cold and warm catenary compiles (~1 min)
def test_cdpr_warm_log_prob_equals_full_solve(cdpr_fit):
    """The warm-started log-probability (poses predicted at the optimum, 2 Newton steps)
    equals the full solve (12 steps from the measured poses) at walkers spread over
    3 least-squares standard deviations, without any fallback."""
    from fitting.posterior.sampler import initial_walkers, log_prob_fn

    th = initial_walkers(cdpr_fit, 16, np.random.default_rng(0), scale=3.0)
    warm, full = log_prob_fn(cdpr_fit), log_prob_fn(cdpr_fit, warm=False)
    a, b = warm(th), full(th)
    assert warm.restarts == 0 and np.all(np.isfinite(a))
    assert np.ptp(a) > 10  # the walkers really sample different log-probabilities
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-7)


@pytest.mark.slow
def test_cdpr_log_prob_fallback_and_failure(cdpr_fit):
    """A walker far from the optimum (EA x 0.2: the warm 2-step solve cannot converge)
    is re-evaluated with the full solve and counted; one whose statics cannot converge
    at all (cables 0.1 m too long: the clipped Newton steps cannot reach) gets -inf, not NaN."""
    from fitting.posterior.sampler import log_prob_fn

    th0 = np.asarray(cdpr_fit.ls.theta)
    far = th0.copy()
    far[:6] += np.log(0.2)
    slack = th0.copy()
    slack[6:] += 0.1
    warm, full = log_prob_fn(cdpr_fit), log_prob_fn(cdpr_fit, warm=False)
    lp = warm(np.stack([th0, far, slack]))
    # the slack walker always needs the full solve; whether the EA x 0.2 one does depends on the warm
    # solver's basin (the one engine's warm start reaches it from the optimum's poses): 1 or 2 restarts
    assert warm.restarts in (1, 2)
    ref = full(np.stack([th0, far, slack]))
    np.testing.assert_allclose(lp[0], ref[0], rtol=1e-10, atol=1e-7)
    # lp[1]: the full solve, or a warm solve converged to the warm tolerance (1e-7 of the wrench
    # scale), which at a log-probability of -1.6e6 moves it by ~1e-8 relative
    np.testing.assert_allclose(lp[1], ref[1], rtol=1e-7)
    assert np.isfinite(lp[1]) and lp[1] < lp[0] - 1e3
    assert lp[2] == -np.inf and ref[2] == -np.inf


@pytest.mark.slow
def test_cdpr_posterior_chain_runs_warm(cdpr_fit):
    post = sample_posterior(cdpr_fit, nwalkers=24, nsteps=60, seed=3)
    assert post.restarts == 0
    assert post.samples.shape == (60, 24, 12) and np.all(np.isfinite(post.log_prob))
    assert 0.1 < float(np.mean(post.acceptance_fraction)) < 0.9


TOTALS: list = []


class _RecordingBar:
    """A stand-in progress bar that records every total it is given (in ``TOTALS``)."""

    def __init__(self, *a, total=None, **k):
        self.done = 0
        self._total = total
        TOTALS.append(total)

    @property
    def total(self):
        return self._total

    @total.setter
    def total(self, value):
        self._total = value
        TOTALS.append(value)

    def update(self, k):
        self.done += k

    def set_postfix_str(self, s):
        pass

    def refresh(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *a):
        return False


def test_the_progress_total_is_fixed_and_the_plan_said_up_front(fit, monkeypatch):
    """An automatic chain's bar has the cap as its total from the start (it never grows), and
    :func:`plan` says the length range and the time per step before anything runs."""
    from cstiffjax.core import progress
    from fitting.posterior.sampler import plan

    monkeypatch.setattr(progress, "bar", _RecordingBar)
    TOTALS.clear()
    post = sample_posterior(fit, nwalkers=16, seed=3, min_steps=200, max_steps=5000)
    assert TOTALS == [5000] and 200 < post.num_steps <= 5000
    p = plan(fit, nwalkers=16, min_steps=200, max_steps=5000)
    assert (p["walkers"], p["steps_min"], p["steps_max"]) == (16, 200, 5000) and 0 < p["s_per_step"] < 1.0
    assert plan(fit, nwalkers=16, nsteps=300)["steps_min"] == 300
