"""Selection of candidate effects: the scores of one candidate (ΔBIC, Wald test, held-out
error, explained share) and the verdict on it, shared by :mod:`fitting.diagnosis.diagnose`
and :mod:`fitting.diagnosis.discover` (the gates are described in the former's docstring)."""

from dataclasses import dataclass

import numpy as np

from cstiffjax.cable.laws import CableLaw
from fitting.diagnosis.effect_posterior import WALD_P

BIC_THRESHOLD = -10.0  # "strong" evidence on the BIC scale (Kass & Raftery)


@dataclass
class Candidate:
    """One effect tried on top of the current model (see module docstring)."""

    effect: str
    delta_bic: float
    chi2_per_dof: float
    parameters: dict
    k: int
    wald: float
    wald_threshold: float
    identified: bool
    explained_fraction: float
    cv: float | None = None
    cv_reference: float | None = None
    accepted: bool = False
    reason: str = ""
    law: CableLaw = CableLaw.spring  # the cable law of the fitted model (small_sag: cable_mass's screen)
    screen_delta_bic: float | None = None  # the small-sag screen's ΔBIC when the catenary was fitted after it
    physical: str = ""  # why the estimate is no physical evidence (Domain.problem), "" when it is
    penalty: float = 0.0  # extra evidence (BIC units) an implausible correction needs (grammar plausibility)
    plausibility: str = ""  # the physical reading behind ``penalty``
    equivalent: str = ""  # a look-alike reading the recordings cannot tell from this effect
    rejected_because: str = ""  # the physical reason it was rejected ("" when rejected on the statistics)

    def to_json(self) -> dict:
        d = {k: getattr(self, k) for k in ("effect", "delta_bic", "chi2_per_dof", "parameters", "k", "wald",
                                           "identified", "explained_fraction", "cv", "cv_reference",
                                           "accepted", "reason", "law", "screen_delta_bic")}
        d["held_out_chi2_per_datum"] = d.pop("cv")
        d["held_out_reference"] = d.pop("cv_reference")
        d["law"] = self.law.name
        if self.rejected_because and not self.accepted:
            d["rejected_because"] = self.rejected_because
        if self.equivalent:
            d["equivalent"] = self.equivalent
        return d


def physical_problem(effect, params: dict, robot, data) -> str:
    """Why the fitted ``params`` (:func:`effect_parameters`) of ``effect`` (a vocabulary
    effect or a grammar :class:`~fitting.effects.grammar.Term`) are no physical evidence for
    it (the first :meth:`~fitting.effects.base.Domain.problem` of its parameter specs), or ``""``."""
    owner = getattr(effect, "family", effect)  # a grammar term: its family's specs
    for spec in owner.specs(robot, data):
        p = params.get(spec.name)
        if p is None:
            continue
        why = spec.domain.problem(spec.name, p["value"], p["std"], p["null"], p["unit"])
        if why:
            return why
    return ""


def effect_parameters(model, fit, name, inflate):
    """``{param: {value, std, null, unit}}`` of effect ``name`` in a fit, physical units."""
    i = model.effect_index(name)
    sl = model.block_slice(i)
    idx_free = np.flatnonzero(fit.free)
    pos = {int(j): q for q, j in enumerate(idx_free)}
    phys = np.asarray(model.null) + np.asarray(model.scale) * fit.theta
    out = {}
    for bi, nm, off, shape, unit in model.blocks:
        if bi != i:
            continue
        size = int(np.prod(shape, dtype=int))
        ids = range(off, off + size)
        std = np.array([np.sqrt(max(fit.covariance[pos[j], pos[j]], 0.0)) for j in ids]) * np.asarray(
            model.scale)[off:off + size] * inflate
        val = phys[off:off + size]
        shape_out = (lambda a: float(a[0])) if shape == () else (lambda a, s=shape: a.reshape(s).tolist())
        out[nm] = {"value": shape_out(val), "std": shape_out(std), "null": shape_out(np.asarray(model.null)[ids]),
                   "unit": unit}
    theta_e = fit.theta[sl]
    cov_idx = [pos[j] for j in range(sl.start, sl.stop)]
    C = fit.covariance[np.ix_(cov_idx, cov_idx)]
    gauge = getattr(model.effects[i], "gauge", lambda m: None)(model.num_cables)  # (a grammar term: none)
    if gauge is not None:  # judge the effect on what the recordings can see (Effect.gauge)
        Q = _complement(np.asarray(gauge, dtype=float))
        P, scale = Q @ Q.T, np.asarray(model.scale)[sl]
        (d,) = out.values()  # (an effect with a gauge has one parameter block)
        null = np.ravel(d["null"])
        value = null + scale * (P @ ((np.ravel(d["value"]) - null) / scale))  # reported without the unseen part
        std = scale * np.sqrt(np.maximum(np.diag(P @ C @ P), 0.0)) * inflate
        d["value"], d["std"] = value.reshape(np.shape(d["value"])).tolist(), std.reshape(np.shape(d["std"])).tolist()
        theta_e, C = Q.T @ theta_e, Q.T @ C @ Q
    sd = np.sqrt(np.maximum(np.diag(C), 1e-300))
    corr = C / np.outer(sd, sd)
    cond = np.linalg.cond(corr) if corr.size else 1.0
    identified = bool(np.all(np.isfinite(C)) and cond < 1e10)
    try:
        wald = float(theta_e @ np.linalg.solve(C, theta_e)) / inflate**2
    except np.linalg.LinAlgError:
        wald, identified = 0.0, False
    return out, wald, identified


