"""Posterior sampling of a calibrated model with emcee, and its diagnostics.

The log-posterior over the unconstrained parameters ``θ`` of a :class:`~fitting.calibration.least_squares.Fit` is

``log p(θ | data) = -½ ‖r(θ)‖² + log|∂v/∂θ| + const``

where ``r`` are the whitened residuals the fit minimised (data and Gaussian priors)
and the log-Jacobian of the transforms makes the prior flat in the *physical* values
``v`` (not in ``θ``). It is jitted and vmapped over walkers (emcee ``vectorize=True``).
Walkers start from a Gaussian with the least-squares covariance, seeded.

Diagnostics: acceptance fraction, integrated autocorrelation time ``τ`` (emcee,
Goodman & Weare 2010 / Sokal windowing), effective sample size
``walkers × kept steps / τ``. :meth:`Posterior.summary` refuses a chain shorter than
``50 τ`` (the emcee recommendation) and says how many steps are needed. By default
:func:`sample_posterior` chooses the chain length itself: it extends the chain in chunks
until ``50 τ`` are kept, up to a stated cap (``max_steps``).
"""

import dataclasses
import logging
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from fitting.posterior import emcee_import as _emcee

MIN_TAU_MULTIPLE = 50


class ChainTooShortError(ValueError):
    """The chain is too short to trust its summary (fewer than 50 autocorrelation times)."""


@dataclasses.dataclass(frozen=True)
class Posterior:
    """Samples of the free physical parameters (ordered as ``names``).

    ``samples`` ``(steps, walkers, p)`` physical values (burn-in included); ``theta``
    the same in unconstrained coordinates; ``log_prob`` ``(steps, walkers)``;
    ``acceptance_fraction`` ``(walkers,)``; ``tau`` ``(p,)`` integrated autocorrelation
    times in steps (``nan`` if the chain is too short for an estimate); ``burn`` steps
    discarded by the summaries; ``restarts`` log-probability evaluations whose
    warm-started statics did not converge and were redone with the full solve.
    """

    names: tuple
    samples: np.ndarray
    theta: np.ndarray
    log_prob: np.ndarray
    acceptance_fraction: np.ndarray
    tau: np.ndarray
    burn: int
    fit: object = None
    restarts: int = 0

    @property
    def num_steps(self) -> int:
        return self.samples.shape[0]

    @property
    def num_walkers(self) -> int:
        return self.samples.shape[1]

    @property
    def ess(self) -> np.ndarray:
        """Effective sample size per parameter: ``walkers × (steps - burn) / τ``."""
        return self.num_walkers * (self.num_steps - self.burn) / self.tau

    def steps_needed(self) -> int:
        """Steps for ``50 τ`` after burn-in (with the current ``τ`` estimate)."""
        return int(np.ceil(MIN_TAU_MULTIPLE * np.nanmax(self.tau))) + self.burn

    def check_converged(self):
        """Raise :class:`ChainTooShortError` unless ``steps - burn >= 50 τ`` for every parameter."""
        tau = np.nanmax(self.tau) if np.any(np.isfinite(self.tau)) else np.nan
        kept = self.num_steps - self.burn
        if not np.isfinite(tau):
            raise ChainTooShortError(f"the chain ({kept} steps after burn-in) is too short to estimate the "
                                     f"autocorrelation time; run at least {MIN_TAU_MULTIPLE * 20} more steps")
        if kept < MIN_TAU_MULTIPLE * tau:
            raise ChainTooShortError(
                f"chain too short to summarize: {kept} steps after burn-in but the autocorrelation time is "
                f"{tau:.1f} steps; {MIN_TAU_MULTIPLE} autocorrelation times need nsteps >= {self.steps_needed()} "
                f"(burn-in {self.burn} included)")

    def flat(self, theta: bool = False) -> np.ndarray:
        """Post-burn-in samples, ``(walkers × kept steps, p)``."""
        a = self.theta if theta else self.samples
        return a[self.burn:].reshape(-1, a.shape[-1])

    def summary(self, level: float = 0.9, *, check: bool = True) -> dict:
        """Mean, std and equal-tailed ``level`` interval of each free value.

        **Raises:** :class:`ChainTooShortError` when ``check`` and the chain is shorter
        than 50 autocorrelation times.
        """
        if check:
            self.check_converged()
        x = self.flat()
        lo, hi = np.quantile(x, [(1 - level) / 2, (1 + level) / 2], axis=0)
        return {"names": list(self.names), "mean": x.mean(0), "std": x.std(0, ddof=1), "lower": lo, "upper": hi,
                "level": level, "covariance": np.cov(x.T).reshape(len(self.names), len(self.names)),
                "tau": self.tau, "ess": self.ess, "acceptance_fraction": float(np.mean(self.acceptance_fraction))}


