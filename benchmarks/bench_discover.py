"""Blind benchmark of the open-ended diagnosis on effects outside every vocabulary.

    python benchmarks/bench_discover.py [--robots proto tcpr8] [--samples 90] [--cases ...] [--spring-only]

Generates the cases of :func:`fitting.synth.generate_oov.oov_cases` (five kinds simulated
independently of the grammar, plus clean data; the answer key stays in this script),
runs :func:`fitting.diagnosis.diagnose.diagnose` on the nominal description and the CSV only, and
prints per case: the discovered term and its driver, vocabulary effects claimed,
``explained``, χ²/dof before and after, the discovery time and the wall time, and the
verdict:

- ``found``: a discovered term acts on the right *where* with the right *driver*;
- ``honest``: nothing discovered (or not the right one) and ``explained`` false;
- ``WRONG``: a vocabulary label claimed with ``explained: true`` for an out-of-vocabulary
  effect, a wrong term with ``explained: true``, or anything found on clean data.
"""

import argparse
import platform
import sys
import tempfile
import time
from pathlib import Path

from cstiffjax import load_recordings, load_robot
from fitting.diagnosis.diagnose import diagnose
from fitting.effects import VOCABULARY
from fitting.synth.generate_oov import oov_cases, write_oov_case

WHERE_OK = {"l0": ("term:l0|",), "load": ("term:load|", "term:wrench[0]|gain", "term:wrench[1]|gain",
                                          "term:wrench[2]|gain"),
            "pose[2]": ("term:pose[2]|",), "tension": ("term:tension|",)}


def verdict(case, d) -> str:
    """``found`` / ``honest`` / ``WRONG`` (see module doc)."""
    if case.kind == "clean":
        return "clean" if not d.discovered and not d.effects and d.explained else "WRONG"
    right = [e for e in d.discovered if e["key"].startswith(WHERE_OK[case.where]) and e["driver"] == case.driver]
    if right:
        return "found"
    if d.explained:
        return "WRONG"
    return "honest"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", nargs="*", default=["proto", "tcpr8"])
    ap.add_argument("--samples", type=int, default=90)
    ap.add_argument("--cases", nargs="*", help="only these case names")
    ap.add_argument("--spring-only", action="store_true", help="leave cable_mass out (no catenary compile)")
    ap.add_argument("--budget", type=float, default=60.0, help="discovery compute budget per case, s")
    args = ap.parse_args(argv)
    effects = tuple(e for e in VOCABULARY if not (args.spring_only and e.name == "cable_mass"))
    tmp = Path(tempfile.mkdtemp(prefix="bench_discover_"))
    print(f"machine: {platform.processor() or platform.machine()}, python {sys.version.split()[0]}; "
          f"{args.samples} samples per case; vocabulary: {len(effects)} effects", flush=True)
    hdr = (f"{'case':28s} {'discovered term':52s} {'driver':12s} {'effects':16s} {'expl':4s} "
           f"{'chi2/dof before':>15s} {'after':>7s} {'disc s':>7s} {'wall s':>7s} verdict")
    print(hdr)
    print("-" * len(hdr), flush=True)
    bad = 0
    for i, c in enumerate(oov_cases()):
        if c.robot not in args.robots or (args.cases and c.name not in args.cases):
            continue
        write_oov_case(c, tmp / c.name, args.samples, seed=200 + i)
        robot = load_robot(tmp / c.name / "robot.toml")
        rec = load_recordings(tmp / c.name / "recordings.csv", robot)
        t0 = time.perf_counter()
        d = diagnose(robot, rec, effects=effects, posterior_steps=0, discovery_budget_s=args.budget)
        wall = time.perf_counter() - t0
        v = verdict(c, d)
        bad += v == "WRONG"
        term = "; ".join(e["term"] for e in d.discovered) or "-"
        drv = "; ".join(str(e["driver"]) for e in d.discovered) or "-"
        print(f"{c.name:28s} {term[:52]:52s} {drv[:12]:12s} {'+'.join(d.effects) or '-':16s} "
              f"{str(d.explained)[0]:4s} {d.baseline['chi2_per_dof']:15.4g} {d.final['chi2_per_dof']:7.3f} "
              f"{d.discovery.get('elapsed_s', 0.0):7.1f} {wall:7.1f} {v}", flush=True)
        for e in d.discovered:
            print(f"{'':28s}   -> {e['interpretation']}", flush=True)
    print(f"\n{bad} wrong verdict(s)")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
