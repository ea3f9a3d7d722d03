"""CSS membership (Cui et al. 2019) of the 8-cable TCPR-8-like robot: poses/s and a bounded-memory sweep.

One JAX CPU device per core (``XLA_FLAGS=--xla_force_host_platform_device_count=<cores>``,
set here unless XLA_FLAGS is given): workspace.sweep shards every chunk over them.

1. Throughput, near the CSS (the worst case: every batch needs the Fourier-Motzkin step):
   --n random poses around the reference pose, ~30% members. css.css_point in its
   pose-minor batch form through workspace.sweep (vectorized, batches of 64 per device),
   best of --repeat after compile; beside it, interleaved, the same kernel written out with K
   by autodiff (``css_kernel.membership_stiffness``, what ``css_point`` runs) and with K by
   the hand-derived contractions (the test reference; ``css_point``'s straight-cable form
   until it was replaced) and the one-pose form under vmap (the old path).
   Wall time and the load average are printed.
2. Sweep over the whole frame: a lazy Grid of --sweep-poses poses, folded into (count,
   volume, integral of mu) on the devices, so memory does not grow with the number of poses. Time, rate and
   peak RSS (ru_maxrss) after a 1/10 sweep and after the full one.

3. --reproduce: Cui et al. 2019 beside our reconstruction: eq. (26), Tables 5 and 8 (CSS volume and
   U for the load cases of Table 4 and postures of Table 7, on a --step grid over the frame,
   for the "scaled" and "max" criteria) and Tables 10-11 (pose change under 10 N at points of
   the two constant stiffness planes). Figures go to --figures.

Usage: python benchmarks/bench_css.py [--n 262144] [--sweep-poses 1e8 (0: skip)] [--chunk 1048576] [--no-vmap]
                                      [--frame-contractions]
       python benchmarks/bench_css.py --reproduce [--step 0.02] [--figures DIR]
"""

import os

os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={os.cpu_count()}")

import argparse
import resource
import time

import jax
import jax.numpy as jnp
import numpy as np

import cstiffjax  # noqa: F401  (float64)
from cstiffjax.core import lie
from cstiffjax.core.status import Status, select
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.plots import css as plots_css
from cstiffjax.stiffness import css
from cstiffjax.stiffness import kernel as css_kernel
from cstiffjax.stiffness.matrix import _rpy_matrix
from cstiffjax.workspace.sweep import Grid, sweep

POSE0 = jnp.array([0.0, 0.0, 0.83, 0.0, 0.0, 0.0])


