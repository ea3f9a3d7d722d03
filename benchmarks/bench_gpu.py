"""Every batched entry point in one process, sized for the device: throughput and the device's limits.

    python benchmarks/bench_gpu.py [--scale 1.0] [--repeat 3] [--only css feasible ...] [--json out.json]

Rows (each: the first call, compile included, then the best of ``--repeat`` warm calls):

  stiffness            cstiffjax.stiffness.matrix.stiffness on an (n, 6) pose batch, TCPR-8
  stiffness, pulleys   the same with 2 cm swivel pulleys on all 8 cables
  css sweep            CSS membership (css_point's pose-minor form) over a grid of the frame,
                       workspace.sweep with a fold (count, sum of mu) on the devices
  wrench-feasible      wrench_feasible (box +-5 N, +-0.5 N m) over a grid, sweep + fold
  wrench-closure       wrench_closure over a grid, sweep + fold
  interference         interference (straight cables, per pose under vmap) over a grid, sweep + fold
  catenary             catenary() on n random cases (spans from the closed form, both taut and slack)
  forward statics      forward_statics (catenary law) vmapped over a pose batch, 6-cable prototype
  diagnosis            fitting's diagnose() of the bundled example01 (cold: with compiles; warm),
                       without the discovery step (it runs to a time budget, not to an amount of work)

Sizes scale with the device: small on a CPU (the whole script runs in a few minutes on two
cores), 2^22-2^24 poses on a GPU or TPU (sweeps at the backend's default launch size,
workspace.sweep.launch_sizes). Beside each rate: XLA's own cost model of one item (flops and
bytes accessed of the kernel compiled for a small batch; loop bodies such as Newton
iterations are counted once, so those rows are lower bounds), the achieved GFLOP/s and GB/s
from it, and, for a known GPU, its physical limits (peak FP64 and memory bandwidth).
Prints a Markdown table and the run's facts (backend, device kind, driver, jax version,
date) and writes them as JSON.
"""

import os

os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={os.cpu_count()}")  # CPU: a device per core

import argparse
import datetime
import importlib.metadata
import json
import platform
import subprocess
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import cstiffjax  # noqa: F401  (float64)
from cstiffjax.cable.catenary import catenary
from cstiffjax.cable.laws import CableLaw
from cstiffjax.cable.path import vertical_axes
from cstiffjax.core.status import to_codes
from cstiffjax.examples import example_path
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.forward import StaticsProblem, forward_statics
from cstiffjax.statics.geometry import cable_lengths
from cstiffjax.stiffness import css
from cstiffjax.stiffness.matrix import stiffness
from cstiffjax.workspace.interference import interference, interference_model
from cstiffjax.workspace.sweep import Grid, sweep
from cstiffjax.workspace.wrench_closure import wrench_closure
from cstiffjax.workspace.wrench_feasible import WrenchSet, wrench_feasible

PEAKS = {  # device kind (substring) -> (peak FP64 FLOP/s, memory bandwidth B/s, note)
    "H200": (67e12, 4.8e12, "FP64 67 TFLOP/s with tensor cores (34 without), HBM3e 4.8 TB/s"),
    "H100": (67e12, 3.35e12, "SXM: FP64 67 TFLOP/s with tensor cores (34 without), HBM3 3.35 TB/s"),
    "A100": (19.5e12, 2.0e12, "FP64 19.5 TFLOP/s with tensor cores (9.7 without), HBM2e up to 2.0 TB/s"),
}
SIZES = {  # items per row: CPU / GPU or TPU
    "cpu": {"stiffness": 32768, "pulleys": 32768, "css": 2**18, "feasible": 2**18, "closure": 2**18,
            "interference": 16384, "catenary": 100_000, "statics": 16},
    "accelerator": {"stiffness": 2**22, "pulleys": 2**22, "css": 2**24, "feasible": 2**24, "closure": 2**24,
                    "interference": 2**21, "catenary": 2**22, "statics": 4096},
}
ROWS = ("stiffness", "pulleys", "css", "feasible", "closure", "interference", "catenary", "statics", "diagnosis")
POSE0 = jnp.array([0.0, 0.0, 0.83, 0.0, 0.0, 0.0])
BOX = WrenchSet.box(-np.r_[5, 5, 5, 0.5, 0.5, 0.5], np.r_[5, 5, 5, 0.5, 0.5, 0.5])