def _checked(fn, theta, args):
    """``(r, ok)``: residuals and whether the model evaluation converged (residual
    functions with inner solves expose ``checked``; plain ones always converge)."""
    if hasattr(fn, "checked"):
        return fn.checked(theta, args)
    return fn(theta, args), jnp.asarray(True)


@eqx.filter_jit
def _log_prob(fn, spec, args, theta):
    def one(t):
        r, ok = _checked(fn, t, args)
        lp = -0.5 * jnp.sum(r * r) + spec.log_abs_det_jacobian(t)
        return jnp.where(ok & jnp.isfinite(lp), lp, -jnp.inf), ok

    return jax.vmap(one)(theta)


class _LogProb:
    """Walker-batched log-posterior (``θ (k, p) -> (k,)``) with a warm start and a checked fallback.

    When the fit's residual function offers ``warm_started`` (CDPR calibrations), each
    walker's statics start at the poses predicted at the least-squares optimum with a
    few Newton steps; walkers whose solve did not converge (``ok`` False) are evaluated
    again with the fit's own residual (started at the measured poses, full steps), and
    counted in ``restarts``. Without it the fit's residual is used directly."""

    def __init__(self, fit, warm: bool = True):
        self.fit, self.restarts = fit, 0
        self.fast = None
        if warm and hasattr(fit.residual_fn, "warm_started"):
            self.fast = fit.residual_fn.warm_started(fit.ls.theta, fit.args)

    def __call__(self, theta):
        theta = jnp.asarray(theta, dtype=jnp.float64)
        fit = self.fit
        if self.fast is None:
            return np.asarray(_log_prob(fit.residual_fn, fit.spec, fit.args, theta)[0])
        lp, ok = (np.asarray(a) for a in _log_prob(self.fast[0], fit.spec, self.fast[1], theta))
        if not ok.all():
            self.restarts += int(np.sum(~ok))
            lp_full = np.asarray(_log_prob(fit.residual_fn, fit.spec, fit.args, theta)[0])
            lp = np.where(ok, lp, lp_full)
        return lp


def log_prob_fn(fit, *, warm: bool = True):
    """Jitted, walker-vmapped ``θ (k, p) -> log p (k,)`` of a fit (numpy out; ``-inf``
    where non-finite or where the model's inner statics did not converge).

    ``warm``: start CDPR statics at the poses predicted at the optimum (few Newton
    steps, convergence checked per walker, fallback to the full solve; see
    :class:`_LogProb`). Compiled once per residual function / parameter spec / data
    shapes (cached)."""
    return _LogProb(fit, warm)


@eqx.filter_jit
def _physical(spec, values, theta):
    return jax.vmap(lambda t: spec.free_vector(spec.from_theta(t, values)))(theta)


def _to_physical(fit, theta):
    flat = jnp.asarray(theta.reshape(-1, theta.shape[-1]))
    return np.asarray(_physical(fit.spec, fit.values, flat)).reshape(theta.shape)


@eqx.filter_jit
def _chi2(fn, args, n_data, theta):
    return jax.vmap(lambda t: jnp.sum(fn(t, args)[:n_data] ** 2))(theta)


def initial_walkers(fit, nwalkers: int, rng, scale: float = 1.0) -> np.ndarray:
    """Walkers ``θ̂ + scale · N(0, C_θ)`` (``C_θ`` the least-squares covariance, jittered)."""
    theta = np.asarray(fit.ls.theta)
    cov = np.asarray(fit.ls.covariance)
    cov = 0.5 * (cov + cov.T) + 1e-12 * np.eye(len(theta)) * max(np.max(np.diag(cov)), 1e-300)
    return rng.multivariate_normal(theta, scale**2 * cov, size=nwalkers)


AUTO_FIRST = 1000  # steps of the first chunk of an automatic-length chain
AUTO_MAX_STEPS = 20000  # default cap of an automatic-length chain


