"""A lean optimistix root finder for the elastic catenary's two unknowns
(:func:`cstiffjax.cable.catenary.catenary`'s default solver).

Its own module so that :mod:`cstiffjax.cable.catenary` does not import optimistix (with
lineax, 0.15 s on the 2-core machine): a command line that runs serialized programs
(:mod:`cstiffjax.runtime.programs`) never traces a solve and so never needs it.
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array


class _Newton2State(eqx.Module):
    f: Array
    diff: Array
    diff_prev: Array
    step: Array
    result: optx.RESULTS


class Newton2(optx.AbstractRootFinder):
    """Newton's method for a 2x2 system with a step limit (a lean optimistix root finder).

    Each step solves the 2x2 Newton system by Cramer's rule and shortens it so that no
    unknown moves by more than ``max_step`` (unknowns here are ``log H`` and ``V_B/F``,
    so ``2`` is a factor ``e²`` on ``H``). Stops when the step is below
    ``atol + rtol |y|``, or when the residual is below ``ftol`` *and* the steps have
    stopped shrinking (at least halving) below ``1e-6``: rounding noise, where the inputs
    determine the answer no better (nearly inextensible lines, strain below ~1e-8).
    Non-finite or singular steps stop the solve with
    ``RESULTS.nonlinear_divergence``. (Derivatives of the solution do not go through
    the iterations: see :func:`_solve_ift`.)
    """

    rtol: float
    atol: float
    ftol: float = 1e-14
    max_step: float = 2.0
    norm: Callable = optx.max_norm

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        inf = jnp.full_like(y, jnp.inf)
        return _Newton2State(jnp.full(f_struct.shape, jnp.inf, f_struct.dtype), inf, inf,
                             jnp.array(0), optx.RESULTS.successful)

    def step(self, fn, y, args, options, state, tags):
        def f_and_aux(_y):
            out, aux = fn(_y, args)
            return out, (out, aux)

        J, (f, aux) = jax.jacfwd(f_and_aux, has_aux=True)(y)
        det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
        d = jnp.stack([J[1, 1] * f[0] - J[0, 1] * f[1], J[0, 0] * f[1] - J[1, 0] * f[0]]) / det
        big = jnp.max(jnp.abs(d))
        d = d * jnp.minimum(1.0, self.max_step / jnp.where(big > 0, big, 1.0))
        ok = jnp.all(jnp.isfinite(d)) & (det != 0)
        d = jnp.where(ok, d, 0.0)
        result = optx.RESULTS.where(ok, optx.RESULTS.successful, optx.RESULTS.nonlinear_divergence)
        return y - d, _Newton2State(f, d, state.diff, state.step + 1, result), aux

    def terminate(self, fn, y, args, options, state, tags):
        small_step = jnp.all(jnp.abs(state.diff) <= self.atol + self.rtol * jnp.abs(y))
        size, size_prev = jnp.max(jnp.abs(state.diff)), jnp.max(jnp.abs(state.diff_prev))
        stagnant = (size < 1e-6) & (size > 0.5 * size_prev)
        small_f = jnp.all(jnp.abs(state.f) <= self.ftol) & stagnant
        failed = state.result != optx.RESULTS.successful
        return (small_step | small_f | failed), state.result

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}
