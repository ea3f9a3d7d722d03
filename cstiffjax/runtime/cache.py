"""JAX's persistent compilation cache for cstiffjax: where it lives, how to turn it on, what it holds.

The command line turns it on by default (:func:`cstiffjax.commands.cli.main`), so a second run
of the same command loads its compiled XLA programs from disk instead of compiling them
again. Importing :mod:`cstiffjax` never turns it on: API users (a notebook) opt in with one
call, :func:`enable_compilation_cache` (``cstiffjax.enable_cache()``), which returns the folder.

Location (first that applies):

1. ``$CSTIFFJAX_CACHE_DIR``; the values ``off``, ``0``, ``false``, ``no``, ``none`` or
   the empty string disable the cache;
2. ``$XDG_CACHE_HOME/cstiffjax/jax`` (an absolute ``$XDG_CACHE_HOME`` only);
3. ``~/.cache/cstiffjax/jax``.

A folder that cannot be used (a file of that name, a read-only folder) gives a
:class:`~cstiffjax.runtime.store.CacheWarning` and the run goes on without the cache.
``cstiffjax cache info`` (:func:`cache_info`) says where it is, whether it is on and why, and
what it holds; ``cstiffjax cache clear`` (:func:`clear_cache`) removes its files.

Every compiled program is cached, however small or fast to compile: the diagnosis
compiles dozens of sub-second programs, and together they are most of its cold time.
The largest programs (the diagnosis's fitting loop, residuals and posterior ensemble) are
also kept *traced*, as serialized :mod:`jax.export` programs in ``<folder>/programs``
(:mod:`cstiffjax.runtime.programs`), so a warm run skips their tracing too; turning the cache on
or off turns those on or off with it. Entries are keyed by what makes them (the XLA
program, jaxlib, the XLA flags and compile options; for serialized programs the source of
the packages and the library versions), so an edited model never finds an old entry.
Several processes may share the folder, and an unreadable entry is compiled again and
rewritten (:mod:`cstiffjax.runtime.store`).
"""

import contextlib
import dataclasses
import os
import tempfile
from pathlib import Path

import jax
from jax.experimental.compilation_cache import compilation_cache as _cc

from cstiffjax.runtime import programs, store

ENV = "CSTIFFJAX_CACHE_DIR"
_OFF = ("off", "0", "false", "no", "none", "")


def _location(environ=None) -> tuple[Path | None, str]:
    """The folder of the module docstring's rules (``None``: turned off) and the rule that gave it."""
    env = os.environ if environ is None else environ
    if ENV in env:
        value = env[ENV].strip()
        if value.lower() in _OFF:
            return None, f"turned off by ${ENV}={env[ENV]!r}"
        return Path(value).expanduser().absolute(), f"${ENV}"
    xdg = env.get("XDG_CACHE_HOME", "").strip()
    if xdg and Path(xdg).expanduser().is_absolute():
        return (Path(xdg).expanduser() / "cstiffjax" / "jax").absolute(), "$XDG_CACHE_HOME/cstiffjax/jax"
    return (Path.home() / ".cache" / "cstiffjax" / "jax").absolute(), "the default ~/.cache/cstiffjax/jax"


def cache_dir(environ=None) -> Path | None:
    """The cache folder the rules of the module docstring give, or ``None`` when disabled.

    **Arguments:** ``environ``: a mapping of environment variables (default ``os.environ``).

    **Returns:** an absolute :class:`~pathlib.Path` (not created) or ``None``.
    """
    return _location(environ)[0]


def _not_a_folder(folder: Path) -> Path | None:
    """The first of ``folder`` and its ancestors that exists and is not a folder, if any."""
    for p in (folder, *folder.parents):
        if p.exists() or p.is_symlink():
            return None if p.is_dir() else p
    return None


def _unusable(folder: Path) -> str | None:
    """Why ``folder`` cannot hold the cache (creating it and ``programs/`` in it, and a
    file in each), or ``None``."""
    blocker = _not_a_folder(folder)
    if blocker is not None:
        return "it is a file, not a folder" if blocker == folder else f"{blocker} is a file, not a folder"
    try:
        (folder / store.PROGRAMS).mkdir(parents=True, exist_ok=True)
        for d in (folder, folder / store.PROGRAMS):
            fd, probe = tempfile.mkstemp(prefix=".cstiffjax-probe-", dir=d)
            os.close(fd)
            os.unlink(probe)
    except OSError as e:
        return f"cannot write there ({e.strerror or e})"
    return None


def enable_compilation_cache(path=None, *, environ=None) -> Path | None:
    """Turn on the persistent compilation cache (and serialized programs) for this process.

    One call from a notebook or script: ``cstiffjax.enable_cache()`` uses the folder of the
    module docstring's rules (``~/.cache/cstiffjax/jax`` by default) and takes effect for
    programs compiled before the call too.

    **Arguments:**

    - ``path``: cache folder; default :func:`cache_dir` (which honours
      ``$CSTIFFJAX_CACHE_DIR``, including ``off``).
    - ``environ``: environment mapping for :func:`cache_dir` (default ``os.environ``).

    **Returns:** the folder in use, or ``None`` when the cache is turned off, or the folder
    cannot be used (a file of that name, a read-only folder: a
    :class:`~cstiffjax.runtime.store.CacheWarning` says so); then JAX compiles as usual and
    nothing else changes.
    """
    folder = cache_dir(environ) if path is None else Path(path).expanduser().absolute()
    if folder is None:
        return None
    why = _unusable(folder)
    if why is not None:
        store.warn(f"compilation cache {folder}: {why}; running without the cache (set ${ENV} to a "
                   "writable folder, or to off)")
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    if not store.install(folder):  # take effect even if something was compiled before this call
        _cc.reset_cache()  # pragma: no cover (another jax: its own file cache)
    programs.set_folder(folder / store.PROGRAMS)
    store.remove_stale(folder)
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


