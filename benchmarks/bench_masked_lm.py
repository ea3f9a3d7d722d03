"""The diagnosis's masked fits: the one least-squares engine (:mod:`fitting.calibration.lm`, a jitted
``lax.while_loop``) against the numpy Levenberg-Marquardt loop it replaced.

    python benchmarks/bench_masked_lm.py [--engines numpy jax] [--fits 3]

Each engine runs in a fresh process (imports, tracing and compilation counted; no
persistent compilation cache) on the bundled concealed example (90 samples, spring model
holding every vocabulary effect, θ of 54 entries): the baseline fit (EA free; compile +
fit), then ``--fits`` candidate fits started from it (one per vocabulary effect, in the
order below) and one held-out-fold fit, exactly as :class:`fitting.diagnosis.fitter.Fitter`
makes them. Prints, per fit: wall and CPU seconds, steps, χ²; per process: wall and CPU seconds,
and the load average.

``numpy`` is the **baseline**: the host loop of ``fitting/effects/fit.py`` before it was replaced
(copied below, :func:`numpy_lm`), around the compiled
:func:`fitting.effects.model.residuals_and_jacobian`. ``jax`` is the library's
:func:`fitting.effects.fit.fit_masked`.
"""

import argparse
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CANDIDATES = ("exit_friction", "length_offset", "anchor_offset", "tension_sensor_bias")


def numpy_lm(fun, theta0, free, *, max_steps: int = 60, rtol: float = 1e-9, must_succeed=None):
    """BASELINE, not library code: the numpy Levenberg-Marquardt loop the diagnosis used
    before it was replaced (``fitting/effects/fit.py::levenberg_marquardt``), verbatim but for the
    result tuple ``(theta, chi2, steps, converged)``."""
    theta = np.array(theta0, dtype=float)
    free = np.asarray(free, dtype=bool)

    def ev(th):
        r, J, ok = (np.asarray(a) for a in fun(th))
        finite = np.all(np.isfinite(J).reshape(len(ok), -1), axis=1) & np.all(np.isfinite(r.reshape(len(ok), -1)), 1)
        return np.where(np.isfinite(r), r, 0.0), np.where(np.isfinite(J), J, 0.0), ok & finite

    r, J, ok = ev(theta)
    need = np.ones_like(ok, dtype=bool) if must_succeed is None else np.asarray(must_succeed, dtype=bool)
    if not np.all(ok[need]):
        return theta, float(np.sum(r * r)), 0, False
    cost = float(np.sum(r * r))
    lam, converged, steps = 1e-4, False, 0
    for steps in range(1, max_steps + 1):  # noqa: B007
        Jf = J[:, free]
        g = Jf.T @ r.ravel()
        A = Jf.T @ Jf
        d = np.where(np.diag(A) > 0, np.diag(A), 1.0)
        accepted = False
        while lam < 1e12:
            try:
                step = np.linalg.solve(A + lam * np.diag(d), -g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            trial = theta.copy()
            trial[free] += step
            rn, Jn, okn = ev(trial)
            cn = float(np.sum(rn * rn))
            if np.all(okn[need]) and np.isfinite(cn) and cn <= cost:
                accepted = True
                break
            lam *= 10
        if not accepted:
            converged = True
            break
        decrease = cost - cn
        theta, r, J, ok, cost = trial, rn, Jn, okn, cn
        lam = max(lam / 10, 1e-12)
        if decrease <= rtol * cost + 1e-12:
            converged = True
            break
    return theta, cost, steps, converged


def child(engine: str, nfits: int) -> None:
    from cstiffjax import CableLaw, load_recordings, load_robot
    from cstiffjax.examples import example_path
    from fitting.diagnosis.effect_posterior import with_weight
    from fitting.diagnosis.fitter import Fitter, transfer
    from fitting.effects import VOCABULARY
    from fitting.effects.model import residuals_and_jacobian

    t_start = time.perf_counter()
    robot = load_robot(example_path("concealed/robot.toml"))
    rec = load_recordings(example_path("concealed/recordings.csv"), robot)
    f = Fitter(robot, rec, CableLaw.spring, VOCABULARY)

    def fit(names, weight, start=None):
        model = f.model_for(names)
        free = f.free_mask(model, names)
        th = np.where(free, np.asarray(model.start), 0.0)
        if start is not None:
            th = transfer(*start, model, th, free)
        if engine == "jax":
            mf = f.fit_free(model, weight, th, free)
            return model, (mf.theta, mf.chi2, mf.steps, mf.converged)
        data = with_weight(f.data, weight)
        return model, numpy_lm(lambda t: residuals_and_jacobian(model, t, f.robot, data), th, free,
                               must_succeed=weight > 0)

    def timed(label, names, weight, start=None):
        t, c = time.perf_counter(), time.process_time()
        out = fit(names, weight, start)
        _, chi2, steps, conv = out[1]
        print(f"  {engine:6s} {label:34s} {time.perf_counter() - t:7.2f} s wall {time.process_time() - c:7.2f} s cpu  "
              f"steps {steps:3d}  "
              f"chi2 {chi2:.4f}{'' if conv else '  (not converged)'}", flush=True)
        return out

    w = np.ones(f.n)
    model, base = timed("baseline (compile + fit)", [], w)
    for name in CANDIDATES[:nfits]:
        timed(f"+{name}", [name], w, (model, base[0]))
    fold = (np.random.default_rng(0).permutation(f.n) % 5 != 0).astype(float)
    timed(f"+{CANDIDATES[0]}, one held-out fold", [CANDIDATES[0]], fold, (model, base[0]))
    print(f"  {engine:6s} {'process total':34s} {time.perf_counter() - t_start:7.2f} s", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--engines", nargs="*", default=["numpy", "jax"], choices=["numpy", "jax"],
                    help="numpy: the pre-issue-13 host loop (baseline); jax: fitting.calibration.lm")
    ap.add_argument("--fits", type=int, default=3, help="candidate fits after the baseline")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child, args.fits)
        return 0
    env = dict(os.environ, PYTHONPATH=str(ROOT), CSTIFFJAX_CACHE_DIR="off")
    for engine in args.engines:
        print(f"{engine}: load average {os.getloadavg()[0]:.1f} (1 min) at start", flush=True)
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, __file__, "--child", engine, "--fits", str(args.fits)], env=env, check=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        print(f"{engine}: wall {time.perf_counter() - t0:.1f} s, cpu {cpu:.1f} s, load average "
              f"{os.getloadavg()[0]:.1f} at the end; {os.cpu_count()} CPUs\n", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