def _default_burn(nsteps: int) -> int:
    return min(max(100, nsteps // 5), nsteps // 2)


def _tau(theta, burn) -> np.ndarray:
    """Integrated autocorrelation time per parameter (``nan`` when the chain is too short
    for any estimate). emcee's "chain is shorter than 50 τ" warning is not logged: the
    caller decides (:meth:`Posterior.check_converged` says it with the steps needed)."""
    emcee = _emcee.emcee()  # lazy: 0.1 s of import (without scipy.stats, fitting.posterior.emcee_import)

    log = logging.getLogger("emcee.autocorr")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        return np.asarray(emcee.autocorr.integrated_time(theta[burn:], quiet=True))
    except Exception:  # too short for any estimate
        return np.full(theta.shape[-1], np.nan)
    finally:
        log.setLevel(level)


def long_enough(nsteps, burn, tau) -> bool:
    return bool(np.all(np.isfinite(tau)) and nsteps - burn >= MIN_TAU_MULTIPLE * np.max(tau))


def _next_length(nsteps, tau, max_steps) -> int:
    """Chain length to aim for next: 10% beyond what the current ``τ`` asks for (the
    default burn-in is a fifth of the chain, so ``50 τ`` kept needs ``62.5 τ`` in all),
    at least 50% more than now, at most ``max_steps``."""
    need = MIN_TAU_MULTIPLE * np.nanmax(tau) / 0.8 * 1.1 if np.any(np.isfinite(tau)) else 2 * nsteps
    return int(min(max_steps, max(np.ceil(need), np.ceil(1.5 * nsteps))))


def sample_posterior(fit, *, nwalkers: int = 32, nsteps: int | None = None, seed: int = 0, burn: int | None = None,
                     scale: float = 1.0, progress: bool | None = None, warm: bool = True,
                     max_steps: int = AUTO_MAX_STEPS, min_steps: int = AUTO_FIRST) -> Posterior:
    """Sample the posterior of a :class:`~fitting.calibration.least_squares.Fit` with emcee.

    **Arguments:** ``fit`` from :func:`~fitting.calibration.least_squares.calibrate` or
    :func:`~fitting.calibration.least_squares.calibrate_model`; ``nwalkers`` (>= 2 p);
    ``nsteps``: chain length, or ``None`` (default) to choose it from the measured
    autocorrelation time: a first chunk of ``min_steps`` (default 1000) steps, then the chain is
    extended (each time to 10% beyond ``62.5 τ``, at least ×1.5) until the kept steps
    reach ``50 τ`` or the chain reaches ``max_steps`` (default 20000; the summary then
    refuses the chain and says how many steps it needs); ``seed`` (walkers and moves);
    ``burn``: steps discarded by the summaries (default ``min(max(100, nsteps // 5),
    nsteps // 2)`` of the final length); ``scale``: spread of the initial walkers in
    least-squares standard deviations; ``progress``: progress bar (None: only on a
    terminal, :mod:`cstiffjax.core.progress`); ``warm``: warm-started statics for CDPR fits
    (see :func:`log_prob_fn`).

    **Returns:** a :class:`Posterior` (call ``.summary()``; it checks convergence).
    """
    emcee = _emcee.emcee()  # lazy, as in _tau

    from cstiffjax.core.progress import bar

    if fit.residual_fn is None:
        raise ValueError("this Fit carries no residual function; make it with calibrate() or calibrate_model()")
    p = int(fit.ls.theta.shape[0])
    if nwalkers < 2 * p:
        raise ValueError(f"nwalkers must be at least 2 x (number of free parameters) = {2 * p}, got {nwalkers}")
    if nsteps is not None and nsteps < 2:
        raise ValueError(f"nsteps must be >= 2 (or None: automatic), got {nsteps}")
    if nsteps is None and not 2 <= min_steps <= max_steps:
        raise ValueError(f"automatic chain length needs 2 <= min_steps <= max_steps, got {min_steps}, {max_steps}")
    rng = np.random.default_rng(seed)
    lp = log_prob_fn(fit, warm=warm)
    sampler = emcee.EnsembleSampler(nwalkers, p, lp, vectorize=True)
    sampler.random_state = np.random.RandomState(seed).get_state()
    target = int(min_steps) if nsteps is None else int(nsteps)
    state = initial_walkers(fit, nwalkers, rng, scale)
    # the bar's total is fixed from the start: the chain length, or the cap of an automatic one
    # (which usually stops far earlier, when 50 τ are kept: the postfix says what it aims at)
    total = int(nsteps) if nsteps is not None else int(max_steps)
    with bar(total=total, desc="emcee" if nsteps is not None else "emcee (stops at 50 τ)", unit="step",
             progress=progress) as pbar:
        while True:
            while sampler.iteration < target:  # chunks of <= 100 steps: the bar moves
                k = min(100, target - sampler.iteration)
                state = sampler.run_mcmc(state, k, progress=False)
                pbar.update(k)
            if nsteps is not None or target >= max_steps:
                break
            theta = sampler.get_chain()
            b = _default_burn(target) if burn is None else int(burn)
            tau = _tau(theta, b)
            if long_enough(target, b, tau):
                break
            target = _next_length(target, tau, max_steps)
            pbar.set_postfix_str(f"aiming at {target}, tau {np.nanmax(tau):.3g}" if np.any(np.isfinite(tau))
                                 else f"aiming at {target}, tau n/a")
            pbar.refresh()
    theta = sampler.get_chain()
    burn = _default_burn(theta.shape[0]) if burn is None else int(burn)
    return Posterior(tuple(fit.names), _to_physical(fit, theta), theta, sampler.get_log_prob(),
                     sampler.acceptance_fraction, _tau(theta, burn), burn, fit, lp.restarts)


def plan(fit, *, nwalkers: int = 32, nsteps: int | None = None, max_steps: int = AUTO_MAX_STEPS,
         min_steps: int = AUTO_FIRST, warm: bool = True, seed: int = 0) -> dict:
    """What :func:`sample_posterior` with these arguments will run, said before it runs.

    **Returns:** ``{"walkers", "steps_min", "steps_max", "s_per_step"}``: the chain length
    (``steps_min == steps_max`` for a fixed ``nsteps``; for an automatic one its first chunk
    and its cap) and the measured wall time of one ensemble step (one vectorized evaluation
    of the log-posterior at ``nwalkers`` points near the optimum, after a first evaluation that
    compiles it), s.
    """
    lp = log_prob_fn(fit, warm=warm)
    walkers = initial_walkers(fit, nwalkers, np.random.default_rng(seed))
    lp(walkers)  # compiles
    t0 = time.perf_counter()
    lp(walkers)
    per_step = time.perf_counter() - t0
    lo, hi = (int(nsteps), int(nsteps)) if nsteps is not None else (int(min_steps), int(max_steps))
    return {"walkers": int(nwalkers), "steps_min": lo, "steps_max": hi, "s_per_step": per_step}


def posterior_predictive_check(post: Posterior, *, ndraws: int = 200, seed: int = 0) -> dict:
    """Posterior predictive χ² check.

    For ``ndraws`` posterior draws ``θ_k`` compares the data χ², ``Σ r(θ_k)²`` over the
    recorded (unmasked) data, with that of replicated data ``Σ z²``, ``z ~ N(0, 1)``
    per recorded value (the whitened noise of a replicate). A p-value
    ``P(χ²_rep >= χ²_obs)`` near 0 means the model misses structure in the data.

    **Returns:** ``{"p_value", "chi2_obs" (ndraws,), "chi2_rep" (ndraws,)}``.
    """
    fit = post.fit
    rng = np.random.default_rng(seed)
    flat = post.flat(theta=True)
    draws = flat[rng.integers(0, len(flat), ndraws)]
    n_data = int(np.asarray(fit.residuals).size)

    obs = np.asarray(_chi2(fit.residual_fn, fit.args, n_data, jnp.asarray(draws)))
    n_eff = int(fit.dof) + len(fit.names) - _num_prior(fit)
    rep = rng.chisquare(n_eff, size=ndraws)
    return {"p_value": float(np.mean(rep >= obs)), "chi2_obs": obs, "chi2_rep": rep, "num_data": n_eff}


def _num_prior(fit) -> int:
    return sum(int(np.prod(fit.spec.shape(n))) for n in (fit.priors or {}))


def chain_is_finite(post: Posterior) -> bool:
    return bool(np.all(np.isfinite(post.log_prob)))


__all__ = [
    "ChainTooShortError",
    "Posterior",
    "chain_is_finite",
    "log_prob_fn",
    "posterior_predictive_check",
    "sample_posterior",
]
