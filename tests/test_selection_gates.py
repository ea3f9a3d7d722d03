"""Every selection gate of :mod:`fitting.diagnosis.diagnose` pinned on both sides of its threshold.

Gates (module docstring of fitting/diagnosis/diagnose.py, step 3-4): ΔBIC = Δχ² + k ln N below
``BIC_THRESHOLD`` (-10), parameters identified (condition number of their correlation
< 1e10), Wald statistic above the χ²_k quantile at ``WALD_P`` (1e-3), at least
``min_explained`` of the excess χ² removed, held-out χ² improved; and the final
``explained`` rule χ²/dof <= 1 + max(0.25, 5 √(2/dof)).

Each gate is tested directly on constructed inputs just above and just below its
threshold (cheap, no compilation), and end to end: the clean lab set (example02, 20
samples) with a tension-sensor bias added to cable 1, sized from a quadratic fit of the
χ² reduction so that ΔBIC lands just above or just below -10. One compiled model (one
effect, one data shape) serves every end-to-end case.
"""

import types

import equinox as eqx
import numpy as np
import pytest

from cstiffjax import load_recordings, load_robot
from cstiffjax.examples import example_path
from fitting.diagnosis import selection as D
from fitting.diagnosis.diagnose import diagnose
from fitting.effects import TensionSensorBias, build_data, make_model

BIC_STRONG = -10.0  # the documented threshold ("strong" evidence, Kass & Raftery), not read from the code
WALD_6_AT_1E3 = 22.4577  # χ² quantile, 6 dof, upper tail 1e-3 (standard tables, e.g. NIST/SEMATECH 1.3.6.7.4)
WALD_1_AT_1E3 = 10.828  # same, 1 dof


def _cand(**kw):
    base = dict(effect="tension_sensor_bias", delta_bic=-50.0, chi2_per_dof=1.0, parameters={}, k=6, wald=100.0,
                wald_threshold=WALD_6_AT_1E3, identified=True, explained_fraction=0.9, cv=1.0, cv_reference=1.5)
    base.update(kw)
    return D.Candidate(**base)


# ------------------------------------------------------------------ gates, direct
def test_constants_are_the_documented_ones():
    assert D.BIC_THRESHOLD == BIC_STRONG
    from fitting.diagnosis.effect_posterior import WALD_P

    assert WALD_P == 1e-3
    from scipy import stats

    assert stats.chi2.isf(WALD_P, 6) == pytest.approx(WALD_6_AT_1E3, abs=1e-4)
    assert stats.chi2.isf(WALD_P, 1) == pytest.approx(WALD_1_AT_1E3, abs=1e-3)


@pytest.mark.parametrize("dbic, ok", [(-10.01, True), (-9.99, False), (-10.0, False), (np.inf, False)])
def test_bic_gate(dbic, ok):
    assert D.verdict(_cand(delta_bic=dbic), 0.5)[0] is ok


@pytest.mark.parametrize("wald, ok", [(WALD_6_AT_1E3 + 0.01, True), (WALD_6_AT_1E3 - 0.01, False)])
def test_wald_gate(wald, ok):
    accepted, reason = D.verdict(_cand(wald=wald), 0.5)
    assert accepted is ok and (ok or "null value" in reason)


@pytest.mark.parametrize("frac, ok", [(0.51, True), (0.49, False)])
def test_min_explained_gate(frac, ok):
    accepted, reason = D.verdict(_cand(explained_fraction=frac), 0.5)
    assert accepted is ok and (ok or "excess" in reason)
    assert D.verdict(_cand(explained_fraction=frac), 0.3)[0]  # the threshold is the argument, not a constant


@pytest.mark.parametrize("cv, ok", [(1.499, True), (1.5, False), (1.501, False), (None, False)])
def test_held_out_gate(cv, ok):
    accepted, reason = D.verdict(_cand(cv=cv), 0.5)
    assert accepted is ok and (ok or "held-out" in reason)
    assert D.verdict(_cand(cv=cv), 0.5, check_cv=False)[0]  # first pass (before the held-out fits) ignores it


