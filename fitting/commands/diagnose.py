"""Diagnose what a robot description leaves out of its recordings.

Calibrates the nominal model (EA free), locates where the residual sits (channel, input
or covariate it follows, workspace region, sample order), then fits every candidate effect
of the vocabulary that applies to the robot and its recordings:

  cable_mass            cable weight and sag (elastic catenary instead of a massless spring)
  anchor_offset         exit points are not where the description says
  length_offset         constant error in each commanded length (encoder zero)
  length_drift          cable lengths creep with time
  tension_sensor_bias   load cells read with a constant offset
  pose_frame_offset     the pose-measurement frame is misregistered against the base
  exit_friction         measured tension depends on the direction the cable last moved
  nonlinear_elasticity  tension is not linear in strain
  platform_mass         platform mass or centre of mass differs from the description
  pulley_kinematics     the cables leave over swivel pulleys, not from fixed points
  length_gain           winch transmission (drum radius, encoder scale) differs from nominal
  tension_sensor_gain   load cells read with a gain error
  attachment_offset     platform attachment points are not where the description says

It selects by the change of BIC, the held-out error and parameter identifiability, and
iterates for a second effect. When no effect explains the structure, it searches corrections
outside the vocabulary (discovered corrections: an offset, gain or drift of a commanded
length, a load cell, a wrench or pose component or the geometry, driven by time, the sample
number, a covariate column, a wrench component or a tension) and reports them by what they
mean physically, never under an effect's name. Gross outliers are flagged and left out.
When nothing explains the structure the verdict is "explained": false, with where it sits.

With no arguments it runs on a bundled example that conceals an effect
(concealed/robot.toml + concealed/recordings.csv). The report (report.md, diagnosis.json,
figures) goes to --report DIR, or to ./diagnosis/ when neither --report nor --json is given.
The JSON layout is the diagnosis contract in cstiffjax/io/formats.md, section 3.
"""
import sys
from pathlib import Path

from cstiffjax.cable.laws import CableLaw
from cstiffjax.commands.common import check_outputs, report_problems, resolve_path, say_replacing
from cstiffjax.core.text import terminal
from cstiffjax.examples import example_path
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot_io import load_robot
from fitting.calibration.models import FIT_LAWS

NAME = "diagnose"
DEFAULT_REPORT = "diagnosis"  # the report folder when neither --report nor --json is given
REPORT_FILES = ("report.md", "diagnosis.json", "residuals.png", "chi2_shares.png")  # written by --report DIR
HELP = "find the physics a robot description leaves out of its recordings"
# XLA's CPU programs on one thread (cstiffjax.core.config.xla_threads; PJRT_NPROC or
# NPROC in the environment win): a diagnosis is thousands of calls of small programs, which a
# pool of one thread per core slows (hand-offs, spinning threads taking the cores from the
# background compilation). Bundled example, 2-core machine, alternating runs: warm 4.89 -> 4.71 s
# and 5.10 -> 4.86 s (two sittings, means of 9 and 8), cold the same within the noise, CPU -1 s
# cold and -0.7 s warm; IRMA4U cold unchanged (52.4 against 52.1 s). The same results to rounding:
# ill-conditioned estimates of rejected candidates move by up to ~1e-3 relative, every golden
# verdict stays (tests/test_golden.py, benchmarks/LATENCY.md)
XLA_THREADS = 1


def add_arguments(p):
    p.add_argument("robot", nargs="?", help="robot description TOML (default: the bundled concealed example)")
    p.add_argument("recordings", nargs="?", help="recordings CSV (default: the bundled concealed example)")
    p.add_argument("--json", metavar="OUT", help="write the diagnosis JSON (cstiffjax/io/formats.md, section 3) to OUT")
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
    from fitting.diagnosis.figure_worker import FigureWorker

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
    with FigureWorker() as figures:  # the report's figures drawn in a child process while the posterior samples
        if args.report:
            figures.start()
        d = diagnose(robot, rec, law=CableLaw.parse(args.law), detect_outliers=not args.no_outliers,
                     sort_by_time=args.sort_by_time, rows=rows, dropped_rows=dropped,
                     on_verdict=figures.submit if args.report else None)
        return _written(args, d, figures)


def _written(args, d, figures) -> int:
    """Write the diagnosis ``d`` (``--json``; ``--report``, its figures from ``figures``, a
    :class:`~fitting.diagnosis.figure_worker.FigureWorker`) and print its summary; the exit code."""
    from fitting.diagnosis.report import document, own_problems, write_json, write_report

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
    try:
        if args.json:
            write_json(d, args.json, doc)
            files.append(str(args.json))
        if args.report:
            write_report(d, args.report, doc, problems, on_replace=say_replacing, figures=figures)
            files.append(f"{Path(args.report)}/ (report.md, diagnosis.json, figures)")
    except OSError:  # an output not written (a full disk): the verdict all the same, and what was written
        asked = [str(o) for o in (args.json, args.report and f"{Path(args.report)}/") if o]
        _print_summary(args, d, [*files, f"NOT written: {', '.join(asked[len(files):])} (the error below)"])
        raise
    _print_summary(args, d, files)
    return report_problems(NAME, problems, notes)


def _print_summary(args, d, files) -> None:
    """Print the diagnosis's summary (the verdict) on stdout, ``files`` the outputs written."""
    if args.quiet:
        from fitting.diagnosis.report import left_out

        lines = [f"effects: {d.effects or 'none'}; explained: {str(d.explained).lower()}; "
                 f"chi2/dof {d.baseline['chi2_per_dof']:.4g} -> {d.final['chi2_per_dof']:.4g}; "
                 f"outliers: {d.outliers or 'none'}{left_out(d)}; {d.elapsed_s:.1f} s"]
        lines += [f"discovered: {e['term']} ({e['interpretation']})" for e in d.discovered]  # outside the vocabulary
    else:
        lines = summary(d, files)
    print("\n".join(map(terminal, lines)), flush=True)  # text from the inputs (names) cannot forge a line


def summary(d, files=()) -> list[str]:
    """The few lines ``cstiffjax diagnose`` prints (the whole document is the JSON / report)."""
    from fitting.diagnosis.report import summary_lines

    files = ", ".join(files) if files else "none (give --report DIR or --json OUT)"
    return [*summary_lines(d), f"files     {files}; {d.elapsed_s:.1f} s"]
