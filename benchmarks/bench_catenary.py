"""Benchmark: vmapped elastic catenary solves (vs MoorPy) and sagging forward statics.

Run: ``python benchmarks/bench_catenary.py [--n 100000] [--moorpy-n 300] [--poses 16]``.

(1) ``n`` random catenary cases over the whole supported range (spans 1 m..1 km, EA
1e3..1e9 N, w 1e-4..1e3 N/m, taut and slack, B above and below A); the end forces are
chosen and the spans computed in 40-digit mpmath, so the chosen forces are the reference.
cstiffjax solves all of them in one vmapped call (time after compile); MoorPy's
``catenary()`` (pip install moorpy, the ``bench`` extra) solves the first ``moorpy-n``
(it is a Python loop; its throughput is extrapolated per solve) with ``Tol=1e-10`` and
no seabed (``CB=-1e9``). Accuracy: max |force error| / max end tension.
(2) forward statics of the 6-cable sagging prototype (Yuan et al. 2015, 8 mm) vmapped over poses
(ideal lengths of each pose, cold start at that pose, :func:`cstiffjax.statics.forward.forward_statics`).
"""

import argparse
import time

import jax
import jax.numpy as jnp
import mpmath as mp
import numpy as np

import cstiffjax
from cstiffjax.cable.catenary import catenary
from cstiffjax.cable.laws import CableLaw
from cstiffjax.core.status import Status
from cstiffjax.examples import example_path
from cstiffjax.statics.forward import StaticsProblem, forward_statics
from cstiffjax.statics.geometry import cable_lengths
from cstiffjax.statics.sag import workspace_grid

mp.mp.dps = 40


def _spans(H, VB, L, EA, w):
    H, VB, L, EA, w = map(mp.mpf, (H, VB, L, EA, w))
    VA = VB - w * L
    x = H * L / EA + (H / w) * (mp.asinh(VB / H) - mp.asinh(VA / H))
    z = (VA * L + w * L**2 / 2) / EA + (mp.sqrt(H**2 + VB**2) - mp.sqrt(H**2 + VA**2)) / w
    return float(x), float(z)


def _sag(H, VB, L, EA, w, n=41):
    s = np.linspace(0, L, n)
    VA = VB - w * L
    V = VA + w * s
    x = H * s / EA + (H / w) * (np.arcsinh(V / H) - np.arcsinh(VA / H))
    z = (VA * s + w * s * s / 2) / EA + (np.hypot(H, V) - np.hypot(H, VA)) / w
    c = np.hypot(x[-1], z[-1])
    return np.max(np.abs(x * z[-1] - z * x[-1])) / c / c


def make_cases(n, seed=0):
    rng = np.random.default_rng(seed)
    rows = []
    while len(rows) < n:
        L, EA, w = 10 ** rng.uniform(0, 3), 10 ** rng.uniform(3, 9), 10 ** rng.uniform(-4, 3)
        th = np.radians(rng.uniform(-80, 80))
        if rng.uniform() < 0.5:
            T = 10 ** rng.uniform(-6, -2) * EA
            H, VB = T * np.cos(th), T * np.sin(th) + w * L / 2
        else:
            H = w * L / 10 ** rng.uniform(-3, np.log10(2.4))
            VB = H * np.tan(th) + rng.uniform(0, 1) * w * L
        VA = VB - w * L
        if max(np.hypot(H, VA), np.hypot(H, VB)) > 0.01 * EA or _sag(H, VB, L, EA, w) > 0.3:
            continue
        rows.append((H, VB, L, EA, w, *_spans(H, VB, L, EA, w)))
    return np.array(rows).T


