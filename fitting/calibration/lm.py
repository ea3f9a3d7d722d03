"""The least-squares engine of ``fitting``: Levenberg-Marquardt over a masked subset of a
parameter vector, written as one ``jax.lax.while_loop``.

Every fit of the package goes through :func:`masked_levenberg_marquardt`: calibration
(:func:`fitting.calibration.least_squares.solve_least_squares`: every entry free, runs under
``jit``/``vmap``) and the diagnosis's masked fits (:mod:`fitting.effects.fit`: the
extended model's full ``θ``, a mask of free entries, required samples). The caller's
``fun(θ, args) -> (r, J, ok)`` is evaluated **once per loop iteration** (its code appears
once in the compiled program, the start evaluation included): ``r`` ``(n, ...)`` whitened
residuals of ``n`` samples, ``J`` ``(r.size, P)`` the Jacobian of ``r.ravel()``, ``ok``
``(n,)`` per-sample success (a sample with a non-finite residual or Jacobian entry counts
as failed; its entries are replaced by 0, never NaN).

Iteration (the numpy loop it replaces, step for step): from the current ``A = JᵀJ``,
``g = Jᵀr`` solve ``(A∘ffᵀ + diag(1 - f) + λ diag(d∘f)) s = -g∘f`` (``f`` the free mask,
``d`` the diagonal of ``A`` where positive, else 1: fixed entries get a zero step) and
evaluate at ``θ + s``. The trial is accepted when every required sample succeeded, χ² is
finite and did not increase; then ``λ ← max(λ/10, 1e-12)`` and the fit stops once the
decrease is ``≤ rtol·χ² + 1e-12``; a rejected trial multiplies ``λ`` by 10, and at
``λ ≥ 1e12`` the fit stops (``Status.no_decrease``, a converged outcome). ``max_steps``
bounds the accepted steps (``Status.not_converged`` when reached); a required sample that
fails at the start is ``Status.start_failed``. The outcome is a
:class:`~cstiffjax.core.status.Status`, the toolkit's one result vocabulary. The mask, the
required samples, ``max_steps`` and ``rtol`` are *data*: one compilation serves every free
set and every sample weighting.

:func:`drive_on_host` runs the same kernels from Python for a ``fun`` that is not
traceable (the diagnosis's grammar-term models, composed on the host from compiled parts).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from cstiffjax.core.arrays import batched_like, to_device
from cstiffjax.core.status import Status, code, from_codes, message
from cstiffjax.runtime import programs

# the loop's stop codes: a Status's integer code once it stops (Python ints: weakly typed
# constants of the compiled loop), negative while it runs
_CONVERGED, _NO_DECREASE, _ITERATION_LIMIT, _START_FAILED = map(
    code, (Status.successful, Status.no_decrease, Status.not_converged, Status.start_failed))
_RUNNING, _UNSTARTED = -1, -2
LAMBDA0, LAMBDA_MIN, LAMBDA_MAX = 1e-4, 1e-12, 1e12


class LMResult(eqx.Module):
    """Result of :func:`masked_levenberg_marquardt` (arrays only: it can leave ``jit``/``vmap``).

    - ``theta`` ``(P,)``: the optimum (fixed entries as given).
    - ``residuals`` ``(n, ...)``, ``jacobian`` ``(r.size, P)``, ``ok`` ``(n,)``: ``fun``'s
      output there (non-finite entries replaced by 0, their samples marked failed).
    - ``chi2``: ``Σ r²``. ``covariance`` ``(P, P)``: ``pinv((JᵀJ)∘ffᵀ)`` (numpy's
      ``rcond = 1e-15``), the Gauss-Newton covariance of the free entries for
      unit-variance residuals; rows and columns of fixed entries are 0 (``None`` when
      not requested).
    - ``steps``: LM iterations (accepted steps, plus the last one that found no decrease).
    - ``result``: a :class:`~cstiffjax.core.status.Status`: ``successful`` or
      ``no_decrease`` (both count as converged), ``not_converged`` (the iteration limit)
      or ``start_failed`` (a required sample failed at ``theta0``; nothing was fitted).
      :attr:`converged`, :meth:`message`.
    """

    theta: Float[Array, " P"]
    residuals: Float[Array, " n ..."]
    jacobian: Float[Array, "N P"]
    ok: Bool[Array, " n"]
    chi2: Float[Array, ""]
    covariance: Float[Array, "P P"] | None
    steps: Int[Array, ""]
    result: Status

    @property
    def converged(self):
        return (self.result == Status.successful) | (self.result == Status.no_decrease)

    def message(self) -> str:
        """Text of a concrete (unbatched) ``result``: ``"converged"`` or its Status message."""
        return fit_message(self.result)


def fit_message(result: Status) -> str:
    """Text of a concrete (unbatched) fit ``result``: ``"converged"`` for
    ``Status.successful``, else the Status message (host only: no device program)."""
    return message(result) or "converged"


def fit_converged(result: Status) -> bool:
    """Whether a concrete (unbatched) fit ``result`` counts as converged (``successful`` or
    ``no_decrease``), on the host (no device program)."""
    return code(result) in (_CONVERGED, _NO_DECREASE)


class _State(eqx.Module):
    theta: Array
    r: Array
    J: Array
    ok: Array
    cost: Array
    lam: Array
    accepted: Array
    code: Array


def _clean(r, J, ok):
    """Zero non-finite entries and mark their samples failed."""
    n = ok.shape[0]
    fin = jnp.all(jnp.isfinite(r).reshape(n, -1), 1) & jnp.all(jnp.isfinite(J).reshape(n, -1), 1)
    return jnp.where(jnp.isfinite(r), r, 0.0), jnp.where(jnp.isfinite(J), J, 0.0), ok & fin


def _unstarted(theta0, r, J, ok, xp=jnp) -> _State:
    """The state before the first evaluation (``xp``: ``jnp`` in a traced program, ``np``
    on the host, where ``jnp`` would compile a program per shape, :mod:`cstiffjax.core.arrays`)."""
    z = xp.zeros((), theta0.dtype)
    return _State(theta0, xp.zeros_like(r), xp.zeros_like(J), xp.zeros(ok.shape, bool), z,
                  xp.asarray(LAMBDA0, theta0.dtype), xp.zeros((), xp.int32), xp.asarray(_UNSTARTED, xp.int32))


def _propose(s: _State, free):
    """The trial point after the current one: the damped Gauss-Newton step of the free
    entries (the first trial, ``theta0``, is the caller's)."""
    f = free.astype(s.J.dtype)
    A = s.J.T @ s.J
    g = s.J.T @ s.r.ravel()
    dA = jnp.diag(A)
    d = jnp.where(dA > 0, dA, 1.0)
    K = A * jnp.outer(f, f) + jnp.diag(1.0 - f + s.lam * d * f)
    step = jnp.linalg.solve(K, -g * f)
    return s.theta + jnp.where(free, step, 0.0)


def _update(s: _State, trial, out, need, max_steps, rtol) -> _State:
    """Accept or reject ``trial`` given ``out = fun(trial)``; adapt ``λ``; set the stop code."""
    r, J, ok = _clean(*out)
    cost = jnp.sum(r * r)
    start = s.code == _UNSTARTED
    good = jnp.all(ok | ~need)
    accept = start | (good & jnp.isfinite(cost) & (cost <= s.cost))
    accepted = s.accepted + (accept & ~start).astype(s.accepted.dtype)
    lam_up = s.lam * 10
    code_start = jnp.where(~good, _START_FAILED, jnp.where(max_steps <= 0, _ITERATION_LIMIT, _RUNNING))
    code_acc = jnp.where(s.cost - cost <= rtol * cost + 1e-12, _CONVERGED,
                         jnp.where(accepted >= max_steps, _ITERATION_LIMIT, _RUNNING))
    stop = jnp.where(start, code_start, jnp.where(accept, code_acc, jnp.where(lam_up >= LAMBDA_MAX, _NO_DECREASE,
                                                                                _RUNNING)))
    lam = jnp.where(start, s.lam, jnp.where(accept, jnp.maximum(s.lam / 10, LAMBDA_MIN), lam_up))
    pick = lambda new, old: jnp.where(accept, new, old)  # noqa: E731
    return _State(pick(trial, s.theta), pick(r, s.r), pick(J, s.J), pick(ok, s.ok), pick(cost, s.cost), lam,
                  accepted, stop.astype(jnp.int32))


def _result(s: _State, free, covariance: bool = True) -> LMResult:
    f = free.astype(s.J.dtype)
    cov = jnp.linalg.pinv((s.J.T @ s.J) * jnp.outer(f, f), rtol=1e-15, hermitian=True) if covariance else None
    steps = s.accepted + (s.code == _NO_DECREASE).astype(s.accepted.dtype)
    return LMResult(s.theta, s.r, s.J, s.ok, s.cost, cov, steps, from_codes(s.code))


def _run_impl(fun, theta0, args, free, need, max_steps, rtol, covariance=True):
    shapes = jax.eval_shape(fun, theta0, args)  # at trace time only
    # the state batched as theta0 is (a vmapped calibration: the loop's body batched once)
    s0 = _unstarted(theta0, *(jnp.zeros(x.shape, x.dtype) for x in shapes))
    s0 = jax.tree.map(lambda v: batched_like(v, theta0), s0)
    need = jnp.ones(shapes[2].shape, bool) if need is None else need

    def body(s):  # the start evaluates theta0: no normal equations there (~2 ms on a diagnosis
        # model; under vmap the cond is a select and computes both, a zero step at the start)
        trial = jax.lax.cond(s.code == _UNSTARTED, lambda: theta0, lambda: _propose(s, free))
        return _update(s, trial, fun(trial, args), need, max_steps, rtol)

    return _result(jax.lax.while_loop(lambda s: s.code < 0, body, s0), free, covariance)


def _like(args) -> LMResult:
    """An output-shaped :class:`LMResult` (placeholders; ``covariance`` None unless the last
    argument asks for it), for a serialized program's output."""
    return LMResult(0, 0, 0, 0, 0, 0 if args[-1] else None, 0, Status.successful)


# the compiled loop; a serialized program when cstiffjax.runtime.programs is on (a warm command
# line then loads it instead of tracing the model: seconds)
_run = programs.Program(_run_impl, name="fitting.calibration.lm._run", like=_like)
# the same loop for a model fitted once or twice (``quick``): compiled with programs.ONCE_OPTIONS
_run_quick = programs.Program(_run_impl, name="fitting.calibration.lm._run_quick", like=_like,
                              compiler_options=programs.ONCE_OPTIONS)


def _loop(quick: bool):
    return _run_quick if quick else _run


def _masks(theta0, free, must_succeed):
    free = to_device(np.ones(theta0.shape, bool) if free is None else free, bool)
    return free, None if must_succeed is None else to_device(must_succeed, bool)


def masked_levenberg_marquardt(fun, theta0, args, *, free=None, must_succeed=None, max_steps=60,
                               rtol=1e-9, covariance: bool = True, quick: bool = False) -> LMResult:
    """Minimise ``Σ r(θ)²`` over the free entries of ``θ`` (see module doc). Traceable:
    works under ``jit`` and ``vmap``.

    **Arguments:**

    - ``fun``: ``(θ, args) -> (r (n, ...), J (r.size, P), ok (n,) bool)``, traceable and
      hashable (static under jit: a module-level function or an ``eqx.Module``).
    - ``theta0``: ``(P,)`` float64 start (unconstrained coordinates, the caller's units).
    - ``args``: a pytree passed to ``fun`` (data: changing its values does not recompile).
    - ``free``: ``(P,)`` bool, the entries to fit (default all); the others stay at
      ``theta0``. ``must_succeed``: ``(n,)`` bool, the samples whose ``ok`` a step needs
      (default all).
    - ``max_steps``: the most accepted steps (0: evaluate at ``theta0`` only).
      ``rtol``: relative χ² decrease below which the fit has converged.
    - ``covariance``: compute ``LMResult.covariance`` in the compiled program (False:
      ``None``, for callers that form it themselves; measured to cost more inside the
      loop's program than on the host).
    - ``quick``: compile the loop for compile time (:data:`cstiffjax.runtime.programs.ONCE_OPTIONS`:
      about half the compile, twice the run time), for a ``fun`` fitted only once or twice;
      its own program (every call, :func:`lower` and :func:`evaluate` of such a ``fun`` must
      say so too, or it is compiled twice). The same values to rounding.

    **Returns:** an :class:`LMResult`; a failure is its ``result``, never a NaN ``theta``.
    """
    return _loop(quick)(*_run_args(fun, theta0, args, free, must_succeed, max_steps, rtol, covariance))


def _run_args(fun, theta0, args, free, must_succeed, max_steps, rtol, covariance) -> tuple:
    """The arguments of :func:`_run` (one place, so a call and :func:`lower` agree)."""
    theta0 = to_device(theta0, np.float64)
    free, need = _masks(theta0, free, must_succeed)  # need None: every sample, set in _run (no tracing here)
    return (fun, theta0, args, free, need, to_device(max_steps, np.int32), to_device(rtol, np.float64), covariance)


def lower(fun, theta0, args, *, free=None, must_succeed=None, max_steps=60, rtol=1e-9, covariance: bool = True,
          quick: bool = False):
    """The program :func:`masked_levenberg_marquardt` runs for these arguments, traced and lowered
    without running it: only their shapes, dtypes and static parts matter (any values do).
    ``.compile()`` puts it in JAX's in-memory cache, so the later call with arguments of the
    same structure does not compile again. Thread-safe for *compilation* (the diagnosis
    compiles a model in a background thread while the main thread fits); never run compiled
    programs from two threads at once (XLA's CPU runtime deadlocked on that,
    :mod:`fitting.diagnosis.effect_posterior`)."""
    return _loop(quick).lower(*_run_args(fun, theta0, args, free, must_succeed, max_steps, rtol, covariance))


def evaluate(fun, theta, args, num_samples: int | None = None, quick: bool = False):
    """``(r, J, ok)`` of ``fun`` at ``theta`` through the compiled loop of
    :func:`masked_levenberg_marquardt` (``max_steps = 0``: no second compilation of ``fun``);
    non-finite entries are 0 and their samples not ok. ``num_samples``: ``n`` when the
    caller knows it (default: from an abstract evaluation of ``fun``, which traces it:
    seconds for a diagnosis model, on every call). ``quick``: as the fits of ``fun``
    (:func:`masked_levenberg_marquardt`)."""
    n = num_samples
    if n is None:
        n = jax.eval_shape(fun, jnp.asarray(theta, dtype=jnp.float64), args)[2].shape[0]
    out = masked_levenberg_marquardt(fun, theta, args, must_succeed=np.zeros(n, bool), max_steps=0,
                                     covariance=False, quick=quick)
    return out.residuals, out.jacobian, out.ok


# the host-driven kernels compile with the fitting programs' options too (a cold diagnosis
# compiles them for every width the discovery fits: ~40 % less compile time)
_propose_jit = jax.jit(_propose, compiler_options=programs.COMPILER_OPTIONS)
_update_jit = jax.jit(_update, compiler_options=programs.COMPILER_OPTIONS)
_result_jit = jax.jit(_result, static_argnums=2, compiler_options=programs.COMPILER_OPTIONS)


def drive_on_host(fun, theta0, *, free=None, must_succeed=None, max_steps=60, rtol=1e-9,
                  covariance: bool = True) -> LMResult:
    """:func:`masked_levenberg_marquardt` for a ``fun: θ -> (r, J, ok)`` composed on the host
    (not traceable): the same proposal/acceptance kernels, driven by a Python loop.
    Arguments and result as in :func:`masked_levenberg_marquardt`."""
    host = np.asarray(theta0, dtype=np.float64)  # host values: no conversion programs (cstiffjax.core.arrays)
    theta0 = jax.device_put(host)
    out = tuple(np.asarray(a) for a in fun(host))
    free, need = _masks(theta0, free, must_succeed)
    need = to_device(np.ones(out[2].shape, bool)) if need is None else need
    max_steps, rtol = np.int32(max_steps), np.float64(rtol)
    # (θ and the state as device arrays, as the kernels return them: one entry in their dispatch caches)
    s = _update_jit(jax.device_put(_unstarted(host, *out, xp=np)), theta0, out, need, max_steps, rtol)
    while int(s.code) < 0:
        trial = _propose_jit(s, free)
        s = _update_jit(s, trial, tuple(np.asarray(a) for a in fun(np.asarray(trial))), need, max_steps, rtol)
    return _result_jit(s, free, covariance)
