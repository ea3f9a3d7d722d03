"""Benchmark of the fitting package (run: ``python benchmarks/bench_fit.py [--quick]``).

1. Calibration of EA + length offsets from 90 synthetic samples of the Yuan et al. 2015
   prototype (6 cables), spring and catenary, time after compile (targets < 1 s, < 5 s).
2. emcee, 32 walkers x 2000 steps, on the spring EA fit (target < 60 s; Newton statics
   warm-started at the least-squares poses, see fitting.posterior.sampler.log_prob_fn).
3. Coverage: 90% intervals over repeated synthetic data sets (target 85-95%):
   least-squares intervals of the CDPR fit, and emcee intervals of a linear-Gaussian model.
"""

import argparse
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

import cstiffjax  # noqa: F401
from cstiffjax import CableLaw
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from fitting import calibrate, calibrate_model, sample_posterior, synthetic_recordings
from fitting.calibration.parameters import apply_to_robot


def _truth(nominal, rng, mass=None):
    v = {"EA": nominal.EA * (1 + 0.05 * rng.uniform(-1, 1, 6))}
    if mass is not None:
        v["mass_per_length"] = jnp.full(6, mass)
    return apply_to_robot(nominal, v), 1e-3 * rng.uniform(-1, 1, 6)


def _recordings(robot, offset, key, n, law):
    import equinox as eqx

    rec = synthetic_recordings(robot, key, n, law=law)
    return eqx.tree_at(lambda r: r.l0, rec, rec.l0 - offset)


def bench_calibration(nominal, law, n, rng, mass=None):
    truth, off = _truth(nominal, rng, mass)
    start = apply_to_robot(nominal, {"mass_per_length": truth.mass_per_length})
    r1 = _recordings(truth, off, jax.random.PRNGKey(1), n, law)
    r2 = _recordings(truth, off, jax.random.PRNGKey(2), n, law)
    t = time.perf_counter()
    calibrate(start, r1, free=("EA", "length_offset"), law=law)
    first = time.perf_counter() - t
    t = time.perf_counter()
    fit = calibrate(start, r2, free=("EA", "length_offset"), law=law)
    jax.block_until_ready(fit.chi2)
    return first, time.perf_counter() - t, fit


def coverage_cdpr(nominal, n, reps, rng):
    truth, off = _truth(nominal, rng)
    hits = []
    for k in range(reps):
        fit = calibrate(nominal, _recordings(truth, off, jax.random.PRNGKey(100 + k), n, CableLaw.spring),
                        free=("EA", "length_offset"))
        for name, true in (("EA", truth.EA), ("length_offset", off)):
            hits.append(np.abs(np.asarray(fit.values[name]) - np.asarray(true)) <= 1.6449 * np.asarray(fit.std[name]))
    return float(np.mean(hits)), np.concatenate(hits).size


def coverage_linear(reps, nsteps, rng):
    x = np.linspace(-1, 2, 25)
    hits = []
    for _ in range(reps):
        y = 0.7 - 1.2 * x + 0.3 * rng.normal(size=x.size)
        fit = calibrate_model(lambda p, x: p["a"] + p["b"] * x, {"a": 0.0, "b": 0.0}, x, y, 0.3)
        s = sample_posterior(fit, nwalkers=16, nsteps=nsteps, seed=int(rng.integers(1 << 30))).summary()
        hits.append((s["lower"] <= [0.7, -1.2]) & ([0.7, -1.2] <= s["upper"]))
    return float(np.mean(hits)), 2 * reps


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="small sizes (smoke run)")
    ap.add_argument("--coverage-only", action="store_true", help="only the linear-Gaussian emcee coverage")
    a = ap.parse_args()
    if a.coverage_only:
        cov_l, k_l = coverage_linear(80, 4000, np.random.default_rng(0))
        print(f"emcee 90% interval coverage, linear ({k_l} intervals): {100 * cov_l:.1f}% (target 85-95%)")
        return
    n, steps, reps = (30, 300, 10) if a.quick else (90, 2000, 30)
    rng = np.random.default_rng(0)
    nominal = load_robot(example_path("example01/robot.toml"))
    rows = []
    print(f"machine: {platform.machine()}, {os.cpu_count()} cpus, load {os.getloadavg()[0]:.1f}, "
          f"jax {jax.__version__}, devices {jax.devices()}", flush=True)
    print(f"{'benchmark':<58}{'time [s]':>10}  {'target':<8}  notes", flush=True)

    def report(*row):
        rows.append(row)
        name, t, target, note = row
        print(f"{name:<58}{t:>10.3f}  {target:<8}  {note}", flush=True)
    first, t, fit = bench_calibration(nominal, CableLaw.spring, n, rng)
    report(*(f"calibrate EA+length_offset, {n} samples, spring", t, "< 1 s", f"compile+run {first:.1f} s, "
                 f"chi2/dof {float(fit.chi2_per_dof):.3f}"))
    first_c, tc, fitc = bench_calibration(nominal, CableLaw.catenary, n, rng, mass=0.25)
    report(*(f"calibrate EA+length_offset, {n} samples, catenary", tc, "< 5 s", f"compile+run {first_c:.1f} s, "
                 f"chi2/dof {float(fitc.chi2_per_dof):.3f}"))
    fit_ea = calibrate(nominal, synthetic_recordings(nominal, jax.random.PRNGKey(5), n), free="EA")
    sample_posterior(fit_ea, nwalkers=32, nsteps=3, seed=0)  # compile
    t0 = time.perf_counter()
    post = sample_posterior(fit_ea, nwalkers=32, nsteps=steps, seed=0)
    te = time.perf_counter() - t0
    report(*(f"emcee 32 walkers x {steps} steps (EA, {n} samples)", te, "< 60 s",
                 f"acceptance {np.mean(post.acceptance_fraction):.2f}, max tau {np.nanmax(post.tau):.0f}, "
                 f"warm-start fallbacks {post.restarts}"))
    cov, k = coverage_cdpr(nominal, n, reps, rng)
    report(*(f"LS 90% interval coverage, CDPR ({k} intervals)", float("nan"), "85-95%", f"{100 * cov:.1f}%"))
    cov_l, k_l = coverage_linear(5 * reps, 4000, rng)
    report(*(f"emcee 90% interval coverage, linear ({k_l} intervals)", float("nan"), "85-95%",
                 f"{100 * cov_l:.1f}%"))
    print(f"load at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
