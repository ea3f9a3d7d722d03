"""Every CPU core for the command line (cstiffjax.devices) and programs split over devices
(cstiffjax.programs.Program ``split``): the split gives the unsplit results, is compiled
once (ahead or at the call), serialized like any program, and is off with one device."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import pytest

from cstiffjax import devices

ROOT = Path(__file__).resolve().parents[1]


def _env(**extra):
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_NUM_CPU_DEVICES", "XLA_FLAGS")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    return {**env, **extra}


def _run(code, **extra):
    out = subprocess.run([sys.executable, "-c", code], env=_env(**extra), capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout.strip().splitlines()


@pytest.mark.parametrize("count, want", [(1, 1), (2, 2), (3, 2), (4, 4), (5, 4), (12, 8), (16, 16), (64, 16)])
def test_the_split_count_is_the_largest_divisor_within_the_devices(monkeypatch, count, want):
    monkeypatch.setattr(jax, "local_devices", lambda: list(range(count)))
    assert devices.split_count(16) == want
    assert devices.split_count(1) == 1 and devices.split_count(7) == (7 if count >= 7 else 1)


def test_one_device_or_several_processes_never_split(monkeypatch):
    assert devices.split_count(16) == len(jax.local_devices()) == 1  # the test process: one device
    monkeypatch.setattr(jax, "local_devices", lambda: [0, 1])
    monkeypatch.setattr(jax, "process_count", lambda: 2)
    assert devices.split_count(16) == 1


def test_the_users_device_count_is_kept_and_a_running_backend_is_left_alone():
    jax.devices()  # the backend runs in this process
    before = jax.config.jax_num_cpu_devices
    assert devices.use_cpu_cores({"JAX_NUM_CPU_DEVICES": "1"}) is None
    assert devices.use_cpu_cores({"XLA_FLAGS": "--xla_force_host_platform_device_count=3"}) is None
    assert devices.use_cpu_cores({}) is None  # too late: the count cannot change any more
    assert jax.config.jax_num_cpu_devices == before


def test_the_console_script_gets_one_device_per_core():
    code = ("from cstiffjax.devices import cores, use_cpu_cores\nn = use_cpu_cores()\nimport jax\n"
            "print(n, len(jax.devices()), cores())")
    n, got, cores = _run(code)[-1].split()
    want = int(cores) if int(cores) >= 2 else 1
    assert int(got) == want and n == (str(want) if want > 1 else "None")
    assert _run(code, JAX_NUM_CPU_DEVICES="1")[-1].split()[:2] == ["None", "1"]
    entry = (ROOT / "pyproject.toml").read_text()
    assert 'cstiffjax = "cstiffjax.cli:entry"' in entry  # the console script is the entry with the devices


_SPLIT = """
import os, sys
import jax, jax.numpy as jnp, numpy as np, equinox as eqx
jax.config.update("jax_num_cpu_devices", 2)
from cstiffjax import programs, devices
programs._COVERED = programs._COVERED | {"__main__"}  # this script's code may be serialized here

class Gain(eqx.Module):
    k: jax.Array

def f(mod, thetas, data):
    # a per-row program with a reduction inside each row: the split must not change it
    return jnp.tanh(thetas @ data * mod.k), jnp.sum(thetas ** 2, axis=1) > 1.0

import logging
compiles = []  # compilations of a program (jit(call): exported; jit(flat): traced for export)
class Count(logging.Handler):
    def emit(self, record):
        msg = record.getMessage()
        if msg.startswith(("Finished XLA compilation of jit(call)", "Finished XLA compilation of jit(flat)")):
            compiles.append(msg)
