"""Stiffness K of the 8-cable TCPR-8-like robot: poses/s after compile, side by side.

Rows:
  jax autodiff   cstiffjax.stiffness.matrix.stiffness on the whole (n, 6) batch: forward-mode autodiff (linearize once,
                 6 twist directions) of the wrench written for a pose-minor batch (css_kernel.spring_stiffness),
                 chunks of 64 split over all devices (one per core, XLA_FLAGS set here unless given), the
                 status in chunks of up to 16 x 64; beside it the same kernel as it was called before
                 (status by pose_status vmapped per pose, chunks of 64, one device); also vmapped over single
                 poses, and the former per-pose twist_jacobian path (stiffness_from_lengths), vmapped
  jax split      cstiffjax.stiffness.matrix.stiffness_split (K1 by autodiff of S T, K2 closed form), vmapped
  jax closed     cstiffjax.stiffness.css.stiffness_contractions (closed-form outer products, affine in T), vmapped
                 (also in lax.map batches of 1024 poses, which keeps the intermediates in cache)
  numpy loop     per-pose NumPy closed form written here: K1 = -sum t_i d[u_i; r_i x u_i]/dx, K2 = S diag(k) S^T

All rows compute the same spring-law K (checked against each other before timing). The machine is
shared: every repeat times all rows one after the other (interleaved), best of --repeat each, wall time
and the process's CPU time (less distorted by other processes where one core is used).
Usage: python benchmarks/bench_stiffness.py [--n 32768] [--n-numpy 2000] [--repeat 3]
"""

import argparse
import os
import time

os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={os.cpu_count()}")  # one device per core

import jax
import jax.numpy as jnp
import numpy as np

import cstiffjax  # noqa: F401  (float64)
from cstiffjax.core.status import to_codes
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.stiffness import kernel as css_kernel
from cstiffjax.stiffness.css import stiffness_contractions
from cstiffjax.stiffness.matrix import (
    pose_status,
    stiffness,
    stiffness_from_lengths,
    stiffness_split,
    unstrained_lengths,
)


