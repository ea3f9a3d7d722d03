"""How many of CASPR's models ``cstiffjax convert`` reads (run:
``python benchmarks/caspr_models.py CASPR_CHECKOUT [--ea N] [--all-sets]``).

CASPR (github.com/darwinlau/CASPR) lists its models in three files under
``data/model_config/``: ``models/models_list.csv``, ``indev_models/indev_models_list.csv`` and
``test_models/test_models_list.csv`` (one line per model: name, folder, bodies file, cables
file, ...). Each listed model is read with :func:`cstiffjax.io.caspr.read_caspr` (its default
cable set, ``ea`` = ``--ea``) and printed as a Markdown table row: converted (with its cable
count and whether it has pulleys) or refused (with the first words of the converter's
message). ``--all-sets`` also tries every other cable set of each model. Nothing of CASPR is
copied: the checkout is read where it lies. The counts and the table go to
``cstiffjax/io/caspr.md``.
"""

import argparse
import csv
import re
import sys
from pathlib import Path

from cstiffjax.io.caspr import CasprModelError, read_caspr

LISTS = ("models/models_list.csv", "indev_models/indev_models_list.csv", "test_models/test_models_list.csv")


REASONS = (  # (pattern of the converter's message, short reason); the first that matches
    (r"<links>: (\d+) link", r"multi-link body (\1 links)"),
    (r"<joint>: type = '(\w+)'", r"joint \1 (not a 6-DOF platform)"),
    (r"<(screw_base_rotating_pulley)> cannot be mapped", r"<\1> (a pulley that moves along its winch)"),
    (r"cable kind <(\w+)>", r"<\1> cables"),
)


def on_disk(path: Path) -> Path:
    """``path``, its components matched without regard to case where they differ (CASPR's
    lists were written on Windows: ``NIST_RoboCrane`` lies in ``NIST_ROBOCRANE``)."""
    if path.exists():
        return path
    found = Path(path.anchor)
    for part in path.parts[1:]:
        if not (found / part).exists() and found.is_dir():
            part = next((q.name for q in found.iterdir() if q.name.lower() == part.lower()), part)
        found = found / part
    return found


def listed_models(root: Path):
    """``(list, name, bodies path, cables path)`` of every model in CASPR's three lists."""
    config = root.resolve() / "data" / "model_config"
    for listing in LISTS:
        path = config / listing
        with path.open(newline="") as f:
            for row in csv.reader(f):
                if len(row) >= 4 and row[0].strip():
                    folder = path.parent / row[1].strip().strip("/")
                    yield (listing.split("/")[0], row[0].strip(), on_disk(folder / row[2].strip()),
                           on_disk(folder / row[3].strip()))


def reason(error: Exception) -> str:
    """A short reason from the converter's message (:data:`REASONS`), else its first clause."""
    text = str(error)
    for pattern, short in REASONS:
        if (match := re.search(pattern, text)) is not None:
            return match.expand(short)
    return re.sub(r"^\S+\.xml: (line \d+: )?", "", text).split("; ")[0][:160]


def try_model(bodies: Path, cables: Path, ea: float, cable_set: str | None = None):
    """``(True, description, CasprModel)`` of a converted model, or ``(False, the error, None)``."""
    try:
        model = read_caspr(bodies, cables, ea=ea, cable_set=cable_set)
    except (CasprModelError, ValueError) as e:
        return False, e, None
    r = model.robot
    pulleys = int((abs(r.pulley_radius) > 0).sum())
    text = f"{r.num_cables} cables, set {model.cable_set!r}" + (f", {pulleys} over pulleys" if pulleys else "")
    return True, text, model


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("caspr", type=Path, help="a checkout of github.com/darwinlau/CASPR")
    p.add_argument("--ea", type=float, default=1e5, help="E*A given for cable_ideal cables, N (default 1e5)")
    p.add_argument("--all-sets", action="store_true", help="also try every other cable set of each model")
    args = p.parse_args(argv)
    rows, converted = [], 0
    for listing, name, bodies, cables in listed_models(args.caspr):
        ok, what, model = try_model(bodies, cables, args.ea)
        converted += ok
        others = ""
        if args.all_sets and model is not None:
            more = [s for s in model.cable_sets if s != model.cable_set and try_model(bodies, cables, args.ea, s)[0]]
            others = f"; also {', '.join(more)}" if more else ""
        rows.append(f"| {name} | {listing} | {'converted: ' + what + others if ok else reason(what)} |")
    print(f"{converted} of {len(rows)} listed models convert (--ea {args.ea:g})\n")
    print("| model | list | result |\n|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
