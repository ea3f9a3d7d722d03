"""Is anything left in the final residual? (a stricter ``explained``).

χ²/dof near 1 says the residual is as *large* as the noise, not that it is noise. Here
every residual channel (``x y z rx ry rz t_1 … t_m``, whitened) is tested

- against every input and covariate (commanded lengths ``l0_i``, the recorded external
  wrench components, the direction of the last length change ``dir_i``, ``time``, the
  sample index and every extra numeric column): Pearson correlation, two-sided t test
  with ``n - 2`` degrees of freedom;
- for whiteness in sample (time) order: Ljung-Box statistic over lags 1..``lags``
  (χ² with ``lags`` degrees of freedom).

All p-values together get the Holm step-down correction (family-wise error rate
``alpha``); any rejection is structure left over. Measured quantities (pose, tensions)
are not used as drivers: their noise is in the residual itself. Plain numpy/scipy.
"""

import numpy as np

from cstiffjax.io import schema
from fitting.calibration.models import measured_mask
from fitting.diagnosis.localize import channel_labels, covariates, pearson

ALPHA = 0.01  # family-wise false-alarm rate of the whole battery on one data set
LAGS = 5


def drivers(recordings, data) -> dict[str, np.ndarray]:
    """The explanatory variables tested (see module doc), name -> (n,)."""
    cov = covariates(recordings, data)
    m = np.shape(recordings.l0)[1]
    measured = set(schema.column_names(m, [g for g in schema.GROUPS if g.role == "measurement"]))
    out = {k: v for k, v in cov.items() if k not in measured and not k.startswith("sag_")}
    out["index"] = np.arange(recordings.num_samples, dtype=float)
    return out


def holm(p: np.ndarray, alpha: float) -> np.ndarray:
    """Holm step-down rejections (bool, like ``p``) at family-wise level ``alpha``."""
    p = np.asarray(p, dtype=float)
    order = np.argsort(p)
    k = len(p)
    reject = np.zeros(k, dtype=bool)
    for rank, i in enumerate(order):
        if p[i] > alpha / (k - rank):
            break
        reject[i] = True
    return reject


def _two_sided_t(t: float, dof: int) -> float:
    """Two-sided p-value of Student's ``t`` with ``dof`` degrees of freedom."""
    from scipy import special  # lazy, as in fitting.diagnose.wald_critical

    return float(2 * special.stdtr(dof, -abs(t)))


def ljung_box(x: np.ndarray, lags: int = LAGS) -> tuple[float, float]:
    """``(Q, p)`` Ljung-Box statistic of ``x`` in its order over lags 1..``lags``."""
    from scipy import special  # lazy, as in fitting.diagnose.wald_critical

    x = np.asarray(x, dtype=float) - np.mean(x)
    n = len(x)
    den = float(np.sum(x * x))
    if den <= 0 or n <= lags + 2:
        return 0.0, 1.0
    q = sum((np.sum(x[h:] * x[:-h]) / den) ** 2 / (n - h) for h in range(1, lags + 1)) * n * (n + 2)
    return float(q), float(special.chdtrc(lags, q))


def residual_structure(recordings, data, r, keep, *, alpha: float = ALPHA, lags: int = LAGS) -> dict:
    """Test the whitened residuals ``r`` ``(n, 6 + m [+ sensors])`` of the samples ``keep``
    (the measured values only).

    **Returns:** ``{"structured": bool, "tests": int, "alpha": alpha, "findings": [...]}``;
    each finding ``{channel, test ("correlation" | "whiteness"), driver, statistic (r or
    Q), p}`` is a rejected hypothesis, strongest first.
    """
    r = np.asarray(r)
    keep = np.asarray(keep, dtype=bool)
    labels = channel_labels(recordings.num_cables, data.sensors)
    tmask = measured_mask(recordings, data.sensors)
    drv = drivers(recordings, data)
    tests = []
    for j in range(r.shape[1]):
        use = keep & tmask[:, j]
        n = int(use.sum())
        if n < 8 or not np.any(r[use, j] != 0):
            continue
        res = r[use, j]
        for name, v in drv.items():
            x = v[use]
            if np.ptp(x) == 0:
                continue
            rho = pearson(res, x)
            t = rho * np.sqrt((n - 2) / max(1 - rho * rho, 1e-300))
            tests.append((labels[j], "correlation", name, rho, _two_sided_t(t, n - 2)))
        q, p = ljung_box(res, lags)
        tests.append((labels[j], "whiteness", f"lags 1-{lags}", q, p))
    if not tests:
        return {"structured": False, "tests": 0, "alpha": alpha, "findings": []}
    p = np.array([t[4] for t in tests])
    rej = holm(p, alpha)
    order = np.argsort(p)
    findings = [{"channel": tests[i][0], "test": tests[i][1], "driver": tests[i][2], "statistic": float(tests[i][3]),
                 "p": float(tests[i][4])} for i in order if rej[i]]
    return {"structured": bool(rej.any()), "tests": len(tests), "alpha": alpha, "findings": findings}
