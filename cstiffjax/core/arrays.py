"""Host values to JAX arrays without compiling anything.

In JAX 0.10 ``jnp.asarray`` of a NumPy array or a Python number runs a small compiled
program (``stage``, ``convert_element_type``, ``broadcast_in_dim`` for ``jnp.zeros``),
built once per shape and dtype in every new process: ~5-8 ms each. A warm
``cstiffjax diagnose`` met about forty of them (loading the robot and the recordings,
laying out the models, the discovery's fits; benchmarks/LATENCY.md). ``jax.device_put`` of a
NumPy array compiles nothing. :func:`to_device` is that, for host values; device arrays and
tracers go through ``jnp.asarray`` as before.

:func:`batched_like` is a tracing aid for loops written for one pose and batched with
``jax.vmap``.
"""

import jax
import jax.numpy as jnp
import numpy as np


def to_device(x, dtype=None) -> jax.Array:
    """``x`` as a JAX array of ``dtype`` (default: NumPy's choice for a host value, the
    array's own for a JAX array).

    **Arguments:** ``x``: a JAX array or tracer (then ``jnp.asarray(x, dtype)``), or anything
    ``np.asarray`` takes (placed with ``jax.device_put``); ``dtype``: a NumPy/JAX dtype.

    **Returns:** a JAX array (a tracer stays a tracer)."""
    if isinstance(x, jax.Array):  # tracers too
        return jnp.asarray(x, dtype=dtype)
    return jax.device_put(np.asarray(x, dtype=dtype))


def f64(x) -> jax.Array:
    """:func:`to_device` as float64 (the toolkit's converter for float leaves)."""
    return to_device(x, np.float64)


def batched_like(value, ref):
    """``value``, batched wherever ``ref`` is under ``jax.vmap`` (unchanged otherwise): a
    ``select`` on the constant ``True`` between ``value`` and ``ref``'s first entry, which
    XLA folds away (the compiled program computes the same numbers the same way).

    For the initial carry of a ``while_loop`` written for one pose. ``vmap``'s rule for
    ``while_loop`` finds the batched carries by batching the loop's body again until
    they stop changing, and once more with every carry batched when the loop's predicate
    is batched (every solve's is: each pose stops on its own). A body traced once per
    pass: a Newton iteration whose counters and Jacobian start unbatched was batched
    three times. Started batched, it is batched once (bundled diagnosis: tracing its
    fitting loop 1.68 -> 1.4 s, the posterior's ensemble, batched over walkers and
    samples, 1.9 -> 1.3 s; benchmarks/LATENCY.md).

    **Arguments:** ``value``: an array (any shape and dtype); ``ref``: an array of at
    least one entry, batched when the loop will be.

    **Returns:** ``value``, with ``ref``'s batching."""
    value = jnp.asarray(value)
    first = jnp.ravel(ref)[0]
    return jnp.where(True, value, jnp.broadcast_to(first, value.shape).astype(value.dtype))
