"""Stiffness matrix K of a CDPR at a pose, its eigen-stiffnesses and directions.

K = -dW/dx by autodiff, in base-frame twist coordinates [dx dy dz dthx dthy dthz]
(rows: force N and moment N·m; columns: m and rad). Tensions default to feasible
tensions (within [tension_min, tension_max]) holding the platform weight plus --wrench,
by the rule of cstiffjax.stiffness.tensions.feasible_tensions for r = m - 6 degrees of redundancy:
r = 0 the unique solution, r = 1 the midpoint of the feasible segment, r = 2 the centroid
of the CTFR (Cui et al. 2019 Table 3), r >= 3 the tensions closest to the midpoint of the limits
(QP). With fewer than 6 cables (a suspended robot: gravity closes the equilibrium) they are
the balancing tensions of the pose, which must be an equilibrium (the least-squares answer
must balance the load; the stiffness is then that of the equilibrium, the weight's term
included). When no feasible tensions exist the command fails (exit 2: no valid answer); pass
--tensions to impose your own. Bad arguments or input files exit 1.
Eigen-stiffnesses are those of the symmetric part, with translation and rotation blocks
reported separately (their units differ).
Where the tensions balance the load (the default tensions always; given --tensions when
|S t + W| is within the balance tolerance) the pose is an equilibrium and its stability is
judged as forward statics judges it (cstiffjax.statics.suspended.is_stable: the symmetric
part of K, rotations scaled by the platform's size, positive definite): an unstable
equilibrium (e.g. a suspended platform balanced above the point its cables pull at) is
printed and written like any other, then named on stderr, and the command exits 2.
"""

import sys

import jax.numpy as jnp
import numpy as np

from cstiffjax.commands.common import (
    EXIT_NO_ANSWER,
    EXIT_OK,
    add_robot_pose_arguments,
    check_input_status,
    check_outputs,
    finite_float,
    format_matrix,
    pose_option,
    resolve_path,
    write_json,
)
from cstiffjax.core.errors import NoAnswerError
from cstiffjax.core.status import Status, describe
from cstiffjax.core.text import terminal
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.forward import wrench_scale
from cstiffjax.statics.geometry import balanced, external_wrench, gravity_wrench, inverse_statics, wrench
from cstiffjax.statics.suspended import is_stable, platform_size
from cstiffjax.stiffness.matrix import stiffness_split
from cstiffjax.stiffness.tensions import feasible_tensions

NAME = "stiffness"
HELP = "stiffness K at a pose (eigen-stiffnesses and directions)"


def add_arguments(p):
    add_robot_pose_arguments(p)
    p.add_argument("--tensions", nargs="+", type=finite_float, metavar="T", help="cable tensions N (one per cable)")
    p.add_argument("--wrench", nargs=6, type=finite_float, default=None, metavar="W",
                   help="external wrench fx fy fz mx my mz (N, N·m) for the inverse statics")
    p.add_argument("--json", metavar="OUT", help="write K, split and eigen-data as JSON")


def run(args) -> int:
    robot_path = resolve_path(args.robot)
    check_outputs((robot_path,), files={"--json": args.json})
    robot = load_robot(robot_path)
    pose = jnp.asarray(args.pose)
    if args.tensions is not None:
        if len(args.tensions) != robot.num_cables:
            raise ValueError(f"--tensions: got {len(args.tensions)} values, the robot has {robot.num_cables} cables")
        t = jnp.asarray(args.tensions)
        status = "given"
    else:
        wrench = None if args.wrench is None else jnp.asarray(args.wrench)  # an array: one compile for any value
        t, status = _default_tensions(robot, pose, wrench)
    split = stiffness_split(robot, pose, t, throw=False)
    check_input_status(split.result, pose_option(args.pose))
    if split.result != Status.successful:
        raise NoAnswerError(f"no stiffness at pose {list(args.pose)}: {describe(split.result)}")
    K = np.asarray(split.K)
    print(f"robot {terminal(robot.name)}, pose {list(args.pose)}")
    print("tensions [N]:", " ".join(f"{v:.4g}" for v in np.asarray(t)), f"({status})")
    if np.any(np.asarray(t) < 0):
        print("warning: negative tensions: cables cannot push; this pose is not feasible under this load")
    print("K (rows f[N], m[N·m]; columns dx[m], dtheta[rad]):")
    print(format_matrix(K))
    out = {"robot": robot.name, "pose": list(args.pose), "tensions": t, "K": K,
           "tension_rule": status, "K1": split.K1, "K2": split.K2, "K_gravity": split.K_gravity}
    for name, sl in (("translation", slice(0, 3)), ("rotation", slice(3, 6))):
        B = 0.5 * (K[sl, sl] + K[sl, sl].T)
        vals, vecs = np.linalg.eigh(B)
        unit = "N/m" if name == "translation" else "N·m/rad"
        print(f"{name} eigen-stiffnesses [{unit}]:")
        for v, d in zip(vals, vecs.T, strict=True):
            print(f"  {v:12.5g}  along {np.round(d, 4).tolist()}")
        out[f"{name}_eigenvalues"], out[f"{name}_eigenvectors"] = vals, vecs.T
    external = None if args.wrench is None else jnp.asarray(args.wrench)
    out["status"] = _stability(robot, pose, t, external, split.K)
    print(f"status: {out['status']}")
    if args.json:
        write_json(args.json, out)
        print(terminal(f"wrote {args.json}"))
    if out["status"] != describe(Status.unstable):
        return EXIT_OK
    print(f"pose {list(args.pose)} is an unstable equilibrium of this robot under this load: a displacement "
          f"along a direction of negative (or zero) eigen-stiffness above is not restored", file=sys.stderr)
    return EXIT_NO_ANSWER


