"""Tracing cost of the loops written for one pose and batched with ``jax.vmap``
(:func:`cstiffjax.core.arrays.batched_like`): the loop's body is batched once, and the
numbers are those of the unbatched loop.

This file counts ``vmap``'s passes over a loop body through JAX's batching module (no
public API says how often a jaxpr was batched): it is on the allowed list of
``tests/test_results.py``'s private-access check.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax._src.interpreters import batching

from cstiffjax.core.arrays import batched_like
from cstiffjax.statics.root_finding import dense_lm, newton
from fitting.calibration.lm import masked_levenberg_marquardt


def _system(c):
    return lambda z: jnp.array([z[0] ** 2 - c, z[0] * z[1] - 1.0])  # root (√c, 1/√c)


def _body_passes(monkeypatch, fn, *args, in_axes=0, carry=6) -> int:
    """How many different batchings of the loop body with ``carry`` outputs (the solve's
    iteration; the LU solve's inner loops have fewer) tracing ``vmap(fn)`` made (a repeated
    request is served from JAX's cache: it costs nothing)."""
    seen = []
    real = batching._batch_jaxpr_axes

    def counting(closed_jaxpr, axis_data, in_dims, out_dims):
        seen.append((closed_jaxpr, len(out_dims), tuple(in_dims), tuple(map(repr, out_dims))))
        return real(closed_jaxpr, axis_data, in_dims, out_dims)

    monkeypatch.setattr(batching, "_batch_jaxpr_axes", counting)
    jax.make_jaxpr(jax.vmap(fn, in_axes=in_axes))(*args)
    return len({(id(j), i, o) for j, n, i, o in seen if n == carry})


def test_batched_like_is_the_value_with_the_batching_of_ref():
    ref = jnp.array([1.0, np.nan])  # the value of ref never matters, a NaN included
    for v in (jnp.zeros((), jnp.int32), jnp.ones((2, 3)), jnp.array(True), jnp.asarray(2.5)):
        for f in (batched_like, jax.jit(batched_like)):
            out = f(v, ref)
            assert out.dtype == v.dtype and out.shape == v.shape
            np.testing.assert_array_equal(out, v)
    refs = jnp.arange(6.0).reshape(3, 2)
    with pytest.raises(ValueError):  # batched like ref: vmap cannot return it unbatched
        jax.vmap(lambda r: batched_like(jnp.zeros(()), r), out_axes=None)(refs)
    unbatched = jax.vmap(lambda r, s: batched_like(jnp.zeros(()), s), in_axes=(0, None), out_axes=None)
    assert float(unbatched(refs, jnp.ones(2))) == 0.0


def test_vmapped_newton_batches_its_body_once_and_solves_as_one_pose_at_a_time(monkeypatch):
    """The warm Newton's counters and Jacobian start batched as ``z0`` is: ``vmap`` batches
    its body once (three times or more with ``z0`` unbatched, when the carry's batching has to be
    found by iterating); each pose's root and step count are those of its own solve."""
    c = jnp.array([2.0, 3.0, 5.0])

    def solve(ci, z0):
        return newton(_system(ci), z0, 12, 10.0)

    assert _body_passes(monkeypatch, solve, c, jnp.ones((3, 2))) == 1
    assert _body_passes(monkeypatch, solve, c, jnp.ones(2), in_axes=(0, None)) >= 3
    z, J, taken = jax.jit(jax.vmap(solve))(c, jnp.ones((3, 2)))
    for k in range(3):
        zk, Jk, tk = jax.jit(solve)(c[k], jnp.ones(2))
        np.testing.assert_array_equal(z[k], zk)
        np.testing.assert_array_equal(J[k], Jk)
        assert int(taken[k]) == int(tk)
    np.testing.assert_allclose(z[:, 0], np.sqrt(c), rtol=1e-9)  # (the last step, under NEWTON_STOP, is not applied)


def test_vmapped_dense_lm_batches_its_body_once(monkeypatch):
    """The cold start's Levenberg-Marquardt: its counters start batched as the residual at
    ``z0`` is (even from a shared ``z0``); roots as one pose at a time."""
    c = jnp.array([2.0, 3.0])

    def solve(ci, z0):
        return dense_lm(_system(ci), z0, 50)

    assert _body_passes(monkeypatch, solve, c, jnp.ones(2), in_axes=(0, None)) == 1
    z, _, ok, steps = jax.jit(jax.vmap(solve, in_axes=(0, None)))(c, jnp.ones(2))
    for k in range(2):
        zk, _, _, sk = jax.jit(solve)(c[k], jnp.ones(2))
        np.testing.assert_array_equal(z[k], zk)
        assert int(steps[k]) == int(sk)
    assert bool(jnp.all(ok))
    np.testing.assert_allclose(z[:, 0], np.sqrt(c), rtol=1e-9)


def test_vmapped_fitting_loop_batches_its_body_once(monkeypatch):
    """The fitting loop (``masked_levenberg_marquardt``, vmapped over starts as a
    calibration of many robots is): its state starts batched as ``theta0`` is, so its body
    (8 carried fields) is batched once; each fit is the one made alone."""
    A = jnp.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])

    def fun(th, y):  # linear residuals: (r (3, 1), J (3, 2), ok (3,))
        return (A @ th - y)[:, None], A, jnp.ones(3, bool)

    def fit(th0, y):
        return masked_levenberg_marquardt(fun, th0, y, max_steps=5).theta

    starts, y = jnp.array([[1.0, 1.0], [-2.0, 0.5]]), jnp.array([1.0, 2.0, 3.0])
    assert _body_passes(monkeypatch, fit, starts, y, in_axes=(0, None), carry=8) == 1
    thetas = jax.jit(jax.vmap(fit, in_axes=(0, None)))(starts, y)
    for k in range(2):
        np.testing.assert_array_equal(thetas[k], jax.jit(fit)(starts[k], y))
    np.testing.assert_allclose(thetas[0], np.linalg.lstsq(np.asarray(A), np.asarray(y), rcond=None)[0], rtol=1e-10)
