"""The one adapter to private parts of JAX and equinox.

Everything the toolkit needs that JAX or equinox do not offer publicly is reached here and
nowhere else (``tests/test_results.py`` fails on a private access in any other module), so
an upgrade that moves an internal breaks one file, and each use degrades to public
behaviour where the internal is gone:

- equinox enumerations: the integer code a :class:`~cstiffjax.core.status.Status` holds
  (:func:`enum_codes`, :func:`enum_with_codes`), used by the status adapter;
- JAX's trace state (:func:`trace_state_clean`): whether a call is at top level;
- JAX's array type (:func:`uncommitted`): a buffer re-wrapped as not committed to its device;
- JAX's persistent-cache plumbing (:data:`CacheInterface`, :func:`install_compilation_cache`);
- whether JAX's backends are started (:func:`backends_ready`);
- the logger JAX reports a failed host callback on (:data:`CALLBACK_LOGGER`).
"""

import equinox as eqx
import jax.numpy as jnp

try:
    from jax._src.core import trace_state_clean as _trace_state_clean
except ImportError:  # pragma: no cover (another jax)
    _trace_state_clean = None
try:
    from jax._src.array import ArrayImpl as _ArrayImpl
except ImportError:  # pragma: no cover (another jax)
    _ArrayImpl = None
try:
    from jax._src import compilation_cache as _jax_cache
    from jax._src.compilation_cache_interface import CacheInterface
except ImportError:  # pragma: no cover (another jax: JAX's own file cache is used)
    _jax_cache, CacheInterface = None, object

CALLBACK_LOGGER = "jax._src.callback"
"""The logger on which JAX reports a host callback that raised (a failed ``throw=True`` solve)."""

__all__ = ["CALLBACK_LOGGER", "CacheInterface", "backends_ready", "enum_codes", "enum_message", "enum_with_codes",
           "install_compilation_cache", "trace_state_clean", "uncommitted"]


def enum_codes(member):
    """The integer code(s) an ``eqx.Enumeration`` item holds: a host array for a constant
    member, the array (or tracer) otherwise."""
    return member._value


def enum_with_codes(member, codes):
    """``member`` (any item of an ``eqx.Enumeration``) holding ``codes`` (int32, any shape)."""
    return eqx.tree_at(lambda s: s._value, member, jnp.asarray(codes, dtype=jnp.int32))


def enum_message(cls, code: int) -> str:
    """The message of the item with integer ``code`` of the ``eqx.Enumeration`` ``cls``."""
    return cls._index_to_message[code]


def trace_state_clean() -> bool | None:
    """Whether no JAX trace is active (``None`` when this jax does not say)."""
    return None if _trace_state_clean is None else bool(_trace_state_clean())


def uncommitted(x):
    """The buffer of the single-device array ``x`` re-wrapped as not committed to its device
    (no copy), or ``None`` when this jax cannot do that."""
    if _ArrayImpl is None:  # pragma: no cover
        return None
    try:
        y = _ArrayImpl(x.aval, x.sharding, x._arrays, committed=False)
    except (TypeError, AttributeError, ValueError):  # pragma: no cover (another jax)
        return None
    return None if y.committed else y


def install_compilation_cache(cache) -> bool:
    """Make ``cache`` (a :data:`CacheInterface`) JAX's persistent compilation cache.
    **Returns:** whether it is installed (else JAX keeps its own file cache)."""
    if _jax_cache is None or not hasattr(_jax_cache, "_cache_initialized_mutex"):  # pragma: no cover
        return False
    _jax_cache.reset_cache()
    with _jax_cache._cache_initialized_mutex:
        _jax_cache._cache = cache
        _jax_cache._cache_initialized = True
    return True


def backends_ready() -> bool:
    """Whether JAX has started its backends (``True`` when this jax does not say: then
    nothing that must precede the start is changed)."""
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # pragma: no cover (an internal that moved)
        return True

