"""Process-wide JAX configuration, applied when :mod:`cstiffjax` is imported.

**float64.** Near-taut catenaries and stiff cables (EA ~ 1e6 N on strains ~ 1e-4) lose
all their significant digits in float32, so the package enables ``jax_enable_x64``.

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
"""

import os
from importlib import metadata

import jax

from cstiffjax.core import internals

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


jax.config.update("jax_enable_x64", True)
def _jaxlib_version() -> str:
    try:
        return metadata.version("jaxlib")
    except metadata.PackageNotFoundError:  # not installed as a distribution: untested, leave XLA alone
        return ""


_flags = fast_compile_flags(os.environ, _jaxlib_version(), internals.backends_ready())
if _flags is not None:
    os.environ["XLA_FLAGS"] = _flags
