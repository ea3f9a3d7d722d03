"""Test session set-up: float64, one compilation cache shared by the whole session, GPU
memory allocated as needed (no pre-allocation per worker), and the command line's
garbage-collector thresholds (``cstiffjax.commands.cli.GC_THRESHOLDS``: the suite traces and
compiles as the command line does; three heavy test files 100-103 -> 96-98 s;
``CSTIFFJAX_TEST_GC=default`` keeps CPython's).

The suite compiles the same XLA programs many times over (the diagnosis model for each
test file, closures rebuilt per call, the two xdist workers compiling the same thing).
A persistent JAX compilation cache in a *fresh temporary folder per session* lets every
later compile of an identical program load it instead: the controller process makes the
folder, the workers inherit it through ``CSTIFFJAX_TEST_CACHE``, and it is removed at the
end, so every run starts as cold as a new machine and nothing is written into ``$HOME``.
``CSTIFFJAX_TEST_CACHE=off`` compiles everything from scratch (the cache never changes
results: it stores compiled programs keyed by their exact HLO and compile options).
"""

import os
import shutil
import tempfile

import pytest

# Opt-in (CSTIFFJAX_TEST_XLA_OPT=fast): LLVM -O0 for the generated CPU code. It cuts the
# compile time of the compile-bound tests by about a third (measured: test_css + test_models
# 203 -> 140 CPU-s), but unoptimised code runs many times slower, and the tests that execute
# a lot (the diagnosis's emcee posterior check) then take far longer than they save: a
# clean-clone suite with it on the whole time ran past 20 min. Off by default. Set before
# JAX starts its backend; inherited by the CLI and notebook subprocesses.
_FAST_COMPILE = "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
if os.environ.get("CSTIFFJAX_TEST_XLA_OPT", "").strip().lower() == "fast" and \
        "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _FAST_COMPILE).strip()

# On a GPU every xdist worker would otherwise pre-allocate 75% of the device's memory at its
# first computation, and the second worker fails at start-up: allocate as needed instead,
# unless the user chose (XLA_PYTHON_CLIENT_PREALLOCATE / _MEM_FRACTION / _ALLOCATOR). Set
# before JAX starts its backend; inherited by the CLI and notebook subprocesses.
if not any(k in os.environ for k in ("XLA_PYTHON_CLIENT_PREALLOCATE", "XLA_PYTHON_CLIENT_MEM_FRACTION",
                                     "XLA_PYTHON_CLIENT_ALLOCATOR")):
    os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"

# XLA's CPU pool: one thread per core (XLA's own default) for every test, whichever test starts
# JAX first. `cstiffjax diagnose` sizes the pool to one thread when it is the first to start JAX
# (fitting.commands.diagnose.XLA_THREADS), which moves ill-conditioned estimates at rounding level
# (up to ~1e-3 relative on the golden cases); called in-process it would otherwise give numbers
# that depend on the order of a worker's tests. With PJRT_NPROC set the command leaves the pool
# alone (a user's PJRT_NPROC or NPROC wins likewise). tests/test_golden.py checks the one-thread
# command line in a subprocess against the same documents. (Importing the config starts no backend.)
from cstiffjax.core.config import THREADS_ENV  # noqa: E402  (after XLA_FLAGS: its import reads them)

if not any(k in os.environ for k in THREADS_ENV):
    os.environ["PJRT_NPROC"] = str(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                   else os.cpu_count() or 1)

import jax  # noqa: E402  (after XLA_FLAGS, the allocator settings and the pool's size)

# The command line's heartbeat (a status line every ~10 s on a stderr that is not a terminal,
# cstiffjax.core.progress) is off for the tests that read a command's stderr line by line;
# tests/test_ux.py tests it with a fake clock and turns it on where it checks the command line.
os.environ.setdefault("CSTIFFJAX_PROGRESS_EVERY", "off")

_VAR = "CSTIFFJAX_TEST_CACHE"
_OFF = ("off", "0", "false", "no", "none", "")

jax.config.update("jax_enable_x64", True)


def pytest_configure(config):
    if os.environ.get("CSTIFFJAX_TEST_GC", "") != "default":
        import gc

        from cstiffjax.commands.cli import GC_THRESHOLDS

        gc.set_threshold(*GC_THRESHOLDS)
    if not hasattr(config, "workerinput") and _VAR not in os.environ:  # the controller (or a run without xdist)
        config._cstiffjax_cache = tempfile.mkdtemp(prefix="cstiffjax-test-cache-")
        os.environ[_VAR] = config._cstiffjax_cache
    folder = os.environ.get(_VAR, "off")
    if folder.strip().lower() in _OFF:
        os.environ.setdefault("CSTIFFJAX_CACHE_DIR", "off")  # the CLI under test: no cache in $HOME
        return
    os.environ["CSTIFFJAX_CACHE_DIR"] = folder  # the CLI under test (in process or a subprocess) shares it
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.05)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def pytest_unconfigure(config):
    folder = getattr(config, "_cstiffjax_cache", None)
    if folder:
        shutil.rmtree(folder, ignore_errors=True)
        os.environ.pop(_VAR, None)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """Copies of the example02 robot and its first 20 recordings in a folder of their own
    (the command-line output tests write beside them)."""
    from cstiffjax.examples import example_path

    d = tmp_path_factory.mktemp("lab")
    shutil.copy(example_path("example02/robot.toml"), d / "robot.toml")
    lines = example_path("example02/recordings.csv").read_text().splitlines()
    (d / "rec.csv").write_text("\n".join(lines[:21]) + "\n")
    return d / "robot.toml", d / "rec.csv"
