"""False-alarm rate of the stricter ``explained`` on clean recordings.

    python benchmarks/bench_false_alarm.py [--sets 20] [--robots proto tcpr8] [--samples 90] [--full]

For each robot, ``--sets`` clean data sets (independent seeds, no concealed effect) are
generated (:func:`fitting.synth.generate_oov.simulate_oov`, clean kind: two covariates,
temperature and humidity) and diagnosed. Default: the baseline only (``effects=()``, no
discovery), which isolates the residual checks (:mod:`fitting.diagnosis.residual_checks`);
``--full``: the whole vocabulary and the discovery, as a user would run it. Prints per
robot how many sets came out ``explained: false``, which tests rejected, and χ²/dof.
Target: 0 in 20, at most 1 in 20.
"""

import argparse
import tempfile
import time
from pathlib import Path

from cstiffjax import load_recordings, load_robot
from fitting.diagnosis.diagnose import diagnose
from fitting.synth.generate_oov import OOVCase, write_oov_case


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", type=int, default=20)
    ap.add_argument("--robots", nargs="*", default=["proto", "tcpr8"])
    ap.add_argument("--samples", type=int, default=90)
    ap.add_argument("--full", action="store_true", help="whole vocabulary + discovery (slow)")
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="bench_false_alarm_"))
    worst = 0.0
    for kind in args.robots:
        alarms, t0 = [], time.perf_counter()
        for s in range(args.sets):
            case = OOVCase(f"{kind}_clean_{s}", kind, "clean")
            write_oov_case(case, tmp / case.name, args.samples, seed=1000 + s)
            rb = load_robot(tmp / case.name / "robot.toml")
            rec = load_recordings(tmp / case.name / "recordings.csv", rb)
            kw = dict(posterior_steps=0) if args.full else dict(effects=(), discover=False, posterior_steps=0)
            d = diagnose(rb, rec, **kw)
            chk = d.final["residual_checks"]
            found = bool(d.effects or d.discovered)
            if not d.explained or found:
                alarms.append((s, d.final["chi2_per_dof"], d.effects, [e["key"] for e in d.discovered],
                               [(f["channel"], f["test"], f["driver"], f"{f['p']:.1e}") for f in chk["findings"]]))
            print(f"{kind} set {s:2d}: chi2/dof {d.final['chi2_per_dof']:.3f}, explained {d.explained}, "
                  f"{len(chk['findings'])}/{chk['tests']} tests rejected", flush=True)
        rate = len(alarms) / args.sets
        worst = max(worst, rate)
        print(f"\n{kind}: false alarms {len(alarms)}/{args.sets} ({'full diagnosis' if args.full else 'baseline'}; "
              f"{time.perf_counter() - t0:.0f} s)")
        for a in alarms:
            print("   ", a)
    return 0 if worst <= 1 / 20 else 1


if __name__ == "__main__":
    raise SystemExit(main())