def device_facts():
    """Backend, device kind and count, driver / platform version, versions, date."""
    dev = jax.devices()[0]
    facts = {"backend": dev.platform, "device_kind": dev.device_kind, "devices": len(jax.devices()),
             "platform_version": getattr(dev.client, "platform_version", None), "jax": jax.__version__,
             "jaxlib": importlib.metadata.version("jaxlib"), "date": datetime.datetime.now(datetime.UTC).isoformat(
                 timespec="seconds"), "host_cpu": platform.processor() or platform.machine(),
             "cpu_count": os.cpu_count(), "driver": None}
    if dev.platform == "gpu":
        try:
            out = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                                 capture_output=True, text=True, timeout=20)
            facts["driver"] = out.stdout.strip().splitlines()[0] if out.returncode == 0 else None
        except (OSError, subprocess.SubprocessError, IndexError):
            pass
    try:
        with open("/proc/cpuinfo") as f:
            facts["host_cpu"] = next(x.split(":", 1)[1].strip() for x in f if x.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return facts


def peaks(device_kind):
    """``(FP64 FLOP/s, B/s, note)`` of a known device kind, else ``None``."""
    return next((v for k, v in PEAKS.items() if k.lower() in device_kind.lower()), None)


def cost_per_item(f, args, items):
    """XLA's cost model of ``jit(f)(*args)`` per item: ``(flops, bytes accessed)`` or ``(None, None)``."""
    try:
        cost = jax.jit(f).lower(*args).compile().cost_analysis()
        cost = cost[0] if isinstance(cost, list | tuple) else cost
        return float(cost["flops"]) / items, float(cost["bytes accessed"]) / items
    except Exception:  # the cost model is optional: not every backend gives it
        return None, None


def timed(call, repeat):
    """``(first call s, best warm call s)``; ``call`` must block until its result is ready."""
    t0 = time.perf_counter()
    call()
    first = time.perf_counter() - t0
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - t0)
    return first, best


def random_poses(rng, n, box=((-0.2, 0.2), (-0.15, 0.15), (0.6, 1.1)), tilt=0.05):
    return np.column_stack([rng.uniform(*box[0], n), rng.uniform(*box[1], n), rng.uniform(*box[2], n),
                            rng.uniform(-tilt, tilt, (n, 3))])