def bench_catenary(n, n_moorpy):
    t0 = time.perf_counter()
    H, VB, L, EA, w, sx, sz = make_cases(n)
    print(f"generated {n} reference cases in {time.perf_counter() - t0:.1f} s (mpmath)")
    tmax = np.maximum(np.hypot(H, VB), np.hypot(H, VB - w * L))
    args = [jnp.asarray(a) for a in (sx, sz, L, EA, w)]
    sol = catenary(*args, throw=False)  # compile
    jax.block_until_ready(sol.H)
    times = []
    for _ in range(3):
        t = time.perf_counter()
        sol = catenary(*args, throw=False)
        jax.block_until_ready(sol.H)
        times.append(time.perf_counter() - t)
    dt = min(times)
    ok = np.asarray(sol.result == Status.successful)
    err = np.maximum(np.abs(np.asarray(sol.H) - H), np.abs(np.asarray(sol.V_B) - VB)) / tmax
    rows = [("cstiffjax (vmap, +stiffness_B)", n, n / dt, ok.sum(), np.max(err[ok]), np.median(err[ok]))]
    try:
        from moorpy.Catenary import catenary as mp_catenary
    except ImportError:
        print("MoorPy not importable (pip install moorpy, or the 'bench' extra): skipping the comparison")
        mp_catenary = None
    if mp_catenary is not None:
        import warnings

        errs, nok = [], 0
        t = time.perf_counter()
        for i in range(n_moorpy):
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    fAH, _fAV, _fBH, fBV, _ = mp_catenary(sx[i], sz[i], L[i], EA[i], w[i], CB=-1e9, Tol=1e-10,
                                                        MaxIter=200)
                errs.append(max(abs(fAH - H[i]), abs(-fBV - VB[i])) / tmax[i])
                nok += 1
            except Exception:
                errs.append(np.nan)
        dtm = time.perf_counter() - t
        errs = np.asarray(errs)
        rows.append((f"MoorPy catenary() (first {n_moorpy}, extrapolated)", n_moorpy, n_moorpy / dtm, nok,
                     np.nanmax(errs), np.nanmedian(errs)))
        sub = err[:n_moorpy][ok[:n_moorpy]]
        rows.append((f"cstiffjax on the same {n_moorpy}", n_moorpy, n / dt, ok[:n_moorpy].sum(), sub.max(),
                     np.median(sub)))
    print(f"\n{'solver':48s} {'cases':>7s} {'solves/s':>12s} {'ok':>7s} {'max err':>10s} {'median err':>10s}")
    for name, m, rate, k, emax, emed in rows:
        print(f"{name:48s} {m:7d} {rate:12.4g} {k:7d} {emax:10.2e} {emed:10.2e}")
    strain = tmax / EA
    well = strain >= 1e-6
    print(f"\ncstiffjax max err where strain >= 1e-6 ({well.sum()} cases): {np.max(err[ok & well]):.2e}; "
          f"below, the float64 spans fix the forces only to ~eps/strain")
    if mp_catenary is not None:
        wm = well[:n_moorpy]
        print(f"on the MoorPy subset with strain >= 1e-6 ({wm.sum()} cases): MoorPy max err {np.nanmax(errs[wm]):.2e}, "
              f"cstiffjax {np.max(err[:n_moorpy][wm]):.2e}; MoorPy errors > 1e-6: {(errs > 1e-6).sum()}")
        print(f"speed-up: {rows[0][2] / rows[1][2]:.0f}x (MoorPy per-solve rate extrapolated)")
    print("error = max(|dH|, |dV_B|) / max end tension vs the mpmath-constructed reference")


def bench_statics(n_side):
    r = cstiffjax.load_robot(example_path("prototype_8mm.toml"))
    poses = workspace_grid(np.linspace(-0.5, 0.5, n_side), np.linspace(-0.5, 0.5, n_side), 0.5).reshape(-1, 6)
    l0 = jax.vmap(lambda p: cable_lengths(r, p))(poses)

    @jax.jit
    def solve(l0, poses):
        return jax.vmap(lambda l, p: forward_statics(StaticsProblem(r, l, law=CableLaw.catenary), pose0=p,
                                                     throw=False))(l0, poses)

    t = time.perf_counter()
    out = solve(l0, poses)
    jax.block_until_ready(out.pose)
    tc = time.perf_counter() - t
    t = time.perf_counter()
    out = solve(l0, poses)
    jax.block_until_ready(out.pose)
    dt = time.perf_counter() - t
    ok = np.asarray(out.result == Status.successful)
    print(f"\nforward statics, 6 sagging cables (prototype_8mm), {len(poses)} poses vmapped: "
          f"{len(poses) / dt:.1f} solves/s after compile ({tc:.0f} s first call), {ok.sum()}/{len(poses)} converged, "
          f"max |residual| {np.max(np.abs(np.asarray(out.residual))):.2e} N")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--moorpy-n", type=int, default=300)
    ap.add_argument("--poses", type=int, default=8, help="grid points per axis for the statics benchmark")
    a = ap.parse_args()
    print(f"jax {jax.__version__}, devices {jax.devices()}")
    bench_catenary(a.n, a.moorpy_n)
    bench_statics(a.poses)


if __name__ == "__main__":
    main()
