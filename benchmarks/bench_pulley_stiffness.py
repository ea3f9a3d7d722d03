"""Stiffness K = -dW/dx of the 8-cable TCPR-8 with and without 2 cm swivel pulleys:
poses/s after compile (cstiffjax.stiffness.stiffness, autodiff through the cable path of
cstiffjax.pulley, vmapped over poses). Target (issue 14): >= 5e5 poses/s with pulleys.

Usage: python benchmarks/bench_pulley_stiffness.py [--n 32768] [--repeat 3]
"""

import argparse
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import cstiffjax  # noqa: F401  (float64)
from cstiffjax.examples import example_path
from cstiffjax.pulley import vertical_axes
from cstiffjax.robot_io import load_robot
from cstiffjax.stiffness import stiffness


def rate(fn, args, repeat):
    jax.block_until_ready(fn(*args))  # compile
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=32768)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    plain = load_robot(example_path("tcpr8.toml"))
    pul = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis), plain,
                      (jnp.full(8, 0.02), vertical_axes(plain.anchors)))
    rng = np.random.default_rng(0)
    n = a.n
    poses = jnp.asarray(np.column_stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.15, 0.15, n),
                                         rng.uniform(0.6, 1.1, n), rng.uniform(-0.05, 0.05, (n, 3))]))
    t = jnp.asarray(rng.uniform(100.0, 300.0, (n, 8)))
    fn = jax.jit(jax.vmap(stiffness, in_axes=(None, 0, 0)))
    for label, robot in (("no pulleys", plain), ("pulleys r = 2 cm", pul)):
        dt = rate(fn, (robot, poses, t), a.repeat)
        print(f"{label:18s} {n / dt:12.3e} poses/s  ({n} poses in {dt * 1e3:.1f} ms)")


if __name__ == "__main__":
    main()
