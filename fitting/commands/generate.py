"""Write generated recordings sets with concealed effects and their answer key.

``cstiffjax generate --out DIR`` writes one folder per case, ``DIR/CASE/robot.toml`` (the
nominal description) and ``DIR/CASE/recordings.csv`` (formats.md §2), plus ``DIR/key.json``
(what each case conceals): the vocabulary's effects, clean data and the honesty cases
(:func:`fitting.synth.generate.default_cases`), or with ``--oov`` five effects in no vocabulary
and clean data with covariates (:func:`fitting.synth.generate_oov.oov_cases`). The data are
simulated independently of the diagnosis's effect code; the blind benchmarks
(``benchmarks/bench_diagnose.py``, ``bench_discover.py``) run the diagnosis on them.
"""

from pathlib import Path

from cstiffjax.commands.common import check_outputs, output_folder, write_json

NAME = "generate"
HELP = "write generated recordings with concealed effects and their answer key"


def add_arguments(p) -> None:
    p.add_argument("--out", help="output folder (one sub-folder per case, and key.json)")
    p.add_argument("--samples", type=int, default=90, help="samples per case (default 90)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first case (case i uses seed + i)")
    p.add_argument("--cases", nargs="*", help="case names (default all); see --list")
    p.add_argument("--oov", action="store_true", help="the out-of-vocabulary cases instead of the vocabulary's")
    p.add_argument("--list", action="store_true", help="list the case names and stop")


def _cases(oov: bool):
    """``(cases, write)``: the case list and its writer ``(case, folder, n, seed) -> key``."""
    if oov:
        from fitting.synth.generate_oov import oov_cases, write_oov_case

        return oov_cases(), write_oov_case
    from fitting.synth.generate import default_cases, write_case

    return default_cases(), write_case


def run(args) -> int:
    cases, write = _cases(args.oov)
    if args.list:
        print("\n".join(c.name for c in cases))
        return 0
    if not args.out:
        raise ValueError("--out DIR is required (or --list)")
    names = [c.name for c in cases] + ["key.json"]  # everything the output folder may hold
    if args.cases:
        unknown = sorted(set(args.cases) - {c.name for c in cases})
        if unknown:
            raise ValueError(f"unknown case(s) {unknown}; see cstiffjax generate{' --oov' * args.oov} --list")
        cases = [c for c in cases if c.name in args.cases]
    if args.samples < 1:
        raise ValueError(f"--samples must be at least 1, got {args.samples}")
    out = Path(args.out)
    check_outputs(folders={"--out": (out, ["key.json"])})
    keys = []
    with output_folder(out, names) as tmp:  # the cases and their key appear together, or not at all
        for i, c in enumerate(cases):
            keys.append(write(c, tmp / c.name, args.samples, args.seed + i))
            if not args.quiet:
                print(f"simulated {c.name}")
        write_json(tmp / "key.json", keys)
    print(f"{len(keys)} cases and their answer key in {out}")
    return 0
