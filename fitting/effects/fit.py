"""Levenberg-Marquardt over a *masked* subset of a flat parameter vector, driven from
Python around one compiled ``(r, J, ok)`` function.

The diagnosis fits dozens of models (every candidate, every cross-validation fold, on
every data set) that differ only in which entries of ``θ`` are free and which samples
are weighted in. The residual/Jacobian of the *full* vector is compiled once
(:func:`fitting.effects.model.residuals_and_jacobian`; grammar terms reuse it through
:meth:`fitting.effects.terms_model.TermModel.evaluate`) and the loop (a few small dense
solves per fit) runs in numpy. The covariance is the same Gauss-Newton ``(JᵀJ)⁻¹`` as
:class:`fitting.least_squares.LSResult`'s.

Why not optimistix (:func:`fitting.least_squares.solve_least_squares`), issue 13: the
same fits done with ``optx.LevenbergMarquardt`` on ``y -> r(where(free, y, θ_fixed))``,
with the mask, the fixed values, the required samples and the sample weights passed as
data (one compilation for every free set and fold), were measured slower
(``benchmarks/bench_masked_lm.py``, bundled concealed example, 90 samples, θ of 54
entries, fresh processes, 2 shared cores at load average 9-10): first fit (compile +
fit) 118 s vs 87 s here; each later fit 5.5-27 s (9-27 optimistix steps; 1.5-6.2 s with
``options={"jac": "bwd"}``) vs 0.3-1.0 s (3-4 iterations here), a held-out fold 8.5 s vs
0.3 s; process CPU 73 s (67 s) vs 31 s; the
same optima (χ² equal to 4 decimals). One evaluation of ``(r, J)`` costs the same in
both (0.07 s, also inside a ``lax.fori_loop`` body); the difference is optimistix's step
count and per-step cost. The
diagnosis therefore keeps this loop; calibration keeps optimistix (it must also run
under ``jit``/``vmap``, this loop cannot).
"""

from dataclasses import dataclass

import numpy as np


@dataclass
class MaskedFit:
    """Result of :func:`levenberg_marquardt`.

    ``theta`` (P,) full vector; ``free`` (P,) bool; ``r`` (n, c) whitened residuals;
    ``J`` (n·c, P) Jacobian; ``ok`` (n,) per-sample solver success (a sample whose residuals or Jacobian rows
    are not finite counts as failed); ``chi2``;
    ``covariance`` (k, k) Gauss-Newton covariance of the free entries (unit-variance
    residuals); ``steps``; ``converged``; ``message``.
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


def levenberg_marquardt(fun, theta0, free, *, max_steps: int = 60, rtol: float = 1e-9,
                        must_succeed=None) -> MaskedFit:
    """Minimise ``Σ r(θ)²`` over ``θ[free]``.

    **Arguments:**

    - ``fun``: ``θ -> (r, J, ok)`` (numpy-convertible); ``J`` the Jacobian of ``r.ravel()``.
    - ``theta0``: (P,) start. ``free``: (P,) bool mask of the entries to fit.
    - ``max_steps``: outer iterations. ``rtol``: stop when the χ² decrease is below
      ``rtol · χ²`` (plus 1e-12).
    - ``must_succeed``: (n,) bool, samples whose forward solve must converge for a
      step to be accepted (default all).

    **Returns:** a :class:`MaskedFit`; ``converged`` false (with ``message``) if the start
    point has failed samples or the iteration limit is hit.
    """
    theta = np.array(theta0, dtype=float)
    free = np.asarray(free, dtype=bool)

    def ev(th):
        r, J, ok = (np.asarray(a) for a in fun(th))
        finite = np.all(np.isfinite(J).reshape(len(ok), -1), axis=1) & np.all(np.isfinite(r.reshape(len(ok), -1)), 1)
        return np.where(np.isfinite(r), r, 0.0), np.where(np.isfinite(J), J, 0.0), ok & finite

    r, J, ok = ev(theta)
    need = np.ones_like(ok, dtype=bool) if must_succeed is None else np.asarray(must_succeed, dtype=bool)
    if not np.all(ok[need]):
        bad = np.flatnonzero(~ok & need)
        return MaskedFit(theta, free, r, J, ok, float(np.sum(r * r)), np.full((free.sum(),) * 2, np.nan),
                         0, False, f"forward statics failed at the start for samples {bad.tolist()}")
    cost = float(np.sum(r * r))
    lam, converged, steps, message = 1e-4, False, 0, "iteration limit"
    for steps in range(1, max_steps + 1):  # noqa: B007
        Jf = J[:, free]
        g = Jf.T @ r.ravel()
        A = Jf.T @ Jf
        d = np.where(np.diag(A) > 0, np.diag(A), 1.0)
        accepted = False
        while lam < 1e12:
            try:
                step = np.linalg.solve(A + lam * np.diag(d), -g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            trial = theta.copy()
            trial[free] += step
            rn, Jn, okn = ev(trial)
            cn = float(np.sum(rn * rn))
            if np.all(okn[need]) and np.isfinite(cn) and cn <= cost:
                accepted = True
                break
            lam *= 10
        if not accepted:
            converged, message = True, "no further decrease"
            break
        decrease = cost - cn
        theta, r, J, ok, cost = trial, rn, Jn, okn, cn
        lam = max(lam / 10, 1e-12)
        if decrease <= rtol * cost + 1e-12:
            converged, message = True, "converged"
            break
    Jf = J[:, free]
    try:
        cov = np.linalg.pinv(Jf.T @ Jf, hermitian=True)
    except np.linalg.LinAlgError:
        cov = np.full((free.sum(),) * 2, np.nan)
    return MaskedFit(theta, free, r, J, ok, cost, cov, steps, converged, message)
