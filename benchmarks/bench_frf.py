"""Benchmark: FRF of the 6-cable Yuan et al. 2015 prototype (8 mm sagging cables) on 2000 frequencies.

Prints a table: compile time, time per FRF sweep after compile, frequency evaluations per
second (one evaluation = 6 cable DSMs + 6x6 assembly + complex solve), and the cost of the
Wittrick-Williams natural-frequency search in 0-20 Hz. Run: ``python benchmarks/bench_frf.py``.
"""

import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from cstiffjax.dynamics import frf as dy
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.geometry import inverse_statics


def _timed(fn, repeats):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return out, first, float(np.median(times))


def main(n=2000, repeats=5):
    robot = load_robot(example_path("prototype_8mm.toml"))
    pose = jnp.array([3.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    t = inverse_statics(robot, pose).tensions
    st = dy.cable_statics_from_tensions(robot, pose, t)
    freqs = jnp.linspace(0.2, 20.0, n)
    rows = []
    X, first, med = _timed(lambda: dy.frf(robot, pose, st, freqs, 0.01), repeats)
    rows.append(("FRF, 2000 frequencies (jit, vmap)", first, med, n / med))
    assert np.all(np.isfinite(np.asarray(X)))
    xis = 0.01 * 0.77 / freqs  # Yuan et al.'s xi = 0.01 f_n / f, per frequency
    _, first, med = _timed(lambda: dy.frf(robot, pose, st, freqs, xis), repeats)
    rows.append(("FRF, frequency-dependent xi", first, med, n / med))
    nat, first, med = _timed(lambda: dy.natural_frequencies(robot, pose, st, 20.0, tol=1e-4), 2)
    rows.append((f"W-W natural frequencies 0-20 Hz ({nat.size} modes, 1e-4 Hz)", first, med, float("nan")))
    print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} x {jax.devices()[0].platform}, "
          f"jax {jax.__version__}")
    print(f"{'task':<58} {'1st call s':>10} {'after s':>10} {'eval/s':>12}")
    for name, a, b, c in rows:
        print(f"{name:<58} {a:>10.3f} {b:>10.4f} {c:>12.0f}")


if __name__ == "__main__":
    main()