def grid_of(n, box=((-0.6, 0.6), (-0.4, 0.4), (0.2, 1.6))):
    k = max(round(n ** (1 / 3)), 2)
    return Grid.regular((*box[0], k), (*box[1], k), (*box[2], max(n // (k * k), 1)))


def fold_members(acc, out, valid):
    member = out["member"] & valid
    return acc[0] + jnp.sum(member), acc[1] + jnp.sum(jnp.where(member, out["margin"], 0.0))


INIT = (0, 0.0)


class Bench:
    """The rows, run one after the other in this process."""

    def __init__(self, sizes, repeat):
        self.sizes, self.repeat = sizes, repeat
        self.tcpr8 = load_robot(example_path("tcpr8.toml"))
        self.rng = np.random.default_rng(0)

    def _stiffness(self, robot, n):
        P, T = jnp.asarray(random_poses(self.rng, n)), jnp.asarray(self.rng.uniform(100.0, 300.0, (n, 8)))
        f = jax.jit(lambda p, t: stiffness(robot, p, t))
        first, best = timed(lambda: jax.block_until_ready(f(P, T)), self.repeat)
        return dict(items=n, unit="poses", first_s=first, best_s=best,
                    cost=cost_per_item(lambda p, t: stiffness(robot, p, t), (P[:64], T[:64]), 64))

    def stiffness(self):
        return self._stiffness(self.tcpr8, self.sizes["stiffness"])

    def pulleys(self):
        pul = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis), self.tcpr8,
                          (jnp.full(8, 0.02), vertical_axes(self.tcpr8.anchors)))
        return self._stiffness(pul, self.sizes["pulleys"])

    def _sweep(self, fn, n, vectorized, box=((-0.6, 0.6), (-0.4, 0.4), (0.2, 1.6)), cost_batch=64, **kw):
        g = grid_of(n, box)
        run = lambda: sweep(fn, g, vectorized=vectorized, reduce=fold_members, init=INIT, progress=False, **kw)  # noqa: E731
        first, best = timed(run, self.repeat)
        count, _ = run()
        P = jnp.asarray(random_poses(self.rng, cost_batch))
        cost = cost_per_item(fn, (P.T,), cost_batch) if vectorized else \
            cost_per_item(jax.vmap(fn), (P,), cost_batch)
        return dict(items=len(g), unit="poses", first_s=first, best_s=best, cost=cost,
                    note=f"{int(count)} members")

    def css(self):
        robot = self.tcpr8
        kc = css.target_stiffness(robot, POSE0).K

        def fn(P):
            out = css.css_point(robot, P, kc, 0.05)
            return {"member": out.member, "margin": out.stability}

        return self._sweep(fn, self.sizes["css"], True, ((-0.77, 0.77), (-0.516, 0.516), (0.0, 1.78)))

    def feasible(self):
        robot = self.tcpr8

        def fn(P):
            r = wrench_feasible(robot, P, BOX)
            return {"member": r.member, "margin": jnp.where(r.member, r.margin, 0.0)}

        return self._sweep(fn, self.sizes["feasible"], True)

    def closure(self):
        robot = self.tcpr8

        def fn(P):
            r = wrench_closure(robot, P)
            return {"member": r.member, "margin": jnp.where(r.member, r.margin, 0.0)}

        return self._sweep(fn, self.sizes["closure"], True)

    def interference(self):
        robot = self.tcpr8
        model = interference_model(robot, diameter=0.004)

        def fn(p):
            r = interference(robot, model, p)
            return {"member": r.free, "margin": r.margin}

        return self._sweep(fn, self.sizes["interference"], False)

    def catenary(self):
        n = self.sizes["catenary"]
        sx, sz, L, EA, w = (jnp.asarray(a) for a in catenary_cases(self.rng, n))
        first, best = timed(lambda: jax.block_until_ready(catenary(sx, sz, L, EA, w, throw=False).H), self.repeat)
        ok = int(np.sum(np.asarray(to_codes(catenary(sx, sz, L, EA, w, throw=False).result)) == 0))
        cost = cost_per_item(lambda *a: catenary(*a, throw=False).H, (sx[:64], sz[:64], L[:64], EA[:64], w[:64]), 64)
        return dict(items=n, unit="solves", first_s=first, best_s=best, cost=cost, note=f"{ok} converged",
                    lower_bound=True)

    def statics(self):
        robot = load_robot(example_path("prototype_8mm.toml"))
        n = self.sizes["statics"]
        k = max(round(n ** 0.5), 1)
        x, y = np.meshgrid(np.linspace(-0.5, 0.5, k), np.linspace(-0.5, 0.5, k))
        poses = jnp.asarray(np.column_stack([x.ravel(), y.ravel(), np.full(k * k, 0.5), np.zeros((k * k, 3))]))
        l0 = jax.vmap(lambda p: cable_lengths(robot, p))(poses)
        solve = jax.vmap(lambda l, p: forward_statics(StaticsProblem(robot, l, law=CableLaw.catenary), pose0=p,
                                                      throw=False))
        f = jax.jit(solve)
        first, best = timed(lambda: jax.block_until_ready(f(l0, poses).pose), self.repeat)
        ok = int(np.sum(np.asarray(to_codes(f(l0, poses).result)) == 0))
        cost = cost_per_item(lambda l, p: solve(l, p).pose, (l0[:1], poses[:1]), 1)
        return dict(items=k * k, unit="solves", first_s=first, best_s=best, cost=cost,
                    note=f"{ok} converged", lower_bound=True)

    def diagnosis(self):
        from fitting.diagnosis.diagnose import diagnose

        robot = load_robot(example_path("example01/robot.toml"))
        rec = load_recordings(example_path("example01/recordings.csv"), robot)
        t0 = time.perf_counter()
        d = diagnose(robot, rec, progress=False, discover=False)  # discovery runs to a time budget
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        diagnose(robot, rec, progress=False, discover=False)
        warm = time.perf_counter() - t0
        return dict(items=1, unit="diagnoses", first_s=first, best_s=warm, cost=(None, None),
                    note="found " + ("+".join(d.effects) or "none") + f", {len(rec.pose)} samples, discovery off")


def catenary_cases(rng, n):
    """``(span_x, span_z, L, EA, w)`` of ``n`` cables with chosen end forces (taut and slack,
    B above and below A; 1 m..1 km, EA 1e3..1e9 N, w 1e-4..1e3 N/m), the spans from the
    closed form (float64; :mod:`benchmarks.bench_catenary` builds them in 40 digits)."""
    L, EA, w = 10 ** rng.uniform(0, 3, n), 10 ** rng.uniform(3, 9, n), 10 ** rng.uniform(-4, 3, n)
    th = np.radians(rng.uniform(-80, 80, n))
    taut = rng.uniform(size=n) < 0.5
    T = 10 ** rng.uniform(-6, -2, n) * EA
    H = np.where(taut, T * np.cos(th), w * L / 10 ** rng.uniform(-3, np.log10(2.4), n))
    VB = np.where(taut, T * np.sin(th) + w * L / 2, H * np.tan(th) + rng.uniform(0, 1, n) * w * L)
    VA = VB - w * L
    x = H * L / EA + (H / w) * (np.arcsinh(VB / H) - np.arcsinh(VA / H))
    z = (VA * L + w * L**2 / 2) / EA + (np.hypot(H, VB) - np.hypot(H, VA)) / w
    return x, z, L, EA, w


def table(facts, rows):
    """The Markdown table (and the facts above it)."""
    pk = peaks(facts["device_kind"])
    lines = [f"backend **{facts['backend']}**, {facts['devices']} x {facts['device_kind']}, driver "
             f"{facts['driver'] or 'n/a'}, jax {facts['jax']} / jaxlib {facts['jaxlib']}, host CPU {facts['host_cpu']} "
             f"({facts['cpu_count']} cores), {facts['date']}", ""]
    if pk:
        lines += [f"device limits: {pk[2]}", ""]
    lines += ["| entry point | items | first call [s] | warm [s] | throughput | XLA model: GFLOP/s | GB/s | "
              "device limit | note |", "|---|---:|---:|---:|---:|---:|---:|---|---|"]
    for name, r in rows.items():
        rate = r["items"] / r["best_s"]
        flops, nbytes = r["cost"]
        ge = "≥ " if r.get("lower_bound") else ""
        gf = f"{ge}{rate * flops / 1e9:.3g}" if flops is not None else "n/a"
        gb = f"{ge}{rate * nbytes / 1e9:.3g}" if nbytes is not None else "n/a"
        limit = "n/a"
        if pk and flops is not None:
            limit = (f"{100 * rate * flops / pk[0]:.2g} % of FP64 peak, "
                     f"{100 * rate * nbytes / pk[1]:.2g} % of bandwidth")
        lines.append(f"| {name} | {r['items']} | {r['first_s']:.2f} | {r['best_s']:.4g} | "
                     f"{rate:.3g} {r['unit']}/s | {gf} | {gb} | {limit} | {r.get('note', '')} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scale", type=float, default=1.0, help="multiply every size (default 1)")
    ap.add_argument("--repeat", type=int, default=3, help="warm calls per row, best kept (default 3)")
    ap.add_argument("--only", nargs="*", choices=ROWS, default=ROWS, help="rows to run (default all)")
    ap.add_argument("--json", default="bench_gpu.json", help="where to write the results (default ./bench_gpu.json)")
    a = ap.parse_args(argv)
    facts = device_facts()
    sizes = {k: max(int(v * a.scale), 1) for k, v in
             SIZES["cpu" if facts["backend"] == "cpu" else "accelerator"].items()}
    bench = Bench(sizes, a.repeat)
    rows = {}
    labels = {"stiffness": "stiffness (pose batch)", "pulleys": "stiffness, 2 cm pulleys", "css": "CSS frame sweep",
              "feasible": "wrench-feasible sweep", "closure": "wrench-closure sweep",
              "interference": "interference sweep", "catenary": "catenary solves",
              "statics": "forward statics (catenary), pose batch", "diagnosis": "diagnosis of example01"}
    t0 = time.perf_counter()
    for key in a.only:
        rows[labels[key]] = getattr(bench, key)()
        r = rows[labels[key]]
        print(f"{labels[key]}: {r['items']} {r['unit']}, first {r['first_s']:.2f} s, warm {r['best_s']:.4g} s",
              flush=True)
    facts["total_s"] = time.perf_counter() - t0
    print()
    print(table(facts, rows))
    with open(a.json, "w") as f:
        json.dump({"facts": facts, "peaks": peaks(facts["device_kind"]), "rows": rows}, f, indent=1)
    print(f"\nwrote {a.json} ({facts['total_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
