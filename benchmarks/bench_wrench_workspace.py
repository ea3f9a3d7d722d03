"""Wrench-feasible workspace and tension distribution benchmarks (8-cable TCPR-8 robot).

1. Membership throughput after compile: the pose-minor kernel as
   ``workspace.sweep(vectorized=True)`` runs it (``lax.map`` over ``--batch-size`` batches),
   on one device and sharded over all devices (one per core; ``--one-device`` skips
   that), over ``--poses`` random poses (wall time and the process's CPU time, all
   threads, per call), side by side with a
   per-pose LP baseline (scipy linprog, one LP per extreme wrench of the box) on
   ``--lp-poses`` of them (agreement checked).
2. A ``--sweep-poses`` grid sweep (default 1e7) folded on the device (count, margin sum):
   bounded memory; peak RSS reported.
3. Tension continuity along a ``--trajectory``-pose straight line: for each method the
   largest jump of any tension between neighbouring poses, and the successful share.

Quick mode (``--quick``: 1e6-pose sweep) runs in about a minute on a quiet 2-core CPU.
"""

import argparse
import os
import resource
import time

os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={os.cpu_count()}")  # one device per core

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from scipy.optimize import linprog

from cstiffjax.core.status import Status
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics import geometry as statics
from cstiffjax.stiffness.tension_methods import distribute_tensions
from cstiffjax.workspace.sweep import Grid, sweep
from cstiffjax.workspace.wrench_feasible import WrenchSet, wrench_feasible

BOX = WrenchSet.box(-np.r_[5, 5, 5, 0.5, 0.5, 0.5], np.r_[5, 5, 5, 0.5, 0.5, 0.5])


def lp_member(robot, pose, ws):
    S = np.asarray(statics.structure_matrix_closed_form(robot, pose))
    Wg = np.asarray(statics.gravity_wrench(robot, pose))
    m = S.shape[1]
    for w in ws.extreme_points():
        res = linprog(np.zeros(m), A_eq=S, b_eq=-(w + Wg), bounds=[(float(robot.tension_min),
                      float(robot.tension_max))] * m, method="highs")
        if res.status != 0:
            return False
    return True


def _timed(kernel, X, reps=3):
    """``(wall seconds per call after compile, CPU seconds per call (this process, all threads),
    first call incl. compile, outputs)``."""
    t0 = time.perf_counter()
    jax.block_until_ready(kernel(X))
    first = time.perf_counter() - t0
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in range(reps):
        res = jax.block_until_ready(kernel(X))
    return (time.perf_counter() - t0) / reps, (time.process_time() - c0) / reps, first, res


def throughput(robot, n, lp_n, rng, bs, devices):
    P = np.column_stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.4, 0.4, n), rng.uniform(0.2, 1.6, n),
                         rng.uniform(-0.1, 0.1, (n, 3))])

    def fn(X):
        r = wrench_feasible(robot, X, BOX)
        return {"member": r.member, "margin": r.margin}

    def local(X):  # what sweep(vectorized=True, batch_size=bs) runs per device: lax.map over (6, bs) batches
        return jax.lax.map(fn, X.reshape(6, -1, bs).transpose(1, 0, 2))

    # (the kernel alone, jitted here: the sweep's own chunk program is timed in big_sweep)
    ndev = len(devices)
    n = n // (bs * ndev) * bs * ndev
    P = P[:n]
    X = jnp.asarray(P.T)
    dt, cpu, first, res = _timed(jax.jit(local), X)
    member = np.asarray(res["member"]).ravel()
    print(f"membership (one device, batches of {bs}): {n} poses in {dt:.3f} s after compile -> {n / dt:.3g} poses/s "
          f"[{n / cpu:.3g} per CPU-s] (first call incl. compile {first:.1f} s); members {member.mean():.3f}; "
          f"load {os.getloadavg()[0]:.2f}")
    if ndev > 1:  # the same kernel sharded over all devices, as sweep(vectorized=True) runs it
        mesh = Mesh(np.array(devices), ("poses",))
        Xs = jax.device_put(X, NamedSharding(mesh, PartitionSpec(None, "poses")))
        sharded = jax.jit(jax.shard_map(local, mesh=mesh, in_specs=PartitionSpec(None, "poses"),
                                        out_specs=PartitionSpec("poses"), check_vma=False))
        dt2, cpu2, first2, res2 = _timed(sharded, Xs)
        same = np.array_equal(np.asarray(res2["member"]).ravel(), member)
        print(f"membership ({ndev} devices, shard_map, batches of {bs}): {n} poses in {dt2:.3f} s after compile -> "
              f"{n / dt2:.3g} poses/s [{n / cpu2:.3g} per CPU-s] (first call incl. compile {first2:.1f} s); "
              f"same members as one device: {same}; "
              f"load {os.getloadavg()[0]:.2f}")
    t0 = time.perf_counter()
    ref = [lp_member(robot, P[k], BOX) for k in range(lp_n)]
    dl = time.perf_counter() - t0
    agree = int(np.sum(np.array(ref) == member[:lp_n]))
    print(f"LP baseline (linprog, {len(BOX.extreme_points())} LPs per pose): {lp_n} poses in {dl:.2f} s -> "
          f"{lp_n / dl:.3g} poses/s; agreement {agree}/{lp_n}; speed-up (one device) {n / dt / (lp_n / dl):.3g}x")


