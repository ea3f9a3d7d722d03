"""The diagnosis's masked fits: the numpy-driven Levenberg-Marquardt of
:mod:`fitting.effects.fit` against the same fits done with optimistix (issue 13).

    python benchmarks/bench_masked_lm.py [--engines numpy optimistix loop] [--fits 3]

Each engine runs in a fresh process (imports, tracing and compilation counted; no
persistent compilation cache) on the bundled concealed example (90 samples, spring model
holding every vocabulary effect, θ of 54 entries): the baseline fit (EA free; compile +
fit), then ``--fits`` candidate fits started from it (one per vocabulary effect, in the
order below) and one held-out-fold fit, exactly as :class:`fitting.diagnose._Fitter`
makes them. Prints, per fit: wall seconds, steps, χ²; per process: wall and CPU seconds,
and the load average. ``loop`` times one ``(r, J)`` evaluation at top level and as the
body of a ``lax.fori_loop`` (where any jitted solver runs it).

The optimistix variant is the one the issue asked for: ``optx.LevenbergMarquardt`` on
``y -> r(where(free, y, θ_fixed))`` with the free mask, the fixed values, the required
samples and the sample weights passed as *data* (one compilation for every free set and
fold), a failed required sample adding a ``1e8`` residual entry (the step is rejected),
the residual's Jacobian materialised in forward mode as in
:func:`fitting.least_squares.solve_least_squares`. It lives here, not in the library,
because it was measured slower (see the README, "One least-squares engine").
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
JAC = os.environ.get("BENCH_OPTX_JAC", "fwd")  # optimistix's Jacobian option: "fwd" (linearize) or "bwd"
CANDIDATES = ("exit_friction", "length_offset", "anchor_offset", "tension_sensor_bias")


def _optimistix_solver(jac: str):
    """The jitted optimistix masked solve (built once per process: one compilation)."""
    import equinox as eqx
    import jax.numpy as jnp
    import optimistix as optx

    from fitting.effects.model import residuals
    from fitting.least_squares import _forward_jacobian

    class Masked(eqx.Module):
        def __call__(self, y, margs):
            (model, robot, data), fr, fixed, nd = margs
            r, ok = residuals(model, jnp.where(fr, y, fixed), robot, data)
            good = ok & jnp.all(jnp.isfinite(r), axis=1)
            return jnp.concatenate([jnp.where(good[:, None], r, 0.0).ravel(), 1e8 * (nd & ~good)])

    @eqx.filter_jit
    def solve(theta0, margs):
        fj = _forward_jacobian(Masked(), margs)
        sol = optx.least_squares(lambda y, _: fj(y), optx.LevenbergMarquardt(rtol=1e-9, atol=1e-9), theta0,
                                 max_steps=200, throw=False, options={"jac": jac})
        theta = jnp.where(margs[1], sol.value, theta0)
        return theta, Masked()(theta, margs), sol.stats["num_steps"], sol.result == optx.RESULTS.successful

    return solve


def _optimistix_fit(solve, fn_args, theta0, free, need):
    import jax.numpy as jnp

    from fitting.effects.fit import MaskedFit

    margs = (fn_args, jnp.asarray(free), jnp.asarray(theta0), jnp.asarray(need))
    theta, flat, steps, ok = solve(jnp.asarray(theta0), margs)
    n = len(need)
    r = np.asarray(flat)[:-n]
    return MaskedFit(np.asarray(theta), free, r.reshape(n, -1), None, None, float(r @ r), None, int(steps),
                     bool(ok), "")


def loop_cost() -> None:
    """One ``(r, J)`` evaluation of the baseline model at top level against the same
    evaluation as the body of a ``lax.fori_loop`` of 10 (how every jitted solver loop,
    optimistix's included, runs it)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from cstiffjax import load_recordings, load_robot
    from cstiffjax.examples import example_path
    from fitting.diagnose import _Fitter
    from fitting.effect_posterior import with_weight
    from fitting.effects import VOCABULARY
    from fitting.effects.model import residuals, residuals_and_jacobian

    robot = load_robot(example_path("concealed/robot.toml"))
    rec = load_recordings(example_path("concealed/recordings.csv"), robot)
    f = _Fitter(robot, rec, "spring", VOCABULARY)
    model, data = f.model_for([]), with_weight(f.data, np.ones(f.n))
    th = jnp.zeros(model.size)

    @eqx.filter_jit
    def looped(th, model, robot, data):
        def body(i, acc):
            J = jax.jacfwd(lambda x: residuals(model, x, robot, data)[0].ravel())(th + 1e-12 * acc)
            return acc + 0.0 * jnp.sum(J)
        return jax.lax.fori_loop(0, 10, body, jnp.zeros(()))

    jax.block_until_ready(looped(th, model, f.robot, data))
    jax.block_until_ready(residuals_and_jacobian(model, th, f.robot, data))
    t = time.perf_counter()
    jax.block_until_ready(looped(th, model, f.robot, data))
    inside = (time.perf_counter() - t) / 10
    t = time.perf_counter()
    for _ in range(10):
        jax.block_until_ready(residuals_and_jacobian(model, th, f.robot, data))
    top = (time.perf_counter() - t) / 10
    print(f"  (r, J) evaluation: top level {top:.3f} s, inside a fori_loop body {inside:.3f} s "
          f"({inside / top:.1f}x)", flush=True)


def child(engine: str, nfits: int) -> None:
    if engine == "loop":
        loop_cost()
        return
    from cstiffjax import load_recordings, load_robot
    from cstiffjax.examples import example_path
    from fitting.diagnose import _Fitter, _transfer
    from fitting.effect_posterior import with_weight
    from fitting.effects import VOCABULARY
    from fitting.effects.fit import levenberg_marquardt

    t_start = time.perf_counter()
    robot = load_robot(example_path("concealed/robot.toml"))
    rec = load_recordings(example_path("concealed/recordings.csv"), robot)
    f = _Fitter(robot, rec, "spring", VOCABULARY)
    solve = _optimistix_solver(JAC) if engine == "optimistix" else None

    def fit(names, weight, start=None):
        model = f.model_for(names)
        free = f.free_mask(model, names)
        th = np.where(free, np.asarray(model.start), 0.0)
        if start is not None:
            th = _transfer(*start, model, th, free)
        if engine == "numpy":
            return model, levenberg_marquardt(f.evaluator(model, weight), th, free, must_succeed=weight > 0)
        return model, _optimistix_fit(solve, (model, f.robot, with_weight(f.data, weight)), th, free, weight > 0)

    def timed(label, names, weight, start=None):
        t = time.perf_counter()
        out = fit(names, weight, start)
        print(f"  {engine:10s} {label:34s} {time.perf_counter() - t:7.2f} s  steps {out[1].steps:3d}  "
              f"chi2 {out[1].chi2:.4f}", flush=True)
        return out

    w = np.ones(f.n)
    model, base = timed("baseline (compile + fit)", [], w)
    for name in CANDIDATES[:nfits]:
        timed(f"+{name}", [name], w, (model, base.theta))
    fold = (np.random.default_rng(0).permutation(f.n) % 5 != 0).astype(float)
    timed(f"+{CANDIDATES[0]}, one held-out fold", [CANDIDATES[0]], fold, (model, base.theta))
    print(f"  {engine:10s} {'process total':34s} {time.perf_counter() - t_start:7.2f} s", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--engines", nargs="*", default=["numpy", "optimistix"], choices=["numpy", "optimistix", "loop"],
                    help="loop: one (r, J) evaluation at top level vs inside a lax loop")
    ap.add_argument("--fits", type=int, default=3, help="candidate fits after the baseline")
    ap.add_argument("--jac", default="fwd", choices=["fwd", "bwd"],
                    help="optimistix's jac option (bwd: the Jacobian materialised once per step)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child, args.fits)
        return 0
    env = dict(os.environ, PYTHONPATH=str(ROOT), CSTIFFJAX_CACHE_DIR="off", BENCH_OPTX_JAC=args.jac)
    for engine in args.engines:
        label = f"{engine} (jac={args.jac})" if engine == "optimistix" else engine
        print(f"{label}: load average {os.getloadavg()[0]:.1f} (1 min) at start", flush=True)
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
