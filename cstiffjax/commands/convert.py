"""Convert a CASPR robot model (its *_bodies.xml and *_cables.xml) into a robot TOML.

One rigid platform on a SPATIAL_EULER_XYZ joint, driven by cable_ideal or cable_linear_spring
cables between a base point (link 0) and a platform point (link 1), maps onto the robot
description of formats.md §1. Multi-link bodies, planar/spherical/other joints, pulleys,
via points and passive or variable-stiffness cables are refused with the file, line, element
and value. What CASPR does not hold comes from the options, and every value not read from the
files is printed under "assumed":

  --ea N             axial stiffness E*A of every cable (required for cable_ideal cables, which
                     are rigid in CASPR; a cable_linear_spring's <K> is its E*A otherwise)
  --noise P R T      noise sigmas (m, rad, N); default 1e-4 1e-3 1.0, placeholders
  --gravity          default CASPR's own, [0, 0, -9.81] m/s^2
  --mass-per-length  default 0 (CASPR's cables are massless)
  --tension-limits   default the files' force_min/force_max (the strictest when they differ)

The platform frame is CASPR's link-1 joint frame: a CASPR pose q = [x y z a b c] is our pose
[x y z] + the joint's parent location, with the rotation vector of Rx(a) Ry(b) Rz(c); the
command prints the pose of the model's q_initial and the structure matrix rank there. See
cstiffjax/io/caspr.md.
"""

import tomllib

import numpy as np

from cstiffjax.commands.common import EXIT_OK, check_outputs, finite_float, write_text
from cstiffjax.core.text import terminal
from cstiffjax.io.caspr import read_caspr
from cstiffjax.io.robot import robot_summary
from cstiffjax.io.robot_io import robot_from_dict, robot_to_toml

NAME = "convert"
HELP = "convert a CASPR model (bodies + cables XML) into a robot TOML"
COMPILES = False


def add_arguments(p):
    p.add_argument("bodies", help="CASPR bodies file (*_bodies.xml)")
    p.add_argument("cables", help="CASPR cables file (*_cables.xml)")
    p.add_argument("--out", required=True, metavar="ROBOT.toml", help="robot description to write")
    p.add_argument("--cable-set", metavar="ID", help="<cable_set id> to convert (default: the file's "
                   "default_cable_set, else its first)")
    p.add_argument("--ea", type=finite_float, metavar="N", help="axial stiffness E*A of every cable, N")
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
    check_outputs((args.bodies, args.cables), files={"--out": args.out})
    if args.noise is not None and min(args.noise) <= 0:
        raise ValueError(f"--noise {' '.join(f'{v:g}' for v in args.noise)}: every sigma must be > 0")
    if args.mass_per_length < 0:
        raise ValueError(f"--mass-per-length {args.mass_per_length:g}: must be >= 0 (kg/m)")
    model = read_caspr(args.bodies, args.cables, cable_set=args.cable_set, ea=args.ea, name=args.name,
                       gravity=args.gravity, noise=args.noise, mass_per_length=args.mass_per_length,
                       tension_limits=args.tension_limits)
    text = robot_to_toml(model.robot)
    robot = robot_from_dict(tomllib.loads(text), args.out, text)  # what load_robot will read back
    print(f"CASPR model {terminal(args.bodies)} + {terminal(args.cables)}, cable set {terminal(model.cable_set)}")
    print(terminal(robot_summary(robot)))
    for note in model.assumptions:
        print(f"assumed: {terminal(note)}")
    if model.initial_pose is not None:
        from cstiffjax.statics.geometry import structure_matrix_closed_form  # lazy: JAX only here

        pose = model.initial_pose
        S = np.asarray(structure_matrix_closed_form(robot, pose))
        rank = int(np.linalg.matrix_rank(S))
        print(f"CASPR q_initial = pose {' '.join(f'{v:.6g}' for v in pose)}; structure matrix rank {rank} of 6"
              + ("" if rank == 6 else " (the platform cannot be held there)"))
    write_text(args.out, text)
    print(f"wrote {terminal(args.out)}")
    return EXIT_OK