def test_identified_gate_direct():
    assert not D.verdict(_cand(identified=False), 0.5)[0]


def test_explained_threshold_values():
    """1 + max(0.25, 5 √(2/dof)): 5√(2/dof) = 0.25 at dof = 800."""
    assert D.explained_threshold(100) == pytest.approx(1 + 5 * np.sqrt(0.02))
    assert D.explained_threshold(799) == pytest.approx(1 + 5 * np.sqrt(2 / 799))
    assert D.explained_threshold(801) == pytest.approx(1.25)
    assert D.explained_threshold(10_000) == pytest.approx(1.25)


@pytest.fixture(scope="module")
def model_and_data():
    rb = load_robot(example_path("example02/robot.toml"))
    rec = load_recordings(example_path("example02/recordings.csv"), rb).select(np.arange(20))
    return rb, rec, make_model(rb, build_data(rec), [TensionSensorBias()])


def _fake_fit(model, theta_effect, cov_effect):
    m = model.num_cables
    theta = np.concatenate([np.zeros(m), theta_effect])
    cov = np.eye(model.size)
    cov[m:, m:] = cov_effect
    return types.SimpleNamespace(theta=theta, free=np.ones(model.size, bool), covariance=cov)


@pytest.mark.parametrize("one_minus_rho, ok", [(1e-9, True), (1e-11, False)])
def test_identified_gate_condition_number(model_and_data, one_minus_rho, ok):
    """Two bias entries correlated at ρ: cond = (1 + ρ)/(1 - ρ) = 2e9 (identified) or 2e11 (not)."""
    _rb, _rec, model = model_and_data
    C = np.eye(6) * 0.04
    C[0, 1] = C[1, 0] = 0.04 * (1 - one_minus_rho)
    _, _wald, identified = D.effect_parameters(model, _fake_fit(model, np.ones(6), C), "tension_sensor_bias", 1.0)
    assert identified is ok


def test_wald_statistic_and_inflation_direct(model_and_data):
    """Wald = θᵀ C⁻¹ θ / inflate² (std inflated by √(χ²/dof) when above 1)."""
    _rb, _rec, model = model_and_data
    th = np.array([0.3, -0.2, 0.1, 0.0, 0.4, -0.1])
    out, wald, ident = D.effect_parameters(model, _fake_fit(model, th, np.eye(6) * 0.01), "tension_sensor_bias", 2.0)
    assert ident and wald == pytest.approx(np.sum(th**2) / 0.01 / 4.0)
    np.testing.assert_allclose(out["bias"]["std"], [0.1 * 2.0] * 6)
    np.testing.assert_allclose(out["bias"]["value"], th)  # scale 1 N, null 0


# ------------------------------------------------------------------ gates, end to end
def _biased(rec, b):
    return eqx.tree_at(lambda r: r.tensions, rec, rec.tensions.at[:, 0].add(b))


def _run(rb, rec, **kw):
    d = diagnose(rb, rec, effects=(TensionSensorBias(),), posterior_steps=0, detect_outliers=False, **kw)
    return d, d.candidates[0]


def _reduction(d, c):
    """χ²(baseline) − χ²(with the bias), from the two fits' own χ² and dof."""
    return d.baseline["chi2"] - c.chi2_per_dof * (d.baseline["dof"] - c.k)


@pytest.fixture(scope="module")
def calibration(model_and_data):
    """The χ² reduction D(b) of a bias b on cable 1 is quadratic in b (the bias enters
    linearly and the biased fit absorbs it exactly): fitted from b = 0, 0.3, 0.6 N."""
    rb, rec, _ = model_and_data
    bs = np.array([0.0, 0.3, 0.6])
    runs = [_run(rb, _biased(rec, b)) for b in bs]
    red = np.array([_reduction(d, c) for d, c in runs])
    return np.polyfit(bs, red, 2), runs


