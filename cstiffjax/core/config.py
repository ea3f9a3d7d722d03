"""Process-wide JAX configuration, applied when :mod:`cstiffjax` is imported.

**float64.** Near-taut catenaries and stiff cables (EA ~ 1e6 N on strains ~ 1e-4) lose
all their significant digits in float32, so the package enables ``jax_enable_x64``: with
``jax.config`` when JAX is already imported, else by setting ``JAX_ENABLE_X64=1`` in
``os.environ``, which JAX reads when it is imported (so this module imports no JAX: the
command line's ``--version`` and ``--help`` answer without it; subprocesses inherit it).

**Faster CPU compilation.** The toolkit's programs (equilibria under forward-mode
Jacobians, inside Levenberg-Marquardt loops) are compile-bound on CPU: XLA's newer CPU
fusion emitters make several hundred separately compiled kernels of them. With
``--xla_cpu_use_fusion_emitters=false`` (XLA's classic elemental emitter) the same
programs compile faster and run as fast, with the same results to rounding. Measured on
the 2-core CI machine (README, Benchmarks): the test suite 475 -> 337 s, the bundled
``cstiffjax diagnose`` with an empty cache 34 -> 28 s, the catenary model's fitting loop
14.3 -> 12.0 s to compile; warm diagnose 12.1 vs 12.3 s, CSS and stiffness throughput
unchanged within noise.

The flag is appended to ``XLA_FLAGS`` only when all of these hold (else nothing is
changed): ``$CSTIFFJAX_XLA_FAST_COMPILE`` is not ``0``/``off``/``false``/``no``;
``XLA_FLAGS`` does not already name ``xla_cpu_use_fusion_emitters`` (your setting wins);
JAX's backends are not initialized yet (XLA reads its flags once, when the first backend
starts: import cstiffjax before running JAX code); and the installed jaxlib is one in
which the flag was tested (:data:`TESTED_JAXLIB`). The last condition matters: XLA
*aborts the process* on a flag it does not know, so an untested jaxlib is left alone.
The change is made to ``os.environ``, so subprocesses (a CLI call from a notebook)
inherit it.

**XLA's CPU threads, for a command.** :func:`xla_threads` sizes XLA's CPU pools
(``PJRT_NPROC``, read when the backend starts) for a command whose work is thousands of
calls of small programs; the command line applies it to ``cstiffjax diagnose``
(:mod:`cstiffjax.commands.cli`, a command module's ``XLA_THREADS``). The library's import
leaves the pools as XLA sizes them (one thread per core: a workspace sweep's large
batches use them).
"""

import contextlib
import os
import sys
from importlib import metadata

FAST_COMPILE_ENV = "CSTIFFJAX_XLA_FAST_COMPILE"
FAST_COMPILE_FLAG = "--xla_cpu_use_fusion_emitters=false"
TESTED_JAXLIB = ((0, 10), (0, 11))  # [from, to): jaxlib versions where the flag exists and was measured
_OFF = ("0", "off", "false", "no")


def _version(text: str) -> tuple[int, int]:
    parts = text.split(".")
    try:
        return int(parts[0]), int(parts[1])
    except (IndexError, ValueError):
        return (0, 0)


def fast_compile_flags(environ, jaxlib_version: str, backends_ready: bool) -> str | None:
    """The ``XLA_FLAGS`` value with :data:`FAST_COMPILE_FLAG` appended, or ``None`` when it
    must be left as it is (the rules of the module docstring).

    **Arguments:** ``environ``: the environment mapping; ``jaxlib_version``: e.g.
    ``"0.10.2"``; ``backends_ready``: whether a JAX backend has already started.

    **Returns:** the new ``XLA_FLAGS`` string, or ``None``.
    """
    if environ.get(FAST_COMPILE_ENV, "").strip().lower() in _OFF or backends_ready:
        return None
    current = environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" in current:
        return None
    if not tested_jaxlib(jaxlib_version):
        return None
    return f"{current} {FAST_COMPILE_FLAG}".strip()


def tested_jaxlib(jaxlib_version: str | None = None) -> bool:
    """Whether ``jaxlib_version`` (default: the installed one) is in :data:`TESTED_JAXLIB`,
    where the XLA options the toolkit sets were measured (XLA rejects an option it does not
    know: untested versions get none)."""
    lo, hi = TESTED_JAXLIB
    return lo <= _version(_jaxlib_version() if jaxlib_version is None else jaxlib_version) < hi


X64_ENV = "JAX_ENABLE_X64"


def _enable_x64() -> None:
    """float64 for the process (module doc): now if JAX is imported, else when it is."""
    if "jax" in sys.modules:
        sys.modules["jax"].config.update("jax_enable_x64", True)
    else:
        os.environ[X64_ENV] = "1"


def backends_ready() -> bool:
    """Whether a JAX backend has started (``False`` while JAX is not even imported)."""
    if "jax" not in sys.modules:
        return False
    from cstiffjax.core import internals

    return internals.backends_ready()


_enable_x64()


def _jaxlib_version() -> str:
    try:
        return metadata.version("jaxlib")
    except metadata.PackageNotFoundError:  # not installed as a distribution: untested, leave XLA alone
        return ""


_flags = fast_compile_flags(os.environ, _jaxlib_version(), backends_ready())
if _flags is not None:
    os.environ["XLA_FLAGS"] = _flags


THREADS_ENV = ("PJRT_NPROC", "NPROC")  # XLA's CPU client reads the first that is set, else uses every core


def xla_threads_env(environ, threads: int, backends_ready: bool) -> str | None:
    """The ``PJRT_NPROC`` value that runs XLA's CPU programs on ``threads`` threads, or
    ``None`` when it must be left as it is: the environment already sizes the pools
    (``PJRT_NPROC`` or ``NPROC``: your setting wins) or a JAX backend has started (XLA
    sized them then).

    **Arguments:** ``environ``: the environment mapping; ``threads``: >= 1;
    ``backends_ready``: whether a JAX backend has already started.

    **Returns:** the value to set, or ``None``.
    """
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads must be an integer >= 1, got {threads!r}")
    if backends_ready or any(name in environ for name in THREADS_ENV):
        return None
    return str(threads)


@contextlib.contextmanager
def xla_threads(threads: int):
    """Context manager: this process's XLA CPU programs run on ``threads`` threads
    (:func:`xla_threads_env`'s rules: ``PJRT_NPROC`` set in ``os.environ`` before JAX's
    backend starts, unless the environment sizes the pools already or it has started).
    Yields whether it was set; on exit the variable is removed again (the pools keep the
    size they started with; a backend not started inside the block starts as XLA sizes it).

    For a command line whose work is many calls of small programs (arrays of one row per
    sample and cable): a pool of one thread per core buys them nothing but hand-offs, and
    its threads spin while they wait, taking the cores from the compilation in the
    background and from the figures' process (the measurement is beside
    ``fitting.commands.diagnose.XLA_THREADS`` and in ``benchmarks/LATENCY.md``). Results
    change at rounding level (XLA splits some operations by thread: ~1e-14 relative in a
    well-conditioned quantity, more in an ill-conditioned one)."""
    value = xla_threads_env(os.environ, threads, backends_ready())
    if value is not None:
        os.environ["PJRT_NPROC"] = value
    try:
        yield value is not None
    finally:
        if value is not None:
            os.environ.pop("PJRT_NPROC", None)
