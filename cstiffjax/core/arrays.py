"""Host values to JAX arrays without compiling anything.

In JAX 0.10 ``jnp.asarray`` of a NumPy array or a Python number runs a small compiled
program (``stage``, ``convert_element_type``, ``broadcast_in_dim`` for ``jnp.zeros``),
built once per shape and dtype in every new process: ~5-8 ms each. A warm
``cstiffjax diagnose`` met about forty of them (loading the robot and the recordings,
laying out the models, the discovery's fits; benchmarks/LATENCY.md). ``jax.device_put`` of a
NumPy array compiles nothing. :func:`to_device` is that, for host values; device arrays and
tracers go through ``jnp.asarray`` as before.
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
