"""Whitened nonlinear least squares: Levenberg-Marquardt and the Gauss-Newton covariance.

:func:`solve_least_squares` is the single numerical core of the ``fitting`` package:
every calibration (CDPR, CSJM, any user model) builds a residual function
``r(θ, args)`` of *whitened* residuals ``(measured - predicted) / σ`` in an
unconstrained parameter vector ``θ`` and hands it here. At the optimum the Jacobian
``J = ∂r/∂θ`` (forward-mode autodiff, through any inner implicit solve) gives the
Gauss-Newton covariance ``C = (JᵀJ)⁺``, which is the exact posterior covariance of a
linear-Gaussian model with a flat prior.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from cstiffjax.status import Status, raise_if_failed
from jaxtyping import Array, Float, Int


class LSResult(eqx.Module):
    """Result of :func:`solve_least_squares` (all in the unconstrained ``θ`` coordinates).

    - ``theta`` ``(p,)``: the optimum. ``residuals`` ``(n,)``: whitened residuals there.
    - ``jacobian`` ``(n, p)``: ``∂r/∂θ`` at the optimum (autodiff).
    - ``chi2``: ``Σ r²``. ``dof``: ``num_data - p``. ``chi2_per_dof``: ``chi2 / dof``
      (``nan`` when ``dof <= 0``).
    - ``covariance`` ``(p, p)``: ``pinv(JᵀJ)``, the Gauss-Newton covariance of ``θ``
      for unit-variance residuals (not rescaled by ``chi2_per_dof``).
    - ``result``: a :class:`~cstiffjax.status.Status`. ``num_steps``: LM iterations.
    """

    theta: Float[Array, " p"]
    residuals: Float[Array, " n"]
    jacobian: Float[Array, "n p"]
    chi2: Float[Array, ""]
    dof: Int[Array, ""]
    chi2_per_dof: Float[Array, ""]
    covariance: Float[Array, "p p"]
    result: Status
    num_steps: Int[Array, ""]


def default_solver(rtol: float = 1e-8, atol: float = 1e-8):
    """``optx.LevenbergMarquardt(rtol, atol)``: the default calibration solver."""
    return optx.LevenbergMarquardt(rtol=rtol, atol=atol)


@eqx.filter_jit
def _solve(residual_fn, theta0, args, solver, max_steps, num_data):
    sol = optx.least_squares(residual_fn, solver, theta0, args=args, max_steps=max_steps, throw=False)
    theta = sol.value
    r = residual_fn(theta, args)
    J = jax.jacfwd(residual_fn)(theta, args)
    chi2 = jnp.sum(r * r)
    dof = jnp.asarray(num_data - theta.shape[0])
    chi2_dof = jnp.where(dof > 0, chi2 / jnp.maximum(dof, 1), jnp.nan)
    cov = jnp.linalg.pinv(J.T @ J, hermitian=True)
    finite = jnp.all(jnp.isfinite(r)) & jnp.all(jnp.isfinite(J))
    ok = (sol.result == optx.RESULTS.successful) & finite
    result = Status.where(ok, Status.successful, Status.not_converged)
    return LSResult(theta, r, J, chi2, dof, chi2_dof, cov, result, jnp.asarray(sol.stats["num_steps"]))


def solve_least_squares(
    residual_fn, theta0: Float[Array, " p"], args, *, solver=None, max_steps: int = 200,
    throw: bool = True, num_data: int | None = None,
) -> LSResult:
    """Minimise ``½‖r(θ, args)‖²`` with Levenberg-Marquardt (optimistix).

    **Arguments:**

    - ``residual_fn``: ``(theta, args) -> (n,)`` whitened residuals (NaN-free; masked
      entries must be exactly 0). Must be a hashable function (it is static under jit).
    - ``theta0``: ``(p,)`` float64 start, unconstrained coordinates.
    - ``args``: a pytree passed through to ``residual_fn`` (robot, recordings, ...).
    - ``solver``: an ``optx`` least-squares solver; default
      ``LevenbergMarquardt(rtol=1e-10, atol=1e-10)``.
    - ``max_steps``: iteration limit. ``throw``: raise (``EqxRuntimeError``, also
      under jit) when the solve fails; else check ``result``.
    - ``num_data``: number of effective data (residual entries that are not masked
      zeros) for the degrees of freedom; default the residual length.

    **Returns:** an :class:`LSResult`.
    """
    theta0 = jnp.asarray(theta0, dtype=jnp.float64)
    if theta0.ndim != 1:
        raise ValueError(f"theta0 must be a 1-D parameter vector, got shape {theta0.shape}")
    if not bool(jnp.all(jnp.isfinite(theta0))):
        raise ValueError(f"theta0 contains NaN or inf: {theta0}")
    if num_data is None:
        num_data = int(jax.eval_shape(residual_fn, theta0, args).shape[0])
    out = _solve(residual_fn, theta0, args, solver or default_solver(), max_steps, int(num_data))
    return raise_if_failed(out.result, out, throw)
