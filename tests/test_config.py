"""Process-wide configuration at import (cstiffjax/core/config.py): float64 and the CPU compile flag."""

import os
import subprocess
import sys

import jax
import pytest

from cstiffjax.core import config as C

FLAG = C.FAST_COMPILE_FLAG


def test_float64_is_on():
    assert jax.config.jax_enable_x64 and jax.numpy.ones(1).dtype == "float64"


@pytest.mark.parametrize("environ, version, ready, expected", [
    ({}, "0.10.2", False, FLAG),
    ({"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}, "0.10.0", False,
     f"--xla_force_host_platform_device_count=2 {FLAG}"),
    ({"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"}, "0.10.2", False, None),  # the user's setting wins
    ({C.FAST_COMPILE_ENV: "0"}, "0.10.2", False, None),
    ({C.FAST_COMPILE_ENV: " Off "}, "0.10.2", False, None),
    ({C.FAST_COMPILE_ENV: "1"}, "0.10.2", False, FLAG),
    ({}, "0.10.2", True, None),  # too late: XLA has read its flags
    ({}, "0.9.9", False, None),  # untested jaxlib: XLA aborts on unknown flags, leave it alone
    ({}, "0.11.0", False, None),
    ({}, "garbage", False, None),
])
def test_fast_compile_decision(environ, version, ready, expected):
    assert C.fast_compile_flags(environ, version, ready) == expected


def _flags_after(code):
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", C.FAST_COMPILE_ENV)}
    env["JAX_PLATFORMS"] = "cpu"
    out = subprocess.run([sys.executable, "-c", code + "; import os; print(repr(os.environ.get('XLA_FLAGS')))"],
                         capture_output=True, text=True, env=env, timeout=120, check=True)
    return out.stdout.strip().splitlines()[-1]


@pytest.mark.skipif(not C.TESTED_JAXLIB[0] <= C._version(C._jaxlib_version()) < C.TESTED_JAXLIB[1],
                    reason="the flag is only applied on a tested jaxlib")
def test_import_sets_the_flag_only_before_the_backend_starts():
    # a fresh process: importing cstiffjax appends the flag, and a computation then runs with it
    assert _flags_after("import cstiffjax, jax.numpy as jnp; assert float(jnp.ones(2).sum()) == 2.0") == repr(FLAG)
    # a backend already running: nothing is changed (it would not take effect)
    assert _flags_after("import jax.numpy as jnp; jnp.ones(1).block_until_ready(); import cstiffjax") == "None"


@pytest.mark.parametrize("environ, ready, expected", [
    ({}, False, "1"),
    ({"PJRT_NPROC": "4"}, False, None),  # the user's setting wins
    ({"NPROC": "2"}, False, None),  # XLA reads NPROC too
    ({}, True, None),  # too late: the pools are sized when the backend starts
])
def test_xla_threads_decision(environ, ready, expected):
    assert C.xla_threads_env(environ, 1, ready) == expected


@pytest.mark.parametrize("threads", [0, -1, True, 1.0, "1"])
def test_xla_threads_must_be_a_positive_integer(threads):
    with pytest.raises(ValueError, match="threads must be an integer >= 1"):
        C.xla_threads_env({}, threads, False)


_POOL = ("n = sum(open(f'/proc/self/task/{t}/comm').read().strip().endswith('XLAEigen') "
         "for t in os.listdir('/proc/self/task'))")


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads through Linux's /proc")
@pytest.mark.parametrize("command, env, threads", [
    ("diagnose", {}, "1"),  # its module's XLA_THREADS
    ("check", {}, None),  # no XLA_THREADS: XLA's own pool, one thread per core
    ("diagnose", {"NPROC": "3"}, "3"),  # the user's setting wins
])
def test_the_diagnose_command_runs_xla_on_one_thread_and_others_keep_the_pool(command, env, threads):
    """The command line sizes XLA's CPU pool before the backend starts, for ``diagnose``
    only (its module's ``XLA_THREADS``), never over the user's ``NPROC``; the pool's threads
    are counted inside the command, after a computation (a check that this jaxlib reads
    ``PJRT_NPROC``), and ``PJRT_NPROC`` is gone from the environment after ``main()``."""
    module = {"diagnose": "fitting.commands.diagnose", "check": "cstiffjax.commands.check"}[command]
    code = (f"import os, importlib, jax.numpy as jnp; m = importlib.import_module({module!r})\n"
            f"def run(args):\n    jnp.ones(3).sum().block_until_ready(); {_POOL}; print('pool', n)\n"
            f"m.run = run\nfrom cstiffjax.commands.cli import main; main([{command!r}])\n"
            "print(os.environ.get('PJRT_NPROC'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True,
                         env={**{k: v for k, v in os.environ.items() if k not in C.THREADS_ENV},
                              "JAX_PLATFORMS": "cpu", **env}).stdout.split()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert out == ["pool", threads or str(cores), "None"]