def rss_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def grid_of(n):
    """The whole frame (x, y, z as in the Table 5 sweeps) with about n points (cubic-ish)."""
    k = max(round(n ** (1 / 3)), 2)
    return Grid.regular((-0.77, 0.77, k), (-0.516, 0.516, k), (0.0, 1.78, max(n // (k * k), 1)))


def batch_fn(robot, kc, eps=0.05, load=None, norm="scaled", inherent="spring"):
    """css_point in its pose-minor batch form, for sweep(..., vectorized=True)."""
    return lambda P: css.css_point(robot, P, kc, eps, load, norm=norm, inherent=inherent)


def contractions_fn(robot, kc, eps=0.05, inherent="spring", autodiff=False):
    """The batch form with an explicit choice of ``K0``, ``K_lin``: the hand-derived
    ``css_kernel.contractions`` (straight cables; what ``css_point`` runs without pulleys) or,
    ``autodiff``, ``css_kernel.membership_stiffness`` (what ``css_point`` runs)."""
    tol = css.tolerance(kc, eps, "scaled")

    def fn(P):
        R, r, u, l = css_kernel.geometry(robot, P, 1)
        tp, N, sing = css_kernel.null_space(css_kernel.structure_rows(r, u), css_kernel.load_wrench(robot, R, None, 1))
        V = jnp.concatenate([tp[:, None], N], axis=1)
        if autodiff:
            K0, KL = css_kernel.membership_stiffness(robot, P, V, inherent, 1)
        else:
            K0, KL = css_kernel.contractions(robot, R, r, u, l, V, inherent)
        ok, t, phi, mu, sing = css_kernel.membership_from_stiffness(robot, tp, N, sing, K0, KL, kc, tol)
        return css.CSSPoint(ok, t, phi, mu, select(sing, Status.singular, select(ok, Status.successful,
                                                                                   Status.infeasible)))

    return fn


EQ26 = np.diag([6055.06, 3226.71, 8379.21, 150.83, 177.17, 162.21])
EQ26[0, 4] = EQ26[4, 0] = -267.81
EQ26[1, 3] = EQ26[3, 1] = 137.46
TABLE5 = [(8.608e-3, 0.3292), (8.408e-3, 0.3225), (8.160e-3, 0.3160), (8.024e-3, 0.3136)]
TABLE8 = [(9.448e-3, 0.3418), (8.120e-3, 0.3548), (5.232e-3, 0.3614), (2.776e-3, 0.3782)]
LOAD1 = np.array([5.0, 5, 5, 0.5, 0.5, 0.5])


def css_over_frame(robot, kc, load, rotvec, step, norm):
    g = Grid.regular((-0.77, 0.77, round(1.54 / step) + 1), (-0.516, 0.516, round(1.032 / step) + 1),
                     (0.0, 1.78, round(1.78 / step) + 1), rotation=rotvec)
    w = None if load is None else jnp.asarray(load)
    out = sweep(batch_fn(robot, kc, 0.05, w, norm, "paper"), g, chunk_size=65536, batch_size=64,
                vectorized=True, progress=False)
    s = css.summarize(out.member.reshape(g.shape), out.stability.reshape(g.shape), g.point_volumes())
    return float(s.volume), float(s.stability), g, out


def reproduce(robot, step, figdir):
    target = css.target_stiffness(robot, POSE0, inherent="paper")
    K = np.asarray(target.K)
    nz = np.abs(EQ26) > 0
    print("eq. (26) vs ours (inherent='paper'): max relative difference on the 8 non-zero entries "
          f"{np.max(np.abs(K[nz] / EQ26[nz] - 1)):.2%}; largest |K| where eq. (26) is 0: {np.max(np.abs(K[~nz])):.1e}")
    print("Table 3 tensions [N]: paper 193.7 x4, 210.3 x4; ours", np.round(np.asarray(target.tensions), 2))
    print(f"psi (eq. 22): paper 0.362, ours {float(target.srcc):.3f}")
    kc1 = css.target_stiffness(robot, POSE0, jnp.asarray(LOAD1), inherent="paper")
    print("Table 6 tensions [N]: paper 192.4 189.9 190.8 182.2 222.1 208.1 213.1 212.4; ours",
          np.round(np.asarray(kc1.tensions), 1))
    for norm in ("scaled", "max"):
        print(f"\nTables 5 / 8, criterion '{norm}', grid step {step} m (paper: 1 mm)")
        print(f"{'case':28s} {'V paper [m3]':>12s} {'V ours [m3]':>12s} {'U paper':>8s} {'U ours':>8s}")
        vols, us, names = [], [], []
        for k in range(1, 5):
            v, u, g, out = css_over_frame(robot, target.K, LOAD1 * k, (0.0, 0.0, 0.0), step, norm)
            ref = TABLE5[k - 1]
            print(f"{f'Table 4 case {k} (load x{k})':28s} {ref[0]:12.4g} {v:12.4g} {ref[1]:8.4f} {u:8.4f}")
            vols.append(v), us.append(u), names.append(f"load {k}")
            if k == 1 and figdir:
                shp = g.shape
                plots_css.plot_css_3d(g.axes(), out.member.reshape(shp), out.stability.reshape(shp),
                                      f"{figdir}/css3d_{norm}_load1.png", title=f"CSS, load case 1 ({norm})")
                plots_css.plot_section(g.axes(), out.member.reshape(shp), out.stability.reshape(shp), 0.89,
                                       f"{figdir}/section_{norm}_load1.png")
        for k in range(1, 5):
            rv = np.asarray(lie.log(_rpy_matrix(jnp.deg2rad(jnp.full(3, float(k))))))
            v, u, g, out = css_over_frame(robot, kc1.K, LOAD1, tuple(rv), step, norm)
            ref = TABLE8[k - 1]
            print(f"{f'Table 7 case {k} ({k} deg x3)':28s} {ref[0]:12.4g} {v:12.4g} {ref[1]:8.4f} {u:8.4f}")
            vols.append(v), us.append(u), names.append(f"{k} deg")
        if figdir:
            plots_css.plot_cases(names, vols, us, f"{figdir}/cases_{norm}.png", title=f"CSS per case ({norm})")
    pose_change_tables(robot)


def pose_change_tables(robot):
    """Tables 10-11: pose change under 10 N on the constant stiffness planes (Table 9)."""
    o = np.array([0.0, 0.0, 0.89])
    rect = [o + np.array([x, y, 0]) for x in np.linspace(-0.03, 0.03, 5) for y in np.linspace(-0.02, 0.02, 3)]
    ang = np.linspace(0, 2 * np.pi, 9)[:-1]
    ell = [o] + [o + np.array([0.08 * np.cos(a), 0.04 * np.sin(a), 0]) for a in ang]
    ell += [o + np.array([0.04 * np.cos(a), 0.02 * np.sin(a), 0]) for a in ang[::2]]
    for name, pts, axis, paper in (("Table 10 (10 N along x, rectangle 0.06 x 0.04)", rect, 0, 1.9809),
                                   ("Table 11 (10 N along y, ellipse 0.08 x 0.04)", ell, 1, 3.9706)):
        W = np.zeros(6)
        W[axis] = 10.0
        kc = css.target_stiffness(robot, jnp.concatenate([jnp.asarray(o), jnp.zeros(3)]), jnp.asarray(W),
                                  inherent="paper").K
        target = float(css.pose_change(kc, jnp.asarray(W)).delta[axis]) * 1e3
        rows = []
        for p in pts:
            pose = jnp.concatenate([jnp.asarray(p), jnp.zeros(3)])
            pt = css.css_point(robot, pose, kc, 0.05, jnp.asarray(W), inherent="paper")
            K = css.affine_stiffness(robot, pose, inherent="paper")(pt.tensions)
            rows.append((bool(pt.member), float(css.pose_change(K, jnp.asarray(W)).delta[axis]) * 1e3))
        d = np.array([r[1] for r in rows if r[0]])
        print(f"\n{name}: targeted change paper {paper} mm, ours {target:.4f} mm; {len(d)}/{len(rows)} points in "
              f"the CSS; calculated {d.min():.4f}..{d.max():.4f} mm, max relative error "
              f"{np.max(np.abs(d / target - 1)):.2%} (paper 2.27% / 1.17%)")


def fold(acc, o, valid):
    m = o.member & valid
    return acc[0] + jnp.sum(m), acc[1] + jnp.sum(jnp.where(m, o.stability, 0.0))


INIT = (jnp.zeros((), jnp.int64), jnp.zeros(()))


def volume_fn(fn, grid):
    """``fn``'s members with the volume each stands for (``Grid.point_volume``), for :func:`fold_volume`."""
    return lambda P: (fn(P), grid.point_volume(P[:3]))


def fold_volume(acc, o, valid):
    """(count, ∫dv, ∫μ dv) over the members."""
    (pt, w), m = o, o[0].member & valid
    return acc[0] + jnp.sum(m), acc[1] + jnp.sum(jnp.where(m, w, 0.0)), \
        acc[2] + jnp.sum(jnp.where(m, w * pt.stability, 0.0))


INIT_VOLUME = (jnp.zeros((), jnp.int64), jnp.zeros(()), jnp.zeros(()))


def steady_rates(fns, P, repeat):
    """Poses/s after compile of each ``name: (fn, sweep keywords)``, timed in turn within every
    repeat (interleaved): time one call over P and one over 5 copies of P (same chunks) and
    divide the extra poses by the extra time, which leaves out every per-call cost (sweep
    compiles its chunk program at the first call of each function and keeps it)."""
    n = len(P)
    best = {(name, k): np.inf for name in fns for k in (1, 5)}
    for _ in range(repeat):
        for name, (fn, kw) in fns.items():
            for k in (1, 5):
                t0 = time.perf_counter()
                sweep(fn, np.tile(P, (k, 1)), chunk_size=n, reduce=fold, init=INIT, progress=False, **kw)
                best[name, k] = min(best[name, k], time.perf_counter() - t0)
    return {name: (4 * n / (best[name, 5] - best[name, 1]), best[name, 1]) for name in fns}


def throughput(robot, kc, n, repeat, vmap_row=True):
    rng = np.random.default_rng(0)
    P = np.column_stack([rng.uniform(-0.1, 0.1, n), rng.uniform(-0.08, 0.08, n), rng.uniform(0.75, 0.92, n),
                         rng.uniform(-0.02, 0.02, (n, 3))])
    cnt, _ = sweep(batch_fn(robot, kc), P, chunk_size=n, batch_size=64, vectorized=True, reduce=fold, init=INIT,
                   progress=False)
    cnt_old, _ = sweep(contractions_fn(robot, kc), P, chunk_size=n, batch_size=64, vectorized=True, reduce=fold,
                       init=INIT, progress=False)
    assert int(cnt) == int(cnt_old), (int(cnt), int(cnt_old))
    vec = {"batch_size": 64, "vectorized": True}
    fns = {"css_point batch form (6, 64)": (batch_fn(robot, kc), vec),
           "batch form, K by autodiff": (contractions_fn(robot, kc, autodiff=True), vec),
           "batch form, K by hand contractions": (contractions_fn(robot, kc), vec),
           "vmap of the one-pose form": (lambda p: css.css_point(robot, p, kc, 0.05), {"batch_size": 1024})}
    if not vmap_row:
        del fns["vmap of the one-pose form"]
    load0 = os.getloadavg()[0]
    rates = steady_rates(fns, P, repeat)
    print(f"{'near the CSS: members in the sample (both K paths)':52s} {int(cnt) / n:14.3f}")
    print(f"{'  load average before / after the throughput rows':52s} {load0:8.1f} / {os.getloadavg()[0]:.1f}")
    for name, (rate, first) in rates.items():
        print(f"{'  ' + name + ' [poses/s]':52s} {rate:14.4g}   (one call over the sample: {first:.2f} s)")


def frame_sweep(robot, kc, total, chunk, contractions=False):
    fast = contractions_fn(robot, kc) if contractions else batch_fn(robot, kc)
    label = ", K by hand contractions" if contractions else ""
    for n in (total // 10, total):
        g = grid_of(n)
        t0 = time.perf_counter()
        _, vol, vmu = sweep(volume_fn(fast, g), g, chunk_size=chunk, batch_size=64, vectorized=True,
                              reduce=fold_volume, init=INIT_VOLUME, progress=False)
        dt = time.perf_counter() - t0
        print(f"{f'frame sweep{label}, {len(g):.4g} poses: time [s]':52s} {dt:14.2f}")
        print(f"{'  rate [poses/s]':52s} {len(g) / dt:14.4g}")
        print(f"{'  peak RSS of the process so far [MiB]':52s} {rss_mib():14.1f}")
        print(f"{'  CSS volume [m^3] / U':52s} {float(vol):8.4g} / {float(vmu) / max(float(vol), 1e-300):.4f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reproduce", action="store_true")
    ap.add_argument("--step", type=float, default=0.02)
    ap.add_argument("--figures", default=None)
    ap.add_argument("--n", type=int, default=262144)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sweep-poses", type=float, default=1e8)
    ap.add_argument("--chunk", type=int, default=1 << 20)
    ap.add_argument("--no-vmap", action="store_true", help="skip the (slow) vmap-of-one-pose throughput row")
    ap.add_argument("--frame-contractions", action="store_true",
                    help="also sweep the frame with K by the hand contractions (after the default, autodiff sweep)")
    a = ap.parse_args()
    robot = load_robot(example_path("tcpr8.toml"))
    if a.reproduce:
        return reproduce(robot, a.step, a.figures)
    kc = css.target_stiffness(robot, POSE0).K
    print(f"CSS membership, 8-cable robot; {os.cpu_count()} CPUs, {len(jax.devices())} devices "
          f"({jax.devices()[0].platform}), load avg {os.getloadavg()[0]:.1f}")
    print(f"{'measurement':52s} {'value':>14s}")
    if a.sweep_poses > 0:
        frame_sweep(robot, kc, int(a.sweep_poses), a.chunk)  # first, so its peak RSS is its own
        if a.frame_contractions:
            frame_sweep(robot, kc, int(a.sweep_poses), a.chunk, contractions=True)
    throughput(robot, kc, a.n, a.repeat, not a.no_vmap)
    print("target: >= 1e6 poses/s; 1e8-pose sweep with bounded memory")


if __name__ == "__main__":
    main()
