"""Stiffness K = -dW/dx of the 8-cable TCPR-8 with and without 2 cm swivel pulleys, side by side:
poses/s after compile. Targets: >= 5e5 poses/s with pulleys, >= 1e6 without.

Rows, each for the robot without pulleys and with pulleys on all 8 cables (vertical swivel axes):
  batch        cstiffjax.stiffness.matrix.stiffness on the whole (n, 6) batch: autodiff of the wrench along the
               cable path written pose-minor (css_kernel.lever_paths / spring_stiffness), chunks of BATCH
               split over all devices (one per core: XLA_FLAGS is set here unless given)
  vmapped      the same function vmapped over single poses (poses on the major axis)
  per pose     the per-pose autodiff through statics.cable_geometry (stiffness_from_lengths, vmapped): the
               only pulley-aware stiffness before the kernel saw pulleys

The machine is shared: every repeat times all rows in turn (interleaved), best of --repeat each, both
wall time and the process's CPU time (less distorted by other processes when one core is used).
Usage: python benchmarks/bench_pulley_stiffness.py [--n 32768] [--repeat 5]
"""

import argparse
import os
import time

os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={os.cpu_count()}")  # one device per core

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import cstiffjax  # noqa: F401  (float64)
from cstiffjax.cable.path import vertical_axes
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.stiffness.matrix import stiffness, stiffness_from_lengths, unstrained_lengths


def interleaved(fns, args, repeat):
    """Best wall and CPU time of each function, the functions timed in turn within every repeat."""
    for f in fns.values():
        jax.block_until_ready(f(*args))  # compile
    wall, cpu = dict.fromkeys(fns, np.inf), dict.fromkeys(fns, np.inf)
    for _ in range(repeat):
        for name, f in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            jax.block_until_ready(f(*args))
            wall[name] = min(wall[name], time.perf_counter() - t0)
            cpu[name] = min(cpu[name], time.process_time() - c0)
    return wall, cpu


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=32768)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    plain = load_robot(example_path("tcpr8.toml"))
    pul = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis), plain,
                      (jnp.full(8, 0.02), vertical_axes(plain.anchors)))
    rng = np.random.default_rng(0)
    n = a.n
    poses = jnp.asarray(np.column_stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.15, 0.15, n),
                                         rng.uniform(0.6, 1.1, n), rng.uniform(-0.05, 0.05, (n, 3))]))
    t = jnp.asarray(rng.uniform(100.0, 300.0, (n, 8)))
    fns = {}
    for label, robot in (("no pulleys", plain), ("pulleys r = 2 cm", pul)):
        fns[(label, "batch")] = jax.jit(lambda p, t, robot=robot: stiffness(robot, p, t).K)
        fns[(label, "vmapped")] = jax.jit(jax.vmap(lambda p, t, robot=robot: stiffness(robot, p, t).K))
        fns[(label, "per pose (statics)")] = jax.jit(jax.vmap(
            lambda p, t, robot=robot: stiffness_from_lengths(robot, p, unstrained_lengths(robot, p, t))))
    k = 256
    for label in ("no pulleys", "pulleys r = 2 cm"):
        ref = np.asarray(fns[(label, "per pose (statics)")](poses[:k], t[:k]))
        for row in ("batch", "vmapped"):
            err = np.abs(np.asarray(fns[(label, row)](poses[:k], t[:k])) - ref).max() / np.abs(ref).max()
            assert err < 1e-12, (label, row, err)
    load0 = os.getloadavg()[0]
    wall, cpu = interleaved(fns, (poses, t), a.repeat)
    print(f"stiffness K, TCPR-8, {n} poses; {os.cpu_count()} CPUs; load average {load0:.1f} before, "
          f"{os.getloadavg()[0]:.1f} after; all rows agree to 1e-12 relative")
    print(f"{'robot':18s} {'path':22s} {'poses/s (wall)':>15s} {'poses/CPU-s':>12s}")
    for (label, row), w in wall.items():
        print(f"{label:18s} {row:22s} {n / w:15.3e} {n / cpu[(label, row)]:12.3e}")
    print("targets: >= 1e6 poses/s without pulleys, >= 5e5 with (batch, quiet machine)")


if __name__ == "__main__":
    main()