@dataclasses.dataclass(frozen=True)
class CacheInfo:
    """Where the cache is, whether it is on and why, and what it holds (:func:`cache_info`).

    **Fields:** ``folder`` (``None``: turned off), ``enabled`` (the command line and
    :func:`enable_compilation_cache` use it: on and usable), ``reason`` (why, naming the
    environment variable or rule), ``in_use`` (this process uses it now), the numbers of
    the cache's own files (:data:`~cstiffjax.runtime.store.OWN`): ``compiled`` (XLA
    executables), ``programs`` (serialized traced programs), ``temporary`` (writes in
    progress or leftovers), ``other`` (JAX's bookkeeping, XLA's GPU autotuning), ``size_bytes``
    (of all of them), and ``foreign``: other files in the folder (never touched).
    """

    folder: Path | None
    enabled: bool
    reason: str
    in_use: bool
    compiled: int
    programs: int
    temporary: int
    other: int
    size_bytes: int
    foreign: int


def _usable_without_writing(folder: Path) -> str | None:
    """:func:`_unusable`, judged without creating anything (permissions of the folder or of
    its nearest existing ancestor)."""
    blocker = _not_a_folder(folder)
    if blocker is not None:
        return "it is a file, not a folder" if blocker == folder else f"{blocker} is a file, not a folder"
    probe = next(p for p in (folder, *folder.parents) if p.exists())
    if not os.access(probe, os.W_OK | os.X_OK):
        return f"{probe} is not writable"
    return None


def cache_info(path=None, *, environ=None) -> CacheInfo:
    """What :func:`enable_compilation_cache` would use, and what the folder holds now
    (nothing is created or changed).

    **Arguments:** ``path``, ``environ``: as for :func:`enable_compilation_cache`.

    **Returns:** a :class:`CacheInfo`.
    """
    if path is None:
        folder, rule = _location(environ)
    else:
        folder, rule = Path(path).expanduser().absolute(), "given as an argument"
    if folder is None:
        return CacheInfo(None, False, rule, False, 0, 0, 0, 0, 0, 0)
    why = _usable_without_writing(folder)
    reason = f"location from {rule}" + (f"; not usable: {why}" if why else "")
    files = store.own_files(folder)
    size = sum(_size(p) for kind, ps in files.items() if kind != "foreign" for p in ps)
    in_use = jax.config.jax_compilation_cache_dir == str(folder) and programs.folder() == folder / store.PROGRAMS
    return CacheInfo(folder, why is None, reason, in_use, len(files["compiled"]), len(files["programs"]),
                     len(files["temporary"]), len(files["other"]), size, len(files["foreign"]))


def _size(p: Path) -> int:
    try:
        return p.stat().st_size
    except OSError:  # removed meanwhile (another process)
        return 0


@dataclasses.dataclass(frozen=True)
class Cleared:
    """What :func:`clear_cache` removed: ``folder``, ``removed`` (``{kind: count}`` of
    :data:`~cstiffjax.runtime.store.OWN`), ``size_bytes`` freed, ``failed`` (``(path,
    reason)`` of the files that could not be removed) and ``foreign`` (other files, kept)."""

    folder: Path | None
    removed: dict
    size_bytes: int
    failed: tuple
    foreign: int


def clear_cache(path=None, *, environ=None) -> Cleared:
    """Remove the cache's own files (:data:`~cstiffjax.runtime.store.OWN`) from the folder of
    :func:`cache_info`, and its then-empty sub-folders; any other file stays, and so does
    the folder itself.

    **Arguments:** ``path``, ``environ``: as for :func:`enable_compilation_cache`.

    **Returns:** a :class:`Cleared` (``folder`` ``None`` when the cache is turned off: nothing
    is removed).
    """
    folder = cache_dir(environ) if path is None else Path(path).expanduser().absolute()
    if folder is None:
        return Cleared(None, {}, 0, (), 0)
    files = store.own_files(folder)
    removed, size, failed = {}, 0, []
    for kind, paths in files.items():
        if kind == "foreign":
            continue
        removed[kind] = 0
        for p in paths:
            n = _size(p)
            try:
                p.unlink()
            except FileNotFoundError:  # removed meanwhile
                continue
            except OSError as e:
                failed.append((p, e.strerror or str(e)))
                continue
            removed[kind] += 1
            size += n
    for sub in sorted({p.parent for ps in files.values() for p in ps if p.parent != folder}, reverse=True):
        with contextlib.suppress(OSError):
            sub.rmdir()  # only when empty
    with contextlib.suppress(OSError):
        (folder / store.PROGRAMS).rmdir()
    return Cleared(folder, removed, size, tuple(failed), len(files["foreign"]))
