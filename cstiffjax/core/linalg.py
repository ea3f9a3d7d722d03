"""Small dense linear solves in plain ``jax.numpy`` operations (no LAPACK call).

The per-sample solves of the statics (6 or ``6 + 2m`` unknowns) run under ``vmap`` over
thousands of samples. ``jnp.linalg.solve`` lowers them on the CPU to one batched LAPACK
LU (``getrf``) and two batched triangular solves (``trsm``). In jaxlib 0.10.2 the batched
``trsm`` kernel (like the batched Cholesky and SVD with vectors) splits a batch whose
right-hand side exceeds about 1 MiB into tasks on XLA's intra-op thread pool and *blocks a
pool thread* until they are done; when XLA runs as many of those kernels at once as the
pool has threads (two independent solves of a Newton step and of its tangents, on a
2-core machine), every thread waits for tasks that no thread is free to run: the process
deadlocks, idle, forever (6 000 samples of a 6-cable robot: 6000 × 6 × 6 float64 =
1.7 MiB). :func:`solve` does the elimination as ordinary vectorized array operations
instead: it cannot deadlock, and under ``vmap`` it is as fast as the LAPACK loop
(``benchmarks/LIMITS.md``).
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int


def lu_factor(a: Float[Array, "k k"]) -> tuple[Float[Array, "k k"], Int[Array, " k"]]:
    """``P a = L U`` by Gaussian elimination with partial pivoting (LAPACK ``getrf``'s pivot
    choice: the largest magnitude in the column, the first of ties), in plain array
    operations: safe under ``vmap`` at any batch size (module docstring).

    **Arguments:** ``a``: (k, k) matrix.

    **Returns:** ``(lu, perm)``: ``lu`` holds ``U`` on and above the diagonal and ``L``'s
    multipliers below it (``L`` has a unit diagonal); row ``i`` of ``P a`` is row
    ``perm[i]`` of ``a``.
    """
    k = a.shape[-1]
    rows = jnp.arange(k)

    def eliminate(j, carry):
        m, perm = carry
        p = jnp.argmax(jnp.where(rows >= j, jnp.abs(m[:, j]), -1.0))
        swap = lambda x: jnp.where(_column(rows == j, x), x[p], jnp.where(_column(rows == p, x), x[j], x))  # noqa: E731
        m, perm = swap(m), swap(perm)
        below = rows > j
        factor = jnp.where(below, m[:, j] / m[j, j], 0.0)
        m = jnp.where((rows > j)[None, :], m - factor[:, None] * m[j][None, :], m)  # the columns right of j
        return jnp.where(below[:, None] & (rows == j)[None, :], factor[:, None], m), perm

    return jax.lax.fori_loop(0, k, eliminate, (a, rows))


def lu_solve(factors: tuple[Float[Array, "k k"], Int[Array, " k"]], b: Float[Array, "k ..."]) -> Float[Array, "k ..."]:
    """``a⁻¹ b`` from :func:`lu_factor`'s ``(lu, perm)`` of ``a``: forward then back
    substitution in plain array operations (``O(k²)`` per right-hand side; linear in ``b``,
    so a derivative in ``b`` costs a substitution, not a factorization).

    **Arguments:** ``factors``: :func:`lu_factor` of a (k, k) ``a``; ``b``: (k,) or (k, r).

    **Returns:** ``x`` of ``b``'s shape with ``a x = b`` (non-finite where ``a`` is singular).
    """
    lu, perm = factors
    k = lu.shape[-1]
    rows = jnp.arange(k)
    y = jnp.asarray(b)[perm].astype(lu.dtype)

    def forward(j, y):  # L y' = P b, L unit lower triangular, column by column
        return y - _column(jnp.where(rows > j, lu[:, j], 0.0), y) * y[j]

    def back(i, y):  # U x = y', from the last row up
        j = k - 1 - i
        y = y.at[j].set(y[j] / lu[j, j])
        return y - _column(jnp.where(rows < j, lu[:, j], 0.0), y) * y[j]

    return jax.lax.fori_loop(0, k, back, jax.lax.fori_loop(0, k, forward, y))


def solve(a: Float[Array, "k k"], b: Float[Array, "k ..."]) -> Float[Array, "k ..."]:
    """``a⁻¹ b`` (:func:`lu_factor` then :func:`lu_solve`): ``jnp.linalg.solve`` for the
    small dense systems of the statics (``k`` up to a few tens; ``O(k³)`` work in loops of
    ``k`` steps) without its LAPACK calls, safe under ``vmap`` at any batch size (module
    docstring). A singular ``a`` gives non-finite entries, as ``jnp.linalg.solve`` does.
    Differentiable in ``a`` and ``b`` (the operations are).

    **Arguments:** ``a``: (k, k) matrix; ``b``: (k,) or (k, r) right-hand side(s).

    **Returns:** ``x`` of ``b``'s shape with ``a x = b``.
    """
    return lu_solve(lu_factor(a), b)


def _column(v, x):
    """``v`` (k,) shaped to broadcast against ``x`` along its first axis."""
    return v.reshape(v.shape + (1,) * (x.ndim - 1))
