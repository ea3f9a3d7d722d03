"""Convert a CASPR robot model (its *_bodies.xml and *_cables.xml) into a robot TOML, or the
public IRMA4U recordings into a robot TOML and a recordings CSV.

  cstiffjax convert BODIES.xml CABLES.xml --out ROBOT.toml
  cstiffjax convert irma4u PATH --out DIR


One rigid platform on a SPATIAL_EULER_XYZ joint, driven by one or more cable_ideal or
cable_linear_spring cables from a base point (link 0) or a base_rotating_pulley (a swivel
pulley) to a platform point (link 1), maps onto the robot description of formats.md §1; fewer
than 6 cables make a suspended (under-constrained) robot. Multi-link bodies, planar/spherical/
other joints, screw-drive pulleys, via points and passive or variable-stiffness cables are
refused with the file, line, element and value. What CASPR does not hold comes from the
options, and every value not read from the files is printed under "assumed":

  --ea N             axial stiffness E*A of every cable, N (required for cable_ideal cables,
                     which are rigid in CASPR: no stiffness is made up; a cable_linear_spring's
                     <K> is its E*A otherwise)
  --noise P R T      noise sigmas (m, rad, N); default 1e-4 1e-3 1.0, placeholders
  --gravity          default CASPR's own, [0, 0, -9.81] m/s^2
  --mass-per-length  default 0 (CASPR's cables are massless)
  --tension-limits   default the files' force_min/force_max (the strictest when they differ)

The platform frame is CASPR's link-1 joint frame: a CASPR pose q = [x y z a b c] is our pose
[x y z] + the joint's parent location, with the rotation vector of Rx(a) Ry(b) Rz(c); the
command prints the pose of the model's q_initial and the structure matrix rank there, and
writes that pose as the description's [platform] reference_pose (where `check --plot` draws
the robot). See
cstiffjax/io/caspr.md.

--out may not lie inside cstiffjax's own files (the installed package, or the source checkout
it runs from): a converted model there would mix with the bundled examples and the sources.

`convert irma4u PATH --out DIR` reads a checkout of github.com/fzoffoli/UACDPR_SelfCalibration
(IRMA4U_Mar25.mat and the runs' *_parsed.mat and workspace files) and writes DIR/robot.toml and
DIR/recordings.csv (contract version 3: relative lengths, swivel angles, AHRS, three sessions,
62 samples, no external pose). --ea, --mass-per-length and --name apply; what the files do not
hold is printed under "assumed". See cstiffjax/io/irma4u.md.
"""

import tomllib
from pathlib import Path

import numpy as np

from cstiffjax.commands.common import EXIT_OK, check_outputs, finite_float, say_replacing, write_text
from cstiffjax.core.errors import OutputPathError
from cstiffjax.core.text import terminal
from cstiffjax.io.atomic import output_folder
from cstiffjax.io.caspr import read_caspr
from cstiffjax.io.irma4u import DEFAULT_EA, RUNS, read_irma4u, robot_toml
from cstiffjax.io.recordings import write_recordings
from cstiffjax.io.robot import robot_summary
from cstiffjax.io.robot_io import robot_from_dict, robot_to_toml

NAME = "convert"
HELP = "convert a CASPR model (bodies + cables XML) into a robot TOML, or the IRMA4U recordings (convert irma4u PATH)"
IRMA4U = "irma4u"
IRMA4U_FILES = ("robot.toml", "recordings.csv")
_CASPR_ONLY = ("cable_set", "gravity", "noise", "tension_limits")
COMPILES = False


def add_arguments(p):
    p.add_argument("bodies", metavar="BODIES|irma4u", help="CASPR bodies file (*_bodies.xml), or the word irma4u")
    p.add_argument("cables", metavar="CABLES|PATH", help="CASPR cables file (*_cables.xml); after irma4u: the "
                   "folder of the IRMA4U recordings (a checkout of fzoffoli/UACDPR_SelfCalibration)")
    p.add_argument("--out", required=True, metavar="ROBOT.toml|DIR", help="robot description to write; "
                   f"for irma4u: the folder to write {' and '.join(IRMA4U_FILES)} into")
    p.add_argument("--cable-set", metavar="ID", help="<cable_set id> to convert (default: the file's "
                   "default_cable_set, else its first)")
    p.add_argument("--ea", type=finite_float, metavar="N", help="axial stiffness E*A written for every cable, N: "
                   "Young's modulus x cross-section area, e.g. from the cable's datasheet (required when the "
                   "model has cable_ideal cables, which are rigid in CASPR; replaces a cable_linear_spring's <K>)")
    p.add_argument("--name", help="robot name (default: the bodies file name without _bodies.xml)")
    p.add_argument("--gravity", nargs=3, type=finite_float, metavar=("GX", "GY", "GZ"),
                   help="gravity in the base frame, m/s^2 (default CASPR's 0 0 -9.81)")
    p.add_argument("--noise", nargs=3, type=finite_float, metavar=("POSITION", "ROTATION", "TENSION"),
                   help="noise sigmas: m, rad, N (default 1e-4 1e-3 1.0, placeholders)")
    p.add_argument("--mass-per-length", type=finite_float, default=0.0, metavar="KG_PER_M",
                   help="cable mass per length, kg/m (default 0: massless, as in CASPR)")
    p.add_argument("--tension-limits", nargs=2, type=finite_float, metavar=("MIN", "MAX"),
                   help="tension limits, N (default: the files' force_min/force_max)")