logging.getLogger("jax").addHandler(Count())
jax.config.update("jax_log_compiles", True)
mod, data = Gain(jnp.asarray(0.7, dtype=jnp.float64)), jnp.asarray(np.random.default_rng(0).standard_normal((5, 3)))
X = np.random.default_rng(1).standard_normal((16, 5))
want = jax.jit(f)(mod, jnp.asarray(X), data)
assert devices.split_count(16) == 2
for folder in (None, sys.argv[1]):
    programs.set_folder(folder)
    for fresh in (True, False):  # a new process's view, then this one's memory
        if fresh:
            programs._MEMO.clear(); programs._KEYS.clear(); programs._OUTPUTS.clear()
        prog = programs.Program(f, name="split_test", split=1)
        prog.lower(mod, jnp.zeros((16, 5)), data).compile()
        before = len(compiles)
        got = prog(mod, jnp.asarray(X), data)
        g = prog.bind(mod, jnp.zeros((16, 5)), data, vary=1)
        got2 = g(X)
        assert len(compiles) == before, (folder, fresh, compiles[before:])  # compiled ahead: nothing more
        for a, b, c in zip(got, got2, want):
            assert len(a.sharding.device_set) == 2 and np.array_equal(np.asarray(a), np.asarray(c))
            assert np.array_equal(np.asarray(b), np.asarray(c))
        odd = prog(mod, jnp.asarray(X[:7]), data)  # 7 rows: not split (no divisor), same values
        want7 = jax.jit(f)(mod, jnp.asarray(X[:7]), data)
        assert len(odd[0].sharding.device_set) == 1 and np.array_equal(np.asarray(odd[0]), np.asarray(want7[0]))
files = [p for p in os.listdir(sys.argv[1]) if p.endswith(".jaxexport")]
assert len(files) == 2, files  # the split program and the 7-row one
print("ok")
"""


def test_a_split_program_gives_the_unsplit_results_and_compiles_once(tmp_path):
    """Two CPU devices (a fresh process): a ``split`` program runs half the rows on each,
    with the unsplit values bit for bit, compiled once when lowered ahead (also through
    ``bind``), serialized and loaded again like any program; a batch that does not divide
    stays on one device."""
    assert _run(_SPLIT.replace("sys.argv[1]", repr(str(tmp_path))))[-1] == "ok"


_WALKERS = """
import jax, numpy as np, jax.numpy as jnp
jax.config.update("jax_num_cpu_devices", 2)
from cstiffjax.examples import example_path
from cstiffjax.recordings import load_recordings
from cstiffjax.robot_io import load_robot
from fitting.effect_posterior import with_weight
from fitting.effects.model import walker_residuals
from fitting.fitter import Fitter
from fitting.effects import VOCABULARY
robot = load_robot(example_path("concealed/robot.toml"))
rec = load_recordings(example_path("concealed/recordings.csv"), robot)
f = Fitter(robot, rec, "spring", tuple(e for e in VOCABULARY if e.name == "exit_friction"))
m, data = f.models["base"], with_weight(f.data, np.ones(f.n))
X = np.tile(np.asarray(m.start), (16, 1)) + 0.02 * np.random.default_rng(2).standard_normal((16, m.size))
r2, ok2 = walker_residuals(m, jnp.asarray(X), f.robot, data, None)
r1, ok1 = walker_residuals.jitted(m, jnp.asarray(X), f.robot, data, None)  # one device: the plain program
assert len(r2.sharding.device_set) == 2 and np.array_equal(np.asarray(ok1), np.asarray(ok2))
err = float(np.max(np.abs(np.asarray(r2) - np.asarray(r1))))
assert err < 1e-8, err
print("ok", err)
"""


@pytest.mark.slow  # a fresh process compiling the walker program twice (~15 s)
def test_the_posterior_walkers_split_over_two_devices_agree_with_one():
    """The diagnosis's walker program split over two CPU devices: every walker's whitened
    residuals agree with the one-device program to the equilibrium solver's tolerance (each
    device's batched Newton loop stops when *its* walkers have converged, so a sample may take
    one step more or less: measured 7e-10 on the bundled example), and the same samples fail."""
    assert _run(_WALKERS)[-1].startswith("ok")
