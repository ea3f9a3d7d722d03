"""Diagnose what a robot description leaves out of its recordings.

Calibrates the nominal model (EA free), locates where the residual sits (channel, input
or covariate it follows, workspace region, sample order), fits every candidate effect of
the vocabulary (cable_mass, anchor_offset, length_offset, length_drift,
tension_sensor_bias, pose_frame_offset, exit_friction, nonlinear_elasticity,
platform_mass), selects by ΔBIC, held-out error and parameter identifiability, iterates
for a second effect, and reports. Gross outliers are flagged and left out. When no
candidate explains the structure, the verdict is "explained": false, never a forced label.

With no arguments it runs on a bundled example that conceals an effect
(concealed/robot.toml + concealed/recordings.csv). Without --report and --json the report
(report.md, diagnosis.json, figures) goes to ./diagnosis/, as for the bundled example.
"""

import sys
from pathlib import Path

import numpy as np

from cstiffjax.cable.laws import CableLaw
from cstiffjax.commands.common import check_outputs, report_problems, resolve_path
from cstiffjax.core.text import terminal
from cstiffjax.examples import example_path
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot_io import load_robot
from fitting.calibration.models import FIT_LAWS

NAME = "diagnose"
DEFAULT_REPORT = "diagnosis"  # the report folder when neither --report nor --json is given
REPORT_FILES = ("report.md", "diagnosis.json", "residuals.png", "chi2_shares.png")  # written by --report DIR
HELP = "find the physics a robot description leaves out of its recordings (formats.md §3)"


def add_arguments(p):
    p.add_argument("robot", nargs="?", help="robot description TOML (default: the bundled concealed example)")
    p.add_argument("recordings", nargs="?", help="recordings CSV (default: the bundled concealed example)")
    p.add_argument("--json", metavar="OUT", help="write the diagnosis JSON (formats.md §3) to OUT")
    p.add_argument("--report", metavar="DIR",
                   help="write report.md, diagnosis.json and figures into DIR (default ./diagnosis when --json "
                        "is not given either)")
    p.add_argument("--law", choices=[law.name for law in CableLaw if law in FIT_LAWS], default="spring",
                   help="baseline cable law")
    p.add_argument("--drop-invalid", action="store_true",
                   help="drop invalid rows instead of failing (reported: count and file rows)")
    p.add_argument("--sort-by-time", action="store_true",
                   help="sort the samples by the time column when it goes backwards (else that is an error)")
    p.add_argument("--no-outliers", action="store_true", help="do not flag and leave out gross outliers")
    p.add_argument("--quiet", action="store_true", help="no progress bars; print only the verdict line")