def hat(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def rotvec_to_matrix(w):
    th = np.linalg.norm(w)
    if th < 1e-12:
        return np.eye(3) + hat(w)
    k = hat(w / th)
    return np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * k @ k


def numpy_stiffness(anchors, attach, EA, weight, com, pose, t):
    """Closed form, one pose: K1 = -Σ t_i ∂[u_i; r_i×u_i]/∂x (twist coordinates), spring-law K2."""
    p, R = pose[:3], rotvec_to_matrix(pose[3:])
    K = np.zeros((6, 6))
    for a, b, ea, ti in zip(anchors, attach, EA, t):
        r = R @ b
        d = a - p - r
        l = np.linalg.norm(d)
        u = d / l
        G = np.hstack([np.eye(3), -hat(r)])            # ∂(attachment)/∂x
        du = -(np.eye(3) - np.outer(u, u)) @ G / l      # ∂u/∂x
        dm = hat(r) @ du + np.hstack([np.zeros((3, 3)), hat(u) @ hat(r)])  # ∂(r×u)/∂x
        K -= ti * np.vstack([du, dm])                   # K1
        s = np.concatenate([u, np.cross(r, u)])
        K += (ea + ti) / l * np.outer(s, s)             # K2, EA/l0 = (EA + t)/l
    K[3:, 3:] -= hat(weight) @ hat(R @ com)             # gravity
    return K


def interleaved_rates(fns, args, repeat):
    """Best wall and CPU time of each function, the functions timed in turn within every repeat."""
    for f in fns.values():
        jax.block_until_ready(f(*args))  # compile
    best, cpu = dict.fromkeys(fns, np.inf), dict.fromkeys(fns, np.inf)
    for _ in range(repeat):
        for name, f in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            jax.block_until_ready(f(*args))
            best[name] = min(best[name], time.perf_counter() - t0)
            cpu[name] = min(cpu[name], time.process_time() - c0)
    return best, cpu


def stiffness_before(robot, pose, tensions, bs=64):
    """``stiffness`` as it was before this benchmark's last change (same kernel): the status by
    ``pose_status`` vmapped over single poses, chunks of 64 poses."""
    codes = jax.vmap(lambda p, t: to_codes(pose_status(robot, p, t)))(pose, tensions)
    n = pose.shape[0]
    nc = -(-n // bs)
    P = jnp.concatenate([pose, jnp.broadcast_to(pose[:1], (nc * bs - n, 6))])
    T = jnp.concatenate([tensions, jnp.broadcast_to(tensions[:1], (nc * bs - n, tensions.shape[1]))])
    chunks = (jnp.moveaxis(P.reshape(nc, bs, 6), 2, 1), jnp.moveaxis(T.reshape(nc, bs, -1), 2, 1))
    K = jax.lax.map(lambda pt: css_kernel.spring_stiffness(robot, pt[0], pt[1], 1), chunks)
    return jnp.moveaxis(K, 3, 1).reshape(nc * bs, 6, 6)[:n], codes


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=32768)
    ap.add_argument("--n-numpy", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    robot = load_robot(example_path("tcpr8.toml"))
    rng = np.random.default_rng(0)
    n = a.n
    poses = np.column_stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.15, 0.15, n), rng.uniform(0.6, 1.1, n),
                             rng.uniform(-0.05, 0.05, (n, 3))])
    tens = rng.uniform(50, 350, (n, 8))
    P, Tn = jnp.asarray(poses), jnp.asarray(tens)

    def closed(p, t):
        K0, KL = stiffness_contractions(robot, p, t[:, None])
        return K0 + KL[0]

    impls = {
        "jax autodiff (stiffness, batch)": jax.jit(lambda p, t: stiffness(robot, p, t).K),
        "jax autodiff batch, before": jax.jit(lambda p, t: stiffness_before(robot, p, t)[0]),
        "jax autodiff (stiffness), vmapped": jax.jit(jax.vmap(lambda p, t: stiffness(robot, p, t).K)),
        "jax autodiff, former twist_jacobian path": jax.jit(jax.vmap(
            lambda p, t: stiffness_from_lengths(robot, p, unstrained_lengths(robot, p, t)))),
        "jax split (stiffness_split)": jax.jit(jax.vmap(lambda p, t: stiffness_split(robot, p, t).K)),
        "jax closed (stiffness_contractions)": jax.jit(jax.vmap(closed)),
        "jax closed, lax.map batches of 1024": jax.jit(
            lambda p, t: jax.lax.map(lambda pt: closed(*pt), (p, t), batch_size=1024)),
    }
    args = (np.asarray(robot.anchors), np.asarray(robot.attachments), np.asarray(robot.EA),
            np.asarray(robot.weight), np.asarray(robot.com))
    k = min(200, n)
    ref = np.stack([numpy_stiffness(*args, poses[i], tens[i]) for i in range(k)])
    rows = []
    load0 = os.getloadavg()[0]
    best, cpu = interleaved_rates(impls, (P, Tn), a.repeat)
    for name, f in impls.items():
        err = float(np.max(np.abs(np.asarray(f(P[:k], Tn[:k])) - ref)))
        rows.append((name, n, best[name], n / best[name], n / cpu[name], err))
    m = min(a.n_numpy, n)
    t0 = time.perf_counter()
    for i in range(m):
        numpy_stiffness(*args, poses[i], tens[i])
    dt = time.perf_counter() - t0
    rows.append(("numpy closed form, per-pose loop", m, dt, m / dt, np.nan, 0.0))
    print(f"stiffness K of the 8-cable robot; {os.cpu_count()} CPUs, devices {jax.devices()}, load avg "
          f"{load0:.1f} before the timings, {os.getloadavg()[0]:.1f} after")
    print(f"{'implementation':40s} {'poses':>8s} {'time [s]':>10s} {'poses/s':>12s} {'poses/CPU-s':>12s} "
          f"{'max |K - K_numpy|':>18s}")
    for name, nn, dt, r, rc, err in rows:
        print(f"{name:40s} {nn:8d} {dt:10.4f} {r:12.4g} {rc:12.4g} {err:18.3g}")
    closed = best["jax closed (stiffness_contractions)"]
    new = best["jax autodiff (stiffness, batch)"]
    print(f"ratio autodiff batch / closed form (vmapped): {closed / new:.2f}; "
          f"autodiff batch now / before: {best['jax autodiff batch, before'] / new:.2f}")
    print("target: >= 1e6 poses/s (autodiff)")


if __name__ == "__main__":
    main()
