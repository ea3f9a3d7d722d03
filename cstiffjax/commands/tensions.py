"""Tension distribution at one pose: closed-form (cfm), improved closed-form (icfm),
Dykstra's projection (dykstra) or a QP (qp, --objective 2-norm or max).

The tensions hold the platform weight plus --wrench (N, N·m about the reference point,
base frame) within [tension_min, tension_max]. Every method gives the same answer where
the tensions closest to the mid tension (tension_min + tension_max)/2 are feasible (with 6
cables: the unique balancing tensions); qp --objective max minimizes the largest tension
instead, and icfm, a heuristic, may report infeasible where other methods find tensions.
A redundant robot (more than 6 cables) needs a finite [limits] tension_max for every
method but qp --objective max. Exit 2 (no valid answer) when the pose is infeasible or a
method cannot answer; the message says which. See cstiffjax.stiffness.tension_methods.
"""

import jax.numpy as jnp
import numpy as np

from cstiffjax.commands.common import (
    EXIT_NO_ANSWER,
    EXIT_OK,
    add_robot_pose_arguments,
    check_input_status,
    check_outputs,
    finite_float,
    pose_option,
    resolve_path,
    write_json,
)
from cstiffjax.core.errors import NoAnswerError
from cstiffjax.core.status import describe
from cstiffjax.core.text import terminal
from cstiffjax.io.robot_io import load_robot
from cstiffjax.stiffness.tension_methods import METHODS, OBJECTIVES, distribute_tensions, needs_finite_max

NAME = "tensions"
HELP = "tension distribution at a pose (cfm, icfm, dykstra, qp)"


def add_arguments(p):
    add_robot_pose_arguments(p)
    p.add_argument("--method", choices=METHODS, required=True, help="tension distribution method")
    p.add_argument("--objective", choices=OBJECTIVES, default="2-norm",
                   help="qp objective: 2-norm around the mid tension (default) or min max tension")
    p.add_argument("--wrench", nargs=6, type=finite_float, default=None, metavar="W",
                   help="external wrench fx fy fz mx my mz (N, N·m), weight excluded")
    p.add_argument("--max-steps", type=int, default=20000, help="iterations of dykstra / qp (default 20000)")
    p.add_argument("--json", metavar="OUT", help="write tensions and status as JSON")


def run(args) -> int:
    robot_path = resolve_path(args.robot)
    check_outputs((robot_path,), files={"--json": args.json})
    if args.objective != "2-norm" and args.method != "qp":
        raise ValueError(f"--objective {args.objective}: only with --method qp")
    if args.max_steps < 1:
        raise ValueError(f"--max-steps: {args.max_steps} must be >= 1")
    robot = load_robot(robot_path)
    label = args.method + (f" --objective {args.objective}" if args.method == "qp" else "")
    if needs_finite_max(robot.num_cables, args.method, args.objective) and not np.isfinite(float(robot.tension_max)):
        raise NoAnswerError(f"--method {label} needs a finite [limits] tension_max for a robot with "
                            f"{robot.num_cables} cables (its target is the mid tension (tension_min + tension_max)/2); "
                            f"{robot_path} has tension_max = inf. Set [limits] tension_max, or use --method qp "
                            "--objective max")
    ext = None if args.wrench is None else jnp.asarray(args.wrench)
    out = distribute_tensions(robot, jnp.asarray(args.pose), ext, method=args.method, objective=args.objective,
                              max_steps=args.max_steps, throw=False)
    t = np.asarray(out.tensions)
    check_input_status(out.result, pose_option(args.pose))
    status = describe(out.result)
    label = args.method + (f" ({args.objective})" if args.method == "qp" else "")
    print(f"robot {terminal(robot.name)}, pose {list(args.pose)}, method {label}")
    print("tensions [N]:", " ".join(f"{v:.4f}" for v in t))
    print(f"limits [{float(robot.tension_min):g}, {float(robot.tension_max):g}] N; |S t + W| = "
          f"{float(np.linalg.norm(out.residual)):.3g}; steps {int(out.num_steps)}; status: {status}")
    if args.json:
        write_json(args.json, {"robot": robot.name, "pose": list(args.pose), "method": args.method,
                               "objective": args.objective if args.method == "qp" else None,
                               "wrench": args.wrench, "tensions": t, "residual": out.residual,
                               "status": status, "num_steps": out.num_steps})
        print(terminal(f"wrote {args.json}"))
    return EXIT_OK if status == "ok" else EXIT_NO_ANSWER
