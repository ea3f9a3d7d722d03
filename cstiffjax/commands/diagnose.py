"""Diagnose what a robot description leaves out of its recordings.

Calibrates the nominal model (EA free), locates where the residual sits (channel, input
or covariate it follows, workspace region, sample order), fits every candidate effect of
the vocabulary (cable_mass, anchor_offset, length_offset, length_drift,
tension_sensor_bias, pose_frame_offset, exit_friction, nonlinear_elasticity,
platform_mass), selects by ΔBIC, held-out error and parameter identifiability, iterates
for a second effect, and reports. Gross outliers are flagged and left out. When no
candidate explains the structure, the verdict is "explained": false, never a forced label.

With no arguments it runs on a bundled example that conceals an effect
(concealed/robot.toml + concealed/recordings.csv) and writes its report to ./diagnosis/.
"""

import json
import sys

from ..examples import example_path
from ..recordings import load_recordings
from ..robot_io import load_robot
from ._common import resolve_path

NAME = "diagnose"
HELP = "find the physics a robot description leaves out of its recordings (formats.md §3)"


def add_arguments(p):
    p.add_argument("robot", nargs="?", help="robot description TOML (default: the bundled concealed example)")
    p.add_argument("recordings", nargs="?", help="recordings CSV (default: the bundled concealed example)")
    p.add_argument("--json", metavar="OUT", help="write the diagnosis JSON (formats.md §3) to OUT")
    p.add_argument("--report", metavar="DIR", help="write report.md, diagnosis.json and figures into DIR")
    p.add_argument("--law", choices=("spring", "catenary"), default="spring", help="baseline cable law")
    p.add_argument("--drop-invalid", action="store_true", help="drop invalid rows instead of failing")
    p.add_argument("--no-outliers", action="store_true", help="do not flag and leave out gross outliers")
    p.add_argument("--quiet", action="store_true", help="print only the verdict line")


def run(args) -> int:
    from fitting.diagnose import diagnose  # lazy: fitting imports cstiffjax, never the reverse
    from fitting.report import write_json, write_report

    if (args.robot is None) != (args.recordings is None):
        raise ValueError("give both ROBOT.toml and RECORDINGS.csv, or neither (bundled example)")
    if args.robot is None:
        robot_path, rec_path = example_path("concealed/robot.toml"), example_path("concealed/recordings.csv")
        args.report = args.report or "diagnosis"  # the main job: leave a report to look at
    else:
        robot_path, rec_path = resolve_path(args.robot), resolve_path(args.recordings)
    robot = load_robot(robot_path)
    rec = load_recordings(rec_path, robot, drop_invalid=args.drop_invalid)
    if not args.quiet:
        print(f"diagnosing {rec.num_samples} samples of '{robot.name}' ({robot_path}, {rec_path}) ...",
              file=sys.stderr)
    d = diagnose(robot, rec, law=args.law, detect_outliers=not args.no_outliers)
    doc = None
    if args.report:
        path = write_report(d, args.report)
        print(f"report: {path}", file=sys.stderr)
    if args.json:
        doc = write_json(d, args.json)
    verdict = (f"effects: {d.effects or 'none'}; explained: {str(d.explained).lower()}; "
               f"chi2/dof {d.baseline['chi2_per_dof']:.4g} -> {d.final['chi2_per_dof']:.4g}; "
               f"outliers: {d.outliers or 'none'}; {d.elapsed_s:.1f} s")
    print(verdict)
    for e in d.discovered:  # issue 15: corrections found outside the vocabulary
        print(f"discovered: {e['term']} ({e['interpretation']})")
    if not args.quiet and doc is None:
        from fitting.report import _default, _finite

        print(json.dumps(_finite({k: v for k, v in d.to_json().items()
                                  if k in ("baseline", "localization", "effects", "discovered", "explained", "final")}),
                         indent=1, default=_default))
    return 0