def run(args) -> int:
    from fitting.diagnosis.diagnose import diagnose  # lazy: fitting imports cstiffjax, never the reverse
    from fitting.diagnosis.report import document, own_problems, write_json, write_report

    if (args.robot is None) != (args.recordings is None):
        raise ValueError("give both ROBOT.toml and RECORDINGS.csv, or neither (bundled example)")
    if args.robot is None:
        robot_path, rec_path = example_path("concealed/robot.toml"), example_path("concealed/recordings.csv")
    else:
        robot_path, rec_path = resolve_path(args.robot), resolve_path(args.recordings)
    if not args.report and not args.json:  # a run always leaves its result to look at
        args.report = DEFAULT_REPORT
        print(f"no --report DIR or --json OUT given: the report goes to ./{DEFAULT_REPORT}/", file=sys.stderr)
    check_outputs((robot_path, rec_path), files={"--json": args.json},
                  folders={"--report": (args.report, REPORT_FILES)})
    robot = load_robot(robot_path)
    rec = load_recordings(rec_path, robot, drop_invalid=args.drop_invalid)
    rows, dropped = list(rec.rows), list(rec.dropped_rows)  # file line numbers, from the loader
    if not args.quiet:
        print(terminal(f"diagnosing {rec.num_samples} samples of '{robot.name}' ({robot_path}, {rec_path}) ..."),
              file=sys.stderr)
    d = diagnose(robot, rec, law=CableLaw.parse(args.law), detect_outliers=not args.no_outliers,
                 sort_by_time=args.sort_by_time, rows=rows, dropped_rows=dropped)
    if d.sorted_by_time:
        print("note: the time column went backwards; samples sorted by time (--sort-by-time)", file=sys.stderr)
    for name in d.effects:  # an assumption behind a selected effect (the pulley axes of a plain description)
        if name in d.assumptions:
            print(f"note: {d.assumptions[name]}", file=sys.stderr)
    # the result is written first, whatever its own check finds (reported below, exit 3)
    doc = document(d)
    problems = own_problems(doc)
    notes = [w for w in doc.get("warnings", []) if w not in problems]
    files = []
    if args.json:
        write_json(d, args.json, doc)
        files.append(str(args.json))
    if args.report:
        write_report(d, args.report, doc, problems)
        files.append(f"{Path(args.report)}/ (report.md, diagnosis.json, figures)")
    if args.quiet:
        lines = [f"effects: {d.effects or 'none'}; explained: {str(d.explained).lower()}; "
                 f"chi2/dof {d.baseline['chi2_per_dof']:.4g} -> {d.final['chi2_per_dof']:.4g}; "
                 f"outliers: {d.outliers or 'none'}{_left_out(d)}; {d.elapsed_s:.1f} s"]
        lines += [f"discovered: {e['term']} ({e['interpretation']})" for e in d.discovered]  # outside the vocabulary
    else:
        lines = summary(d, files)
    print("\n".join(map(terminal, lines)))  # text from the inputs (names) cannot forge a line
    return report_problems(NAME, problems, notes)


def _left_out(d) -> str:
    """Summary-line part naming the samples without equilibrium and the dropped rows (if any)."""
    out = ""
    if d.failed_samples["count"]:
        fs = d.failed_samples
        out += f"; no equilibrium (left out): {fs['count']} samples, " + (
            f"rows {fs['rows']}" if fs["rows"] is not None else f"samples {fs['samples']}")
    if d.dropped_rows["count"]:
        out += f"; dropped: {d.dropped_rows['count']} rows {d.dropped_rows['rows']}"
    return out


def summary(d, files=()) -> list[str]:
    """The few lines ``cstiffjax diagnose`` prints (the whole document is the JSON / report)."""
    b, f = d.baseline, d.final
    lines = [f"baseline  chi2/dof {b['chi2_per_dof']:.4g} ({b['model']} law, EA calibrated, {d.samples} samples)"]
    if d.effects:
        for e in d.effects:
            params = "; ".join(f"{nm} {_value(p)}" for nm, p in f["parameters"].get(e, {}).items())
            lines.append(f"effect    {e}: {params}")
    else:
        lines.append("effects   none selected")
    for e in d.discovered:  # corrections found outside the vocabulary
        lines.append(f"discovered {e['term']} ({e['interpretation']})")
    verdict = "yes" if d.explained else "NO: structured residual remains (see the report's 'What remains')"
    lines.append(f"explained {verdict}; final chi2/dof {f['chi2_per_dof']:.4g}")
    left = _left_out(d)
    if d.outliers or left:
        lines.append(f"left out  outlier rows {d.outliers or 'none'}{left}")
    lines.append(f"files     {', '.join(files) if files else 'none (give --report DIR or --json OUT)'}"
                 f"; {d.elapsed_s:.1f} s")
    return lines


def _value(p) -> str:
    """``value ± std unit`` of one parameter; arrays shortened to their largest entry."""
    v, s = np.ravel(p["value"]).astype(float), np.ravel(p["std"]).astype(float)
    if v.size == 1:
        return f"{v[0]:.4g} ± {s[0]:.2g} {p['unit']}"
    k = int(np.argmax(np.abs(v)))
    return f"{v.size} values, largest |{v[k]:.4g}| ± {s[k]:.2g} {p['unit']}"
