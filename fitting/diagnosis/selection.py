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

    def to_json(self) -> dict:
        d = {k: getattr(self, k) for k in ("effect", "delta_bic", "chi2_per_dof", "parameters", "k", "wald",
                                           "identified", "explained_fraction", "cv", "cv_reference",
                                           "accepted", "reason", "law", "screen_delta_bic")}
        d["held_out_chi2_per_datum"] = d.pop("cv")
        d["held_out_reference"] = d.pop("cv_reference")
        d["law"] = self.law.name
        return d


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
    sd = np.sqrt(np.maximum(np.diag(C), 1e-300))
    corr = C / np.outer(sd, sd)
    cond = np.linalg.cond(corr) if corr.size else 1.0
    identified = bool(np.all(np.isfinite(C)) and cond < 1e10)
    try:
        wald = float(theta_e @ np.linalg.solve(C, theta_e)) / inflate**2
    except np.linalg.LinAlgError:
        wald, identified = 0.0, False
    return out, wald, identified


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


def verdict(c, min_explained, check_cv=True):
    if not np.isfinite(c.delta_bic):
        return False, c.reason or "fit failed"
    if c.delta_bic >= BIC_THRESHOLD:
        return False, f"ΔBIC {c.delta_bic:.1f} ≥ {BIC_THRESHOLD}"
    if not c.identified:
        return False, "parameters not identified"
    if c.wald < c.wald_threshold:
        return False, f"parameters consistent with the null value (Wald {c.wald:.1f})"
    if c.explained_fraction < min_explained:
        return False, f"removes only {100 * c.explained_fraction:.0f}% of the excess χ²"
    if check_cv and (c.cv is None or not c.cv < c.cv_reference):
        return False, "held-out error not improved"
    return True, "selected"
