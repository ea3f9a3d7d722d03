"""emcee posterior check of an effect selected by the diagnosis (step 5 of
:mod:`fitting.diagnosis.diagnose`): are its parameters identified, and away from their null value?"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cstiffjax.core.progress import enabled
from fitting.effects.model import solutions, walker_residuals
from fitting.posterior import emcee_import as _emcee
from fitting.posterior.sampler import MIN_TAU_MULTIPLE, long_enough

WALD_P = 1e-3  # significance of the diagnosis's Wald test and of the posterior's null tail
POSTERIOR_WALKERS = 16
POSTERIOR_BURN = 20
POSTERIOR_FIRST = 100  # first chunk of the chain: 16 walkers x 80 kept steps resolve a tail of 1e-3


def with_weight(data, weight):
    """``data`` (:class:`~fitting.effects.model.ModelData`) with per-sample weights ``weight``
    (a host array stays one, a copy: ``jnp.asarray`` would compile a copy program per
    shape, ~8 ms each in a new process)."""
    w = weight.astype(jnp.float64) if isinstance(weight, jax.Array) else np.array(weight, dtype=np.float64)
    return eqx.tree_at(lambda d: d.weight, data, w)


def posterior_check(fitter, model, fit, weight, names, *, steps: int = 300, walkers: int = POSTERIOR_WALKERS,
                    seed: int = 0, progress: bool | None = None, min_steps: int = POSTERIOR_FIRST) -> dict:
    """emcee posterior of the parameters of the *selected* effects ``names`` (are
    they identified, and away from their null value?), from one chain on the final model.

    Samples every free entry of ``fit`` (EA log-scales and every effect stay free: each
    effect's marginal then carries the correlations with the others, at no extra cost since
    the full residual is evaluated anyway). The diagnosis runs it once, on its final fit:
    a posterior of the first of two effects taken before the second was in the model would
    sample ``-χ²/2`` of a model that still misses physics (χ²/dof well above 1, intervals
    too narrow by about its square root), and would cost a second chain.

    ``log p(θ) = -χ²(θ)/2`` from the diagnosis's compiled residuals (flat prior in θ: in
    the physical value of effect parameters, in log EA); a sample whose forward statics
    fails gives ``-inf``. The whole ensemble is evaluated in one call per step
    (:func:`~fitting.effects.model.walker_residuals`, the model vmapped over the walkers;
    emcee's ``vectorize``: both moves propose every walker at once), compiled ahead by
    :meth:`fitting.diagnosis.fitter.Fitter.compile_walkers`. Every walker's statics start at the
    equilibria predicted to first order from the fitted ones (one chord step,
    :func:`~fitting.effects.model.chord_start`, off at second order), solved for values only: one
    Newton step and a chord check (:func:`cstiffjax.statics.forward.forward_statics`,
    ``derivatives=False``), for the spring and catenary laws alike. Walkers (seeded)
    start from ``N(θ̂, C)``, ``C`` the Gauss-Newton covariance. ``emcee.EnsembleSampler``
    moves: 80% independence Metropolis-Hastings proposals from ``N(θ̂, 1.1² C)`` (exact MH
    with the proposal density ratio; near a Gaussian posterior it mixes in a few steps
    whatever the dimension, and a posterior unlike the Gauss-Newton one shows as low
    acceptance and long τ), 20% a random walk ``N(0, 2.38² C / d)``. The stretch move is
    not used: with fewer walkers than ``2 d`` it would not span the space.

    Chain length: ``min(min_steps, steps)`` steps first; then, while the kept steps (after
    ``burn``) are fewer than 50 integrated autocorrelation times, the chain is extended
    (to 10% beyond what the measured ``τ`` asks, at least 25 steps more) up to ``steps``.
    Near a Gaussian posterior ``τ`` is 1.5-2.5 steps, so 100 steps usually suffice (half
    the fixed 200 of earlier versions, measured on the bundled example: the same verdict).

    **Returns:** ``{name: summary}`` for every name in ``names``, each summary JSON-ready
    (the chain's numbers are shared) ``{walkers, steps, burn, samples, acceptance_fraction (mean),
    tau (largest integrated autocorrelation time over the sampled θ, steps; null if not
    finite), converged (kept steps ≥ 50 τ; if false the numbers are indicative only),
    parameters: {param: {median, interval90, null, null_outside_999, z_null}} (physical
    units, shaped like the values; ``z_null`` = (median − null) / posterior std),
    null_d2 (Mahalanobis² of the null under the posterior mean and covariance of the
    effect's block), null_tail (share of samples farther than the null in that metric:
    below 1e-3 the null is outside the joint 99.9% credible region), agrees (null_tail <
    WALD_P: the posterior confirms the Gauss-Newton/Wald identification)}``.
    """
    emcee = _emcee.emcee()  # lazy: 0.1 s of import (without scipy.stats, fitting.posterior.emcee_import)

    data = with_weight(fitter.data, weight)
    used = np.asarray(weight) > 0
    free = np.flatnonzero(fit.free)
    theta_hat = np.array(fit.theta, dtype=float)

    # the walkers' statics start near θ̂'s equilibria (uncommitted arrays, as the zeros the
    # ensemble was compiled for: cstiffjax.runtime.programs._uncommitted); both programs are compiled
    # in the background (or here, when the thread has not started them: Ahead.wait)
    fitter.ahead.wait("solutions", model)
    solved = solutions(model, theta_hat, fitter.robot, data)
    fitter.ahead.wait("walkers", model)
    # all walkers in one call (emcee's vectorize: every move here proposes the whole
    # ensemble); the arguments but θ are partitioned once
    ensemble = walker_residuals.bind(model, np.zeros((walkers, theta_hat.size)), fitter.robot, data, theta_hat,
                                     solved, vary=1)

    def log_prob(X):
        th = np.tile(theta_hat, (walkers, 1))
        th[: len(X), free] = X  # (the ensemble is always whole; a shorter batch is padded)
        r, ok = (np.asarray(a)[: len(X)] for a in ensemble(th))
        r = r.reshape(len(X), -1)
        good = np.all(ok[:, used], axis=1) & np.all(np.isfinite(r), axis=1)
        return np.where(good, -0.5 * np.sum(np.where(good[:, None], r, 0.0) ** 2, axis=1), -np.inf)

    mu, d = theta_hat[free], len(free)
    lam, V = np.linalg.eigh(0.5 * (fit.covariance + fit.covariance.T))
    lam = np.clip(lam, 1e-14 * max(lam.max(), 1e-300), None)
    L, Linv = V * np.sqrt(lam), (V / np.sqrt(lam)).T  # C = L Lᵀ
    s = 1.1

    def independence(x0, random):
        q = mu + s * random.randn(*x0.shape) @ L.T
        logq = lambda x: -0.5 * np.sum(((x - mu) @ Linv.T) ** 2, axis=1) / s**2  # noqa: E731
        return q, logq(x0) - logq(q)

    moves = [(emcee.moves.MHMove(independence), 0.8), (emcee.moves.GaussianMove(L @ L.T * 2.38**2 / d), 0.2)]
    # all walkers in one vmapped call, from the main thread (a thread pool of per-walker calls
    # deadlocked in XLA's CPU runtime; so did two halves of the ensemble called from two
    # threads at once, on IRMA4U with jaxlib 0.10.2: every XLA worker idle, both callers
    # waiting for their results, benchmarks/LATENCY.md). Bundled example (spring), warm cache: the chain's
    # 2080 evaluations 2.2 s one walker at a time, 1.7 s batched (same values bit for bit),
    # for one more compilation in the background thread; proto_cable_mass (catenary): the
    # same diagnosis time cold (54 s), warm 36 -> 30 s.
    sampler = emcee.EnsembleSampler(walkers, d, log_prob, moves=moves, vectorize=True)
    sampler.random_state = np.random.RandomState(seed).get_state()
    p0 = mu + np.random.default_rng(seed).standard_normal((walkers, d)) @ L.T
    target, state = min(min_steps, steps), p0
    while True:
        state = sampler.run_mcmc(state, target - sampler.iteration, progress=enabled(progress),
                                 skip_initial_state_check=True,  # no spanning ensemble needed
                                 progress_kwargs={"desc": f"posterior {', '.join(names)}", "leave": False})
        burn = min(POSTERIOR_BURN, target // 4)
        tau = float(np.max(sampler.get_autocorr_time(discard=burn, tol=0, quiet=True)))
        if target >= steps or long_enough(target, burn, tau):
            break
        need = burn + MIN_TAU_MULTIPLE * tau * 1.1 if np.isfinite(tau) else 2 * target
        target = int(min(steps, max(np.ceil(need), target + 25)))
    steps = target
    chain = sampler.get_chain(discard=burn, flat=True)
    meta = {"walkers": walkers, "steps": steps, "burn": burn, "samples": len(chain),
            "acceptance_fraction": float(np.mean(sampler.acceptance_fraction)),
            "tau": tau if np.isfinite(tau) else None, "converged": long_enough(steps, burn, tau)}
    return {name: {**meta, **_block_summary(chain, model, free, name)} for name in names}


def _block_summary(chain, model, free, name) -> dict:
    """``{parameters, null_d2, null_tail, agrees}`` of effect ``name``'s block in the
    flat ``chain`` (samples x free entries, ``free`` their θ indices)."""
    i = model.effect_index(name)
    sl = model.block_slice(i)
    cols = np.searchsorted(free, np.arange(sl.start, sl.stop))
    X = chain[:, cols]  # θ of the effect's block; its null is θ = 0
    mean, S = X.mean(0), np.atleast_2d(np.cov(X, rowvar=False))
    Sinv = np.linalg.pinv(S, hermitian=True)
    d2 = np.einsum("ij,jk,ik->i", X - mean, Sinv, X - mean)
    null_d2 = float(mean @ Sinv @ mean)
    null_tail = float(np.mean(d2 >= null_d2))
    phys = np.asarray(model.null)[sl] + np.asarray(model.scale)[sl] * X
    q = np.quantile(phys, [0.0005, 0.05, 0.5, 0.95, 0.9995], axis=0)
    null = np.asarray(model.null)[sl]
    z = (q[2] - null) / np.maximum(phys.std(0), 1e-300)
    params = {}
    for bi, nm, off, shape, _unit in model.blocks:
        if bi != i:
            continue
        k = slice(off - sl.start, off - sl.start + int(np.prod(shape, dtype=int)))
        out = (lambda a: a[0].item()) if shape == () else (lambda a, sh=shape: np.reshape(a, sh).tolist())
        params[nm] = {"median": out(q[2][k]), "interval90": [out(q[1][k]), out(q[3][k])], "null": out(null[k]),
                      "null_outside_999": out(((null < q[0]) | (null > q[4]))[k]),
                      "z_null": out(z[k])}
    return {"parameters": params, "null_d2": null_d2, "null_tail": null_tail, "agrees": bool(null_tail < WALD_P)}
