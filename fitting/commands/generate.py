"""Write generated recordings sets with concealed effects and their answer key.

``cstiffjax generate --out DIR`` writes one folder per case, ``DIR/CASE/robot.toml`` (the
nominal description) and ``DIR/CASE/recordings.csv`` (formats.md §2), plus ``DIR/key.json``
(what each case conceals; layout in ``cstiffjax/io/outputs.md``): the vocabulary's effects,
clean data and the honesty cases
(:func:`fitting.synth.generate.default_cases`), or with ``--oov`` five effects in no vocabulary
and clean data with covariates (:func:`fitting.synth.generate_oov.oov_cases`). The data are
simulated independently of the diagnosis's effect code; the blind benchmarks
(``benchmarks/bench_diagnose.py``, ``bench_discover.py``) run the diagnosis on them.

A case's data depend on ``--seed`` and its name only (:func:`fitting.synth.generate.case_seed`),
not on the other cases asked for. Into a folder that already holds a ``key.json`` the new
cases are added: the earlier cases and their key entries are kept, a case generated again
replaces its folder and its key entry, and each replaced case is named.
"""

import json
from pathlib import Path

from cstiffjax.commands.common import check_outputs, output_folder, say_replacing, write_json
from cstiffjax.core.text import terminal

NAME = "generate"
HELP = "write generated recordings with concealed effects and their answer key"


def add_arguments(p) -> None:
    p.add_argument("--out", help="output folder (one sub-folder per case, and key.json)")
    p.add_argument("--samples", type=int, default=90, help="samples per case (default 90)")
    p.add_argument("--seed", type=int, default=0,
                   help="base seed (default 0): each case's seed is a hash of it and the case name, so a case's "
                        "data do not depend on the other cases asked for")
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


def _earlier_key(path: Path) -> list[dict]:
    """The answer key already in the output folder (``[]`` when there is none).

    **Raises:** ``ValueError`` naming the file when it is not a generated answer key (a JSON
    list of objects each with a ``"case"`` string).
    """
    if not path.exists():
        return []
    try:
        key = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not an answer key written by cstiffjax generate ({e}); move it away or choose "
                         "another --out") from None
    if not isinstance(key, list) or not all(isinstance(k, dict) and isinstance(k.get("case"), str) for k in key):
        raise ValueError(f"{path}: not an answer key written by cstiffjax generate (expected a list of objects with "
                         "a \"case\" name); move it away or choose another --out")
    return key


def run(args) -> int:
    from fitting.synth.generate import case_seed

    cases, write = _cases(args.oov)
    if args.list:
        print("\n".join(c.name for c in cases))
        return 0
    if not args.out:
        raise ValueError("--out DIR is required (or --list)")
    if args.cases:
        unknown = sorted(set(args.cases) - {c.name for c in cases})
        if unknown:
            raise ValueError(f"unknown case(s) {unknown}; see cstiffjax generate{' --oov' * args.oov} --list")
        cases = [c for c in cases if c.name in args.cases]
    if args.samples < 1:
        raise ValueError(f"--samples must be at least 1, got {args.samples}")
    out = Path(args.out)
    check_outputs(folders={"--out": (out, ["key.json"])})
    earlier = _earlier_key(out / "key.json") if out.is_dir() else []
    names = [c.name for c in cases] + ["key.json"]  # what this run replaces; other cases there are kept
    keys = []
    with output_folder(out, names, on_replace=say_replacing) as tmp:  # cases and key together
        for c in cases:
            entry = write(c, tmp / c.name, args.samples, case_seed(args.seed, c.name))
            keys.append({**entry, "base_seed": args.seed})
            if not args.quiet:
                print(f"simulated {c.name}")
        new = {k["case"] for k in keys}
        merged = [k for k in earlier if k["case"] not in new] + keys
        write_json(tmp / "key.json", merged)
    replaced = [k for k in earlier if k["case"] in new]
    for k in replaced:
        print(f"replaced {k['case']} (earlier: seed {k.get('seed')}, {k.get('samples')} samples) in {out}")
    print(terminal(f"wrote {len(keys)} case folder(s) (robot.toml, recordings.csv) in {out}: " + " ".join(sorted(new))))
    kept = len(merged) - len(keys)
    kept_note = f" ({kept} kept from the earlier key)" if kept else ""
    print(terminal(f"wrote {out / 'key.json'}: {len(merged)} cases{kept_note}"))
    return 0
