"""Latency a user feels: wall time of ``cstiffjax diagnose`` in fresh processes.

    python benchmarks/bench_cli_latency.py [--repeat 1] [--skip-two]

Runs, each in a new Python process (imports, tracing, compilation and the fits all
counted, as a user meets them):

1. ``cstiffjax diagnose --quiet`` on the bundled concealed example with an empty
   compilation cache (a fresh ``CSTIFFJAX_CACHE_DIR``): cold;
2. the same again with the cache it left: warm;
3. the same with the cache disabled (``CSTIFFJAX_CACHE_DIR=off``), the behaviour before
   the cache existed;
4. a diagnosis that selects two effects (``proto_two_effects`` of
   :func:`fitting.synth.generate.default_cases`, anchor_offset + tension_sensor_bias, 90
   samples, seed 110 as in ``bench_diagnose.py``), cold and warm.

Prints wall and CPU seconds (user + system of the child and of its figure process) per
run; CPU seconds are the better guide on a shared machine. The package's bytecode is
compiled first, as ``pip install`` leaves it. Targets (quiet 2-core machine): cold <= 15 s,
warm <= 5 s, two-effect diagnosis <= 60 s.
"""

import argparse
import compileall
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(args, cache, cwd) -> tuple[float, float, str]:
    env = dict(os.environ, CSTIFFJAX_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "cstiffjax.commands.cli", "diagnose", *args, "--quiet"], cwd=cwd, env=env,
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise RuntimeError(f"diagnose failed ({p.returncode}):\n{p.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, p.stdout.strip().splitlines()[-1]


def _two_effect_case(tmp: Path) -> list[str]:
    from fitting.synth.generate import default_cases, write_case

    cases = default_cases()
    i = next(k for k, c in enumerate(cases) if c.name == "proto_two_effects")
    write_case(cases[i], tmp / "two", 90, seed=100 + i)
    return [str(tmp / "two" / "robot.toml"), str(tmp / "two" / "recordings.csv")]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=1, help="warm runs to take (the best is reported too)")
    ap.add_argument("--skip-two", action="store_true", help="skip the two-effect diagnosis")
    ap.add_argument("--skip-off", action="store_true", help="skip the run without a cache")
    args = ap.parse_args(argv)
    for package in ("cstiffjax", "fitting"):  # bytecode, as `pip install` writes it (PYTHONDONTWRITEBYTECODE
        compileall.compile_dir(ROOT / package, quiet=1)  # would otherwise recompile ~100 modules every run)
    tmp = Path(tempfile.mkdtemp(prefix="bench_cli_latency_"))
    rows = []

    def record(name, res):
        wall, cpu, line = res
        rows.append((name, wall, cpu))
        print(f"{name:44s} wall {wall:7.1f} s   cpu {cpu:7.1f} s   {line}", flush=True)

    cache = tmp / "cache"
    record("diagnose, concealed example, cold cache", _run([], cache, tmp))
    for k in range(args.repeat):
        record(f"diagnose, concealed example, warm cache #{k + 1}", _run([], cache, tmp))
    if not args.skip_off:
        record("diagnose, concealed example, cache off", _run([], "off", tmp))
    if not args.skip_two:
        case = _two_effect_case(tmp)
        cache2 = tmp / "cache2"
        record("diagnose, two effects (proto), cold cache", _run(case, cache2, tmp))
        record("diagnose, two effects (proto), warm cache", _run(case, cache2, tmp))
    print(f"\nload average during the run: {os.getloadavg()[0]:.1f} (1 min); {os.cpu_count()} CPUs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