NOT_EQUILIBRIUM = "not an equilibrium under the given tensions (|S t + W| unbalanced): stability not judged"


def _stability(robot, pose, t, external, K) -> str:
    """``"ok"`` (a stable equilibrium), ``describe(Status.unstable)``, or :data:`NOT_EQUILIBRIUM`
    when the tensions ``t`` leave the load unbalanced at ``pose`` (only given tensions can)."""
    if not balanced(float(np.linalg.norm(np.asarray(wrench(robot, pose, t, external)))),
                    _load_norm(robot, pose, external)):
        return NOT_EQUILIBRIUM
    stable = bool(is_stable(K, platform_size(robot), wrench_scale(robot, external)))
    return "ok" if stable else describe(Status.unstable)


_RULES = {0: "unique solution (no redundancy)", 1: "midpoint of the feasible segment (1 degree of redundancy)",
          2: "centroid of the CTFR (2 degrees of redundancy, Cui et al. 2019 Table 3)"}


def _default_tensions(robot, pose, wrench):
    """Feasible tensions by the documented rule and the rule's name; :class:`NoAnswerError` when
    none exist (fewer than 6 cables: also when the pose is not an equilibrium)."""
    r = robot.num_cables - 6
    rule = _RULES.get(r, f"closest to the midpoint of the limits ({r} degrees of redundancy, QP)")
    if r < 0:
        rule = (f"the balancing tensions of an equilibrium ({robot.num_cables} cables: least squares, unique "
                f"where the pose is an equilibrium)")
    ft = feasible_tensions(robot, pose, wrench, throw=False)
    check_input_status(ft.result, pose_option(pose))
    unbalanced = float(np.linalg.norm(np.asarray(ft.residual)))
    if r < 0 and ft.result == Status.infeasible and not balanced(unbalanced, _load_norm(robot, pose, wrench)):
        raise NoAnswerError(
            f"pose {np.asarray(pose).tolist()} is not an equilibrium of this {robot.num_cables}-cable robot under "
            f"this load: the least-squares tensions {' '.join(f'{v:.4g}' for v in np.asarray(ft.tensions))} N "
            f"leave |S t + W| = {unbalanced:.3g} N unbalanced (the platform hangs where gravity puts it: find that "
            f"pose for given lengths with `cstiffjax statics ROBOT --lengths L1 ... Lm`); pass --tensions to impose "
            f"your own")
    if ft.result != Status.successful:
        mn = inverse_statics(robot, pose, wrench, throw=False).tensions
        raise NoAnswerError(
            f"no feasible tensions at pose {np.asarray(pose).tolist()}: {describe(ft.result)} "
            f"(limits [{float(robot.tension_min):g}, {float(robot.tension_max):g}] N; min-norm tensions "
            f"{' '.join(f'{v:.4g}' for v in np.asarray(mn))} N); pass --tensions to impose your own")
    return ft.tensions, f"feasible tensions: {rule}"


def _load_norm(robot, pose, wrench) -> float:
    """``|W|``: the norm of the weight's wrench plus ``wrench`` at ``pose``, N / N·m."""
    return float(np.linalg.norm(np.asarray(gravity_wrench(robot, pose) + external_wrench(wrench))))