def big_sweep(robot, total, bs):
    k = round(total ** (1 / 3))
    grid = Grid.regular((-0.6, 0.6, k), (-0.4, 0.4, k), (0.2, 1.6, max(1, total // (k * k))))

    def fn(X):
        r = wrench_feasible(robot, X, BOX)
        return {"member": r.member, "margin": jnp.where(r.member, r.margin, 0.0),
                "volume": grid.point_volume(X[:3])}

    def fold(acc, o, valid):
        mem = o["member"] & valid
        return acc[0] + jnp.sum(mem), acc[1] + jnp.sum(jnp.where(mem, o["margin"], 0.0)), \
            acc[2] + jnp.sum(jnp.where(mem, o["volume"], 0.0))

    t0 = time.perf_counter()
    count, msum, volume = sweep(fn, grid, chunk_size=1 << 20, batch_size=bs, vectorized=True, reduce=fold,
                                init=(jnp.array(0), jnp.array(0.0), jnp.array(0.0)), progress=True,
                                desc="wrench-feasible")
    dt = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"sweep: {len(grid)} poses in {dt:.1f} s ({len(grid) / dt:.3g} poses/s incl. compile), "
          f"volume {float(volume):.4g} m^3, mean margin {float(msum) / max(int(count), 1):.3g} N; "
          f"peak RSS {rss:.0f} MiB")


def continuity(robot, n):
    s = np.linspace(0, 1, n)[:, None]
    P = np.array([-0.45, -0.25, 0.4, 0, 0, -0.1]) * (1 - s) + np.array([0.45, 0.25, 1.4, 0.05, 0.05, 0.1]) * s
    ext = jnp.array([40.0, -30.0, -60.0, 2.0, 0.0, 1.0])
    print(f"tension continuity along a {n}-pose line, load {np.asarray(ext).tolist()}:")
    for method, obj in (("cfm", "2-norm"), ("icfm", "2-norm"), ("dykstra", "2-norm"), ("qp", "2-norm"),
                        ("qp", "max")):
        f = jax.jit(jax.vmap(lambda p, method=method, obj=obj: distribute_tensions(
            robot, p, ext, method=method, objective=obj, throw=False)))
        t0 = time.perf_counter()
        out = f(jnp.asarray(P))
        t = np.asarray(out.tensions)
        ok = np.asarray(out.result == Status.successful)
        both = ok[1:] & ok[:-1]
        jump = np.max(np.abs(np.diff(t, axis=0))[both]) if both.any() else np.nan
        print(f"  {method:8s} {obj:7s} successful {ok.sum():3d}/{n}, max jump {jump:8.3f} N "
              f"(between successful neighbours), {time.perf_counter() - t0:.1f} s incl. compile")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, default=1 << 18)
    ap.add_argument("--lp-poses", type=int, default=20)
    ap.add_argument("--sweep-poses", type=int, default=10_000_000)
    ap.add_argument("--trajectory", type=int, default=200)
    ap.add_argument("--quick", action="store_true", help="1e6-pose sweep")
    ap.add_argument("--batch-size", type=int, default=64, help="poses per lax.map step on a device")
    ap.add_argument("--one-device", action="store_true", help="throughput on one device only (default: also "
                    "sharded over all devices, as the sweep runs)")
    ap.add_argument("--skip", nargs="*", default=(), choices=("throughput", "sweep", "continuity"))
    args = ap.parse_args()
    robot = load_robot(example_path("tcpr8.toml"))
    rng = np.random.default_rng(0)
    print(f"robot {robot.name}, box wrench set +-5 N, +-0.5 N·m; devices {jax.devices()}")
    if "throughput" not in args.skip:
        devices = jax.devices()[:1] if args.one_device else jax.devices()
        throughput(robot, args.poses, args.lp_poses, rng, args.batch_size, devices)
    if "sweep" not in args.skip:
        big_sweep(robot, 1_000_000 if args.quick else args.sweep_poses, args.batch_size)
    if "continuity" not in args.skip:
        continuity(robot, args.trajectory)


if __name__ == "__main__":
    main()
