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