def test_bic_penalty_is_k_ln_N(model_and_data, calibration):
    """ΔBIC − (χ²_new − χ²_old) = k ln N with k = 6 biases and N the number of recorded
    scalars (6 pose entries + each recorded tension per sample), counted here."""
    _rb, rec, _ = model_and_data
    N = 6 * rec.num_samples + int(np.sum(np.asarray(rec.tension_mask)))
    assert N == 240
    for d, c in calibration[1]:
        assert c.k == 6
        assert c.delta_bic == pytest.approx(-_reduction(d, c) + 6 * np.log(N), abs=1e-6)


def test_wald_equals_likelihood_ratio_on_a_linear_effect(calibration):
    """For an effect that enters linearly the Wald statistic equals the χ² reduction
    (likelihood ratio), divided by the inflation χ²/dof when that is above 1; EA's
    slight nonlinearity allows a per cent."""
    for d, c in calibration[1][1:]:
        assert 1.0 < c.chi2_per_dof < 1.1
        assert c.wald == pytest.approx(_reduction(d, c) / c.chi2_per_dof, rel=0.01)


@pytest.mark.parametrize("side", [-1, 1])
def test_bic_gate_end_to_end(model_and_data, calibration, side):
    """A bias whose predicted ΔBIC is -10 ∓ 2.5 is rejected (side -1) / selected (side +1)."""
    rb, rec, _ = model_and_data
    poly, _ = calibration
    penalty = 6 * np.log(240)
    target = penalty - BIC_STRONG + side * 2.5  # required χ² reduction
    roots = np.roots(poly - np.array([0, 0, target]))
    b = float(np.max(roots.real[np.abs(roots.imag) < 1e-12]))
    assert 0.2 < b < 0.6
    d, c = _run(rb, _biased(rec, b))
    assert c.delta_bic == pytest.approx(BIC_STRONG - side * 2.5, abs=1.0)  # the quadratic predicted it
    assert c.wald > c.wald_threshold and c.identified and c.explained_fraction > 0.9  # only ΔBIC decides
    if side > 0:
        assert d.effects == ["tension_sensor_bias"] and c.accepted and c.cv < c.cv_reference
    else:
        assert d.effects == [] and not c.accepted and "ΔBIC" in c.reason


@pytest.mark.parametrize("delta, ok", [(-0.05, True), (0.05, False)])
def test_min_explained_end_to_end(model_and_data, delta, ok):
    """Extra unexplainable scatter on x (3σ) leaves part of the excess to the bias; the
    share it removes, computed from the two fits' χ², decides against ``min_explained``."""
    rb, rec, _ = model_and_data
    rng = np.random.default_rng(4)
    noisy = eqx.tree_at(lambda r: r.pose, _biased(rec, 0.8),
                        rec.pose.at[:, 0].add(3.0 * float(rb.noise.position) * rng.normal(size=rec.num_samples)))
    d0, c0 = _run(rb, noisy)
    excess = d0.baseline["chi2"] - d0.baseline["dof"]
    frac = _reduction(d0, c0) / excess
    assert c0.explained_fraction == pytest.approx(frac, rel=1e-9)
    assert 0.2 < frac < 0.9 and c0.delta_bic < BIC_STRONG
    d, c = _run(rb, noisy, min_explained=frac + delta)
    assert (d.effects == ["tension_sensor_bias"]) is ok and c.accepted is ok


def test_tail_probabilities_match_scipy_stats():
    """The critical values and p-values come from ``scipy.special`` (0.07 s of import, not
    ``scipy.stats``' 0.4 s): equal to ``scipy.stats``' distributions."""
    from scipy import stats

    from fitting.diagnosis import residual_checks as RC

    for k in (1, 2, 3, 6, 18, 47):
        assert D.wald_critical(k) == pytest.approx(stats.chi2.isf(D.WALD_P, k), rel=1e-12)
    for t, dof in ((0.3, 5), (-2.5, 40), (4.0, 100), (12.0, 3)):
        assert RC._two_sided_t(t, dof) == pytest.approx(2 * stats.t.sf(abs(t), dof), rel=1e-10)
    x = np.sin(np.arange(60) * 0.7) + np.random.default_rng(0).normal(size=60)
    q, p = RC.ljung_box(x, 10)
    assert p == pytest.approx(stats.chi2.sf(q, 10), rel=1e-10) and 0 < p < 1
