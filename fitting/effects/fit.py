"""The diagnosis's masked fits: :func:`fitting.calibration.lm.masked_levenberg_marquardt` over a subset of the
extended model's flat parameter vector, results as host arrays (:class:`MaskedFit`).

The diagnosis fits dozens of models (every candidate, every cross-validation fold, on
every data set) that differ only in which entries of ``θ`` are free and which samples
are weighted in. The free mask, the fixed values, the required samples and the sample
weights are data of one compiled ``lax.while_loop`` around
:func:`fitting.effects.model.residuals_and_jacobian`: one compilation serves them all.
Grammar-term models (:class:`fitting.effects.terms_model.TermModel`, composed on the host
from compiled parts) run the same kernels through :func:`fitting.calibration.lm.drive_on_host`.
"""

from dataclasses import dataclass

import numpy as np

from cstiffjax.core.status import Status, code
from fitting.calibration import lm
from fitting.calibration.lm import drive_on_host, fit_converged, fit_message, masked_levenberg_marquardt


@dataclass
class MaskedFit:
    """Result of :func:`fit_masked` (numpy).

    ``theta`` (P,) full vector; ``free`` (P,) bool; ``r`` (n, c) whitened residuals;
    ``J`` (n·c, P) Jacobian; ``ok`` (n,) per-sample solver success (a sample whose
    residuals or Jacobian rows are not finite counts as failed; its entries are 0);
    ``chi2``; ``covariance`` (k, k) Gauss-Newton covariance of the free entries
    (unit-variance residuals; NaN when the start failed); ``steps``; ``converged``;
    ``message``.
    """

    theta: np.ndarray
    free: np.ndarray
    r: np.ndarray
    J: np.ndarray
    ok: np.ndarray
    chi2: float
    covariance: np.ndarray
    steps: int
    converged: bool
    message: str


def to_masked_fit(res, free, need) -> MaskedFit:
    """:class:`MaskedFit` of an :class:`fitting.calibration.lm.LMResult` (``need``: the required samples);
    the covariance of the free entries is formed here from the result's Jacobian."""
    free = np.asarray(free, dtype=bool)
    # numpy only: an eager jax op here would compile a small program, which waits ~2 s for
    # the background thread's compilation of a model on a cold run
    ok, J = np.asarray(res.ok), np.asarray(res.jacobian)
    Jf = J[:, free]
    cov = np.linalg.pinv(Jf.T @ Jf, hermitian=True)  # formed here: cheaper than in the compiled loop
    message = fit_message(res.result)
    if code(res.result) == code(Status.start_failed):
        bad = np.flatnonzero(~ok & np.asarray(need, dtype=bool))
        cov = np.full(cov.shape, np.nan)
        message = f"forward statics failed at the start for samples {bad.tolist()}"
    return MaskedFit(np.asarray(res.theta), free, np.asarray(res.residuals), J, ok,
                     float(res.chi2), cov, int(res.steps), fit_converged(res.result), message)


def fit_masked(fun, theta0, args, free, *, must_succeed=None, max_steps: int = 60, rtol: float = 1e-9,
               on_host: bool = False, quick: bool = False) -> MaskedFit:
    """Minimise ``Σ r(θ)²`` over ``θ[free]`` (:func:`fitting.calibration.lm.masked_levenberg_marquardt`).

    **Arguments:**

    - ``fun``: ``(θ, args) -> (r (n, c), J (n·c, P), ok (n,))`` traceable and hashable; or,
      with ``on_host``, ``θ -> (r, J, ok)`` composed on the host (``args`` unused).
    - ``theta0``: (P,) start (dimensionless θ). ``free``: (P,) bool mask of the entries to fit.
    - ``must_succeed``: (n,) bool, samples whose forward solve must converge for a step
      to be accepted (default all).
    - ``max_steps``: accepted steps at most. ``rtol``: stop when the χ² decrease is below
      ``rtol · χ²`` (plus 1e-12).
    - ``quick``: the loop compiled for compile time (``masked_levenberg_marquardt``'s ``quick``).

    **Returns:** a :class:`MaskedFit`; ``converged`` false (with ``message``) if the start
    point has failed required samples or the iteration limit is hit.
    """
    kw = _options(free, must_succeed, max_steps, rtol)
    res = drive_on_host(fun, theta0, **kw) if on_host else masked_levenberg_marquardt(fun, theta0, args, **kw,
                                                                                       quick=quick)
    need = np.ones(res.ok.shape, bool) if must_succeed is None else must_succeed
    return to_masked_fit(res, free, need)


def _options(free, must_succeed, max_steps, rtol) -> dict:
    return dict(free=np.asarray(free, dtype=bool), must_succeed=must_succeed, max_steps=max_steps, rtol=rtol,
                covariance=False)  # formed by to_masked_fit, in numpy


def lower_masked(fun, theta0, args, free, *, must_succeed=None, max_steps: int = 60, rtol: float = 1e-9,
                 quick: bool = False):
    """What :func:`fit_masked` (not ``on_host``) would run on arguments of this structure,
    traced and lowered without running it (:func:`fitting.calibration.lm.lower`; values are ignored):
    ``.compile()`` compiles it for the later fit."""
    return lm.lower(fun, theta0, args, **_options(free, must_succeed, max_steps, rtol), quick=quick)
