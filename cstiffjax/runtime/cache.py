"""JAX's persistent compilation cache for cstiffjax: where it lives and how to turn it on.

The command line turns it on by default (:func:`cstiffjax.commands.cli.main`), so a second run
of the same command loads its compiled XLA programs from disk instead of compiling them
again. Importing :mod:`cstiffjax` never turns it on: API users opt in with
:func:`enable_compilation_cache`.

Location (first that applies):

1. ``$CSTIFFJAX_CACHE_DIR``; the values ``off``, ``0``, ``false``, ``no``, ``none`` or
   the empty string disable the cache;
2. ``$XDG_CACHE_HOME/cstiffjax/jax``;
3. ``~/.cache/cstiffjax/jax``.

Every compiled program is cached, however small or fast to compile: the diagnosis
compiles dozens of sub-second programs, and together they are most of its cold time.
The largest programs (the diagnosis's fitting loop, residuals and posterior ensemble) are
also kept *traced*, as serialized :mod:`jax.export` programs in ``<folder>/programs``
(:mod:`cstiffjax.runtime.programs`), so a warm run skips their tracing too; turning the cache on
or off turns those on or off with it.
"""

import contextlib
import os
from pathlib import Path

import jax
from jax.experimental.compilation_cache import compilation_cache as _cc

from cstiffjax.runtime import programs

ENV = "CSTIFFJAX_CACHE_DIR"
_OFF = ("off", "0", "false", "no", "none", "")


def cache_dir(environ=None) -> Path | None:
    """The cache folder the rules of the module docstring give, or ``None`` when disabled.

    **Arguments:** ``environ``: a mapping of environment variables (default ``os.environ``).

    **Returns:** an absolute :class:`~pathlib.Path` (not created) or ``None``.
    """
    env = os.environ if environ is None else environ
    if ENV in env:
        value = env[ENV].strip()
        if value.lower() in _OFF:
            return None
        return Path(value).expanduser().absolute()
    xdg = env.get("XDG_CACHE_HOME", "").strip()
    base = Path(xdg).expanduser() if xdg and Path(xdg).expanduser().is_absolute() else Path.home() / ".cache"
    return (base / "cstiffjax" / "jax").absolute()


def enable_compilation_cache(path=None, *, environ=None) -> Path | None:
    """Turn on JAX's persistent compilation cache for this process.

    **Arguments:**

    - ``path``: cache folder; default :func:`cache_dir` (which honours
      ``$CSTIFFJAX_CACHE_DIR``, including ``off``).
    - ``environ``: environment mapping for :func:`cache_dir` (default ``os.environ``).

    **Returns:** the folder in use, or ``None`` when the cache is disabled or the folder
    cannot be created (then JAX compiles as usual; nothing else changes).
    """
    folder = cache_dir(environ) if path is None else Path(path).expanduser().absolute()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    _cc.reset_cache()  # take effect even if something was compiled before this call
    programs.set_folder(folder / "programs")
    return folder


_KEYS = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
         "jax_persistent_cache_min_entry_size_bytes")


@contextlib.contextmanager
def compilation_cache(path=None, *, environ=None):
    """Context manager: :func:`enable_compilation_cache` inside the block, the previous
    JAX cache settings after it (so :func:`cstiffjax.commands.cli.main` called from Python leaves the
    process as it found it). Yields the folder in use or ``None``."""
    old = {k: getattr(jax.config, k) for k in _KEYS}
    old_programs = programs.folder()
    try:
        yield enable_compilation_cache(path, environ=environ)
    finally:
        for k, v in old.items():
            jax.config.update(k, v)
        _cc.reset_cache()
        programs.set_folder(old_programs)


def disable_compilation_cache() -> None:
    """Stop writing to / reading from the persistent cache (for the rest of the process)."""
    jax.config.update("jax_compilation_cache_dir", None)
    _cc.reset_cache()
    programs.set_folder(None)