def run(args) -> int:
    if args.bodies == IRMA4U:
        return _run_irma4u(args)
    refuse_source_tree("--out", args.out)
    check_outputs((args.bodies, args.cables), files={"--out": args.out})
    if args.noise is not None and min(args.noise) <= 0:
        raise ValueError(f"--noise {' '.join(f'{v:g}' for v in args.noise)}: every sigma must be > 0")
    if args.mass_per_length < 0:
        raise ValueError(f"--mass-per-length {args.mass_per_length:g}: must be >= 0 (kg/m)")
    model = read_caspr(args.bodies, args.cables, cable_set=args.cable_set, ea=args.ea, name=args.name,
                       gravity=args.gravity, noise=args.noise, mass_per_length=args.mass_per_length,
                       tension_limits=args.tension_limits)
    text = robot_to_toml(model.robot, model.initial_pose)  # q_initial: the description's reference_pose
    robot = robot_from_dict(tomllib.loads(text), args.out, text)  # what load_robot will read back
    print(f"CASPR model {terminal(args.bodies)} + {terminal(args.cables)}, cable set {terminal(model.cable_set)}")
    print(terminal(robot_summary(robot)))
    for note in model.assumptions:
        print(f"assumed: {terminal(note)}")
    full = min(6, robot.num_cables)
    if full < 6:
        print(f"{robot.num_cables} cables: under-constrained, the platform's weight closes the equilibrium "
              "(a suspended robot: cstiffjax/README.md, 'Suspended robots')")
    if model.initial_pose is not None:
        from cstiffjax.statics.geometry import structure_matrix_closed_form  # lazy: JAX only here

        pose = model.initial_pose
        S = np.asarray(structure_matrix_closed_form(robot, pose))
        rank = int(np.linalg.matrix_rank(S))
        print(f"CASPR q_initial = pose {' '.join(f'{v:.6g}' for v in pose)} (written as [platform] reference_pose); "
              f"structure matrix rank {rank} of {full}"
              + ("" if rank == full else " (the platform cannot be held there)"))
    write_text(args.out, text)
    print(f"wrote {terminal(args.out)}")
    return EXIT_OK


def _run_irma4u(args) -> int:
    given = [f"--{k.replace('_', '-')}" for k in _CASPR_ONLY if getattr(args, k) is not None]
    if given:
        raise ValueError(f"{', '.join(given)}: option(s) of CASPR models only; convert irma4u takes --ea, "
                         f"--mass-per-length and --name")
    if args.ea is not None and args.ea <= 0:
        raise ValueError(f"--ea {args.ea:g}: must be > 0 (N)")
    if args.mass_per_length < 0:
        raise ValueError(f"--mass-per-length {args.mass_per_length:g}: must be >= 0 (kg/m)")
    root = Path(args.cables)
    inputs = [root / r.log for r in RUNS] + [root / r.workspace for r in RUNS]
    refuse_source_tree("--out", args.out)
    check_outputs(inputs, folders={"--out": (args.out, IRMA4U_FILES)})
    data = read_irma4u(root, ea=DEFAULT_EA if args.ea is None else args.ea, mass_per_length=args.mass_per_length,
                       name=args.name or IRMA4U)
    session = data.columns["session"]
    print(f"IRMA4U recordings {terminal(str(root))}: {session.size} samples, "
          + ", ".join(f"session {i} = {n} ({int(np.sum(session == i))})" for i, n in enumerate(data.runs)))
    for note in data.assumptions:
        print(f"assumed: {terminal(note)}")
    with output_folder(Path(args.out), IRMA4U_FILES, on_replace=say_replacing) as tmp:  # whole or not at all
        write_text(tmp / IRMA4U_FILES[0], robot_toml(data))
        write_recordings(data.columns, tmp / IRMA4U_FILES[1])
    robot_file, recordings_file = (terminal(str(Path(args.out) / f)) for f in IRMA4U_FILES)
    print(terminal(f"wrote {robot_file} and {recordings_file}"))
    return EXIT_OK


def refuse_source_tree(option: str, out) -> None:
    """Refuse an output path inside cstiffjax's own files: the installed package's folder, or
    the source checkout it runs from (the folder above it holding cstiffjax's pyproject.toml).

    **Arguments:** ``option``: the option's name for the message; ``out``: the path given.

    **Raises:** :class:`~cstiffjax.core.errors.OutputPathError` naming the path and the folder.
    """
    package = Path(__file__).resolve().parents[1]  # cstiffjax/commands/convert.py -> cstiffjax
    checkout = package.parent
    project = checkout / "pyproject.toml"
    roots = [package]
    try:
        if project.is_file() and tomllib.loads(project.read_text()).get("project", {}).get("name") == "cstiffjax":
            roots.append(checkout)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        pass  # not readable as cstiffjax's project file: not its checkout
    target = Path(out).resolve()
    for root in roots:
        if target == root or root in target.parents:
            what = "the installed cstiffjax package" if root == package else "cstiffjax's source checkout"
            raise OutputPathError(f"{option} {out}: lies inside {what} ({root}); converted models are your "
                                  "data: write them to a folder of your own, outside it")