def _complement(G: np.ndarray) -> np.ndarray:
    """``(P, P - k)`` orthonormal basis of the directions orthogonal to the rows of ``G`` ``(k, P)``."""
    _, sv, Vt = np.linalg.svd(G, full_matrices=True)
    rank = int(np.sum(sv > 1e-12 * max(sv.max(initial=0.0), 1e-300)))
    return Vt[rank:].T


def wald_critical(k: int) -> float:
    """Critical χ² of the Wald test of ``k`` effect parameters at level :data:`WALD_P`
    (``scipy.special``, imported here: 0.07 s; ``scipy.stats`` would be 0.4 s, which a
    diagnosis that selects nothing, and so never imports emcee, does not pay)."""
    from scipy import special

    return float(special.chdtri(k, WALD_P))


def chi2_dof(fit, ndata):
    return fit.chi2 / max(ndata - int(fit.free.sum()), 1)


def explained_threshold(dof):
    return 1.0 + max(0.25, 5.0 * np.sqrt(2.0 / max(dof, 1)))


def physical_verdict(c) -> str:
    """The physical reason candidate ``c`` is rejected, or ``""``: its estimate lies at or
    beyond a bound of its parameters' domains or is too small for hardware to produce
    (``c.physical``), or it is an implausible correction (``c.penalty`` > 0) whose evidence
    does not reach ``BIC_THRESHOLD - penalty``."""
    if c.physical:
        return f"no physical evidence: {c.physical}"
    if c.penalty > 0 and c.delta_bic + c.penalty >= BIC_THRESHOLD:
        return (f"implausible ({c.plausibility}): such a correction needs ΔBIC < {BIC_THRESHOLD - c.penalty:.0f}, "
                f"it has {c.delta_bic:.1f}")
    return ""


def verdict(c, min_explained, check_cv=True):
    if not np.isfinite(c.delta_bic):
        return False, c.reason or "fit failed"
    if c.delta_bic >= BIC_THRESHOLD:
        return False, f"ΔBIC {c.delta_bic:.1f} ≥ {BIC_THRESHOLD}"
    if not c.identified:
        return False, "parameters not identified"
    if c.wald < c.wald_threshold:
        return False, f"parameters consistent with the null value (Wald {c.wald:.1f})"
    if why := physical_verdict(c):
        return False, why
    if c.explained_fraction < min_explained:
        return False, f"removes only {100 * c.explained_fraction:.0f}% of the excess χ²"
    if check_cv and (c.cv is None or not c.cv < c.cv_reference):
        return False, "held-out error not improved"
    return True, "selected"


EA_LOG_STD_MAX = 1.0  # an EA whose ln-scale std exceeds this (a factor e ≈ 2.7) is not identified


def calibrated_ea(nominal, fit, inflate: float) -> dict:
    """The ``calibrated`` entry (formats.md §3) of a diagnosis fit: every cable's ``EA`` (N),
    with the cables whose ``EA`` the recordings do not determine reported as such.

    A cable's ``EA`` is fitted as ``θ_j = ln(EA_j / EA_nominal_j)`` (the first entries of
    ``fit.theta``). It counts as identified when its Gauss-Newton standard deviation on that
    scale is at most :data:`EA_LOG_STD_MAX`, both with the other parameters fitted (the
    covariance) and with them held (``1 / |J_j|``), each times ``inflate``. A cable that carries
    almost no tension in every sample fails this (the fit may drive its ``EA`` towards 0: a
    compressed spring is best matched by no spring), and so does a baseline that makes up for
    a missing effect with a near-rigid cable (``EA`` run away to 10⁵ × nominal): its nominal
    value is reported in ``EA`` and the fitted one, with the reason, under ``unidentified``.

    **Arguments:** ``nominal`` (m,) nominal EA, N; ``fit``: a
    :class:`~fitting.effects.fit.MaskedFit` whose EA entries were free; ``inflate``: the
    factor the standard deviations are inflated by (``sqrt(max(1, χ²/dof))``).

    **Returns:** ``{"EA": [m positive numbers, N], "unidentified": [{"cable": 1-based,
    "fitted_EA": N or None, "std_ln_EA": float or None, "reason": str}]}``.
    """
    nominal = np.asarray(nominal, dtype=float)
    m = nominal.size
    with np.errstate(over="ignore", under="ignore", invalid="ignore", divide="ignore"):
        fitted = nominal * np.exp(np.asarray(fit.theta[:m], dtype=float))
        info = np.sum(np.asarray(fit.J)[:, :m] ** 2, axis=0)  # the free EA entries come first
        held = inflate / np.sqrt(info)
        cov = np.asarray(fit.covariance)
        marginal = inflate * np.sqrt(np.abs(np.diag(cov)[:m])) if cov.shape[0] >= m else np.full(m, np.nan)
    ea, unidentified = fitted.copy(), []
    for j in range(m):
        std = max(held[j], marginal[j]) if np.isfinite(held[j]) and np.isfinite(marginal[j]) else np.inf
        if np.isfinite(fitted[j]) and fitted[j] > 0 and std <= EA_LOG_STD_MAX:
            continue
        ea[j] = nominal[j]
        value = f"{fitted[j]:.3g} N" if np.isfinite(fitted[j]) else "not finite"
        spread = f"a standard deviation of ln EA of {std:.3g}" if np.isfinite(std) else "no information on it"
        unidentified.append({
            "cable": j + 1, "fitted_EA": float(fitted[j]) if np.isfinite(fitted[j]) else None,
            "std_ln_EA": float(std) if np.isfinite(std) else None,
            "reason": f"cable {j + 1}: the recordings do not determine EA (fitted {value}, {spread}: a cable that "
                      f"carries almost no tension in every sample, or a model that makes up for a missing effect "
                      f"with a near-slack or near-rigid cable); the nominal {nominal[j]:.6g} N is reported"})
    return {"EA": ea.tolist(), "unidentified": unidentified}
