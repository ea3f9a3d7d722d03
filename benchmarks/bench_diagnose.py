"""Blind benchmark of the mismatch diagnosis on generated recordings with concealed effects.

    python benchmarks/bench_diagnose.py [--robots proto tcpr8] [--samples 90] [--cases ...]

Generates every case of :func:`fitting.synth.generate.default_cases` (the answer key stays in
this script's memory; the cable-hardware cases ``*_pulley_kinematics``, ``*_length_gain``,
``*_tension_sensor_gain``, ``*_attachment_offset``, ``*_hardware_two_effects`` come last),
runs :func:`fitting.diagnosis.diagnose.diagnose` on the nominal description
and the CSV only, and prints a confusion table (expected vs found, first effect), χ²/dof
before/after, outliers and the wall time per case; the load-cell fault cases' faults
(``key["sensor_faults"]``) count as expected, written ``kind:channel`` beside the effects.
The first case of each robot includes the compilation (cold); later cases of the same shape
reuse it (warm). Also runs the two bundled lab examples (``cstiffjax/examples``: example01 =
anchor_offset, example02 = clean; ``--no-examples`` leaves them out).
"""

import argparse
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cstiffjax import load_recordings, load_robot
from cstiffjax.examples import example_path
from fitting.diagnosis.diagnose import diagnose
from fitting.synth.generate import default_cases, write_case


def _row(name, expected, exp_explained, exp_out, d, wall, exp_faults=()):
    first_ok = (d.effects[:1] == expected[:1]) if expected else (d.effects == [])
    faults = [f"{f['kind']}:{f['channel']}" for f in (s.to_json() for s in d.sensor_faults)]
    want = [f"{f['kind']}:{f['channel']}" for f in exp_faults]
    full_ok = sorted(d.effects) == sorted(expected) and d.explained == exp_explained and faults == want
    out_ok = sorted(d.outliers) == sorted(exp_out)
    chain = next(iter(d.final.get("posterior", {}).values()), None)  # the posterior check's one chain
    return dict(case=name, expected="+".join([*expected, *want]) or "none",
                found="+".join([*d.effects, *faults]) or "none",
                explained=d.explained, before=d.baseline["chi2_per_dof"], after=d.final["chi2_per_dof"],
                outliers=len(d.outliers), ok=first_ok and full_ok and out_ok, wall=wall, chain=chain)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", nargs="*", default=["proto", "tcpr8"])
    ap.add_argument("--samples", type=int, default=90)
    ap.add_argument("--cases", nargs="*", help="only these case names")
    ap.add_argument("--no-examples", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    jobs = []
    if not args.no_examples:
        for ex, exp in (("example01", ["anchor_offset"]), ("example02", [])):
            try:
                jobs.append((ex, exp, True, [], example_path(f"{ex}/robot.toml"), example_path(f"{ex}/recordings.csv"),
                             []))
            except FileNotFoundError:
                pass
    tmp = Path(tempfile.mkdtemp(prefix="bench_diagnose_"))
    for i, c in enumerate(default_cases()):
        if c.robot not in args.robots or (args.cases and c.name not in args.cases):
            continue
        key = write_case(c, tmp / c.name, args.samples, seed=100 + i)
        jobs.append((c.name, c.expected, c.explained, key["outliers"], tmp / c.name / "robot.toml",
                     tmp / c.name / "recordings.csv", key["sensor_faults"]))
    print(f"machine: {platform.processor() or platform.machine()}, python {sys.version.split()[0]}; "
          f"{args.samples} samples per generated case", flush=True)
    hdr = f"{'case':34s} {'expected':32s} {'found':32s} {'expl':5s} {'chi2/dof before':>15s} {'after':>7s} " \
          f"{'outl':>4s} {'ok':>3s} {'wall s':>7s}"
    print(hdr)
    print("-" * len(hdr), flush=True)
    for name, exp, exp_expl, exp_out, rp, cp, exp_faults in jobs:
        robot = load_robot(rp)
        rec = load_recordings(cp, robot)
        t0 = time.perf_counter()
        d = diagnose(robot, rec)
        r = _row(name, exp, exp_expl, exp_out, d, time.perf_counter() - t0, exp_faults)
        rows.append(r)
        print(f"{r['case']:34s} {r['expected']:32s} {r['found']:32s} {str(r['explained'])[0]:5s} "
              f"{r['before']:15.4g} {r['after']:7.3f} {r['outliers']:4d} {'yes' if r['ok'] else 'NO':>3s} "
              f"{r['wall']:7.1f}", flush=True)
    labels = sorted({r["expected"] for r in rows} | {r["found"] for r in rows})
    print("\nconfusion (rows: concealed, columns: diagnosed; first effect of each):")
    code = {"none": "none"}  # initials, made unique (anchor_offset AO, attachment_offset AtO)
    for part in sorted({p for lb in labels for p in lb.split("+")} - {"none"}):
        w, k = part.split("_"), 1
        c = "".join(x[0] for x in w).upper()
        while c in code.values():
            k += 1
            c = w[0][:k].capitalize() + "".join(x[0] for x in w[1:]).upper()
        code[part] = c
    short = {lb: "+".join(code[part] for part in lb.split("+")) for lb in labels}
    print("(" + ", ".join(f"{v} = {k}" for k, v in short.items() if k != "none") + ")")
    print(" " * 34 + " ".join(f"{short[lb]:>10s}" for lb in labels))
    for a in labels:
        counts = [sum(1 for r in rows if r["expected"] == a and r["found"] == b) for b in labels]
        if sum(counts):
            print(f"{a:34s}" + " ".join(f"{c:10d}" for c in counts))
    chains = [(r["case"], r["chain"]) for r in rows if r["chain"] is not None]
    if chains:  # a sampler in trouble (samples failing, a chain that did not converge) shows here
        print("\nposterior chains (acceptance, tau steps, steps, converged):")
        for name, c in chains:
            tau = "n/a" if c["tau"] is None else f"{c['tau']:.2f}"
            print(f"{name:34s} {c['acceptance_fraction']:6.3f} {tau:>6s} {c['steps']:5d} "
                  f"{'yes' if c['converged'] else 'NO'}")
        acc = [c["acceptance_fraction"] for _, c in chains]
        print(f"{len(chains)} chains, {sum(c['converged'] for _, c in chains)} converged, acceptance "
              f"{min(acc):.3f}-{max(acc):.3f}")
    walls = np.array([r["wall"] for r in rows])
    n_ok = sum(r["ok"] for r in rows)
    print(f"\n{n_ok}/{len(rows)} cases fully right; chi2/dof after: max "
          f"{max(r['after'] for r in rows if r['explained']):.3f} over explained cases; wall time per case: "
          f"first (cold) {walls[0]:.1f} s, median {np.median(walls):.1f} s, max {walls.max():.1f} s")
    return 0 if n_ok == len(rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
