"""Validate a robot description and (optionally) a recordings file, and summarize them.

Every problem is reported with the file, the key or row/column, the value and what is
allowed. With --drop-invalid, rows with missing or non-numeric required values are
dropped and counted instead of being an error.
"""

import numpy as np

from ..examples import list_examples
from ..recordings import load_recordings
from ..robot import robot_summary
from ..robot_io import load_robot
from ._common import check_outputs, recordings_rows, resolve_path, write_json

NAME = "check"
HELP = "validate and summarize a robot TOML and a recordings CSV"


def add_arguments(p):
    p.add_argument("robot", nargs="?", help="robot description TOML (or a bundled example name)")
    p.add_argument("recordings", nargs="?", help="recordings CSV (optional)")
    p.add_argument("--drop-invalid", action="store_true", help="drop invalid rows instead of failing")
    p.add_argument("--json", metavar="OUT", help="also write the summary as JSON")
    p.add_argument("--list-examples", action="store_true", help="list the bundled example files")


def run(args) -> int:
    if args.list_examples or args.robot is None:
        print("bundled examples:\n  " + "\n  ".join(list_examples()))
        return 0
    robot_path = resolve_path(args.robot)
    rec_path = resolve_path(args.recordings) if args.recordings else None
    check_outputs((robot_path, rec_path), files={"--json": args.json})
    robot = load_robot(robot_path)
    print(f"robot OK: {robot_summary(robot)}")
    summary = {"robot": robot.name, "kind": robot.kind, "cables": robot.num_cables}
    if args.recordings:
        rec = load_recordings(rec_path, robot, drop_invalid=args.drop_invalid)
        n = rec.num_samples
        print(f"recordings OK: {n} samples, {robot.num_cables} cables, "
              f"tensions {'recorded' if rec.has_tensions else 'not recorded'}")
        dropped = (recordings_rows(rec_path, rec) or (None, list(rec.dropped_rows)))[1]  # file line numbers
        if dropped:
            print(f"  dropped {len(dropped)} invalid row(s), file lines {dropped}")
        if rec.covariate_names:
            print(f"  covariates: {', '.join(rec.covariate_names)}")
        pose = np.asarray(rec.pose)
        lo, hi = pose.min(0), pose.max(0)
        names = ("x", "y", "z", "rx", "ry", "rz")
        for j, nm in enumerate(names):
            print(f"  {nm:>2}: {lo[j]: .5g} .. {hi[j]: .5g}")
        summary.update(samples=n, dropped_rows=dropped,
                       covariates=list(rec.covariate_names), pose_min=lo, pose_max=hi)
    if args.json:
        write_json(args.json, summary)
    return 0
