"""Forward statics: where the platform settles on cables of given unstrained lengths, under
its weight and an external wrench, for any number of cables.

  cstiffjax statics ROBOT --lengths L1 ... Lm [--law LAW] [--wrench FX FY FZ MX MY MZ]
                          [--start X Y Z RX RY RZ] [--json OUT]

--lengths are the unstrained lengths of the cable paths (anchor, or pulley entry point, to
attachment), m, one per [[cables]] table in order: the true lengths (no winch gain, no
relative-length zero is applied). --law: spring (default; one-sided), bilateral, small_sag,
catenary (cables with mass hang in their elastic catenary) or ideal (inextensible; 6 cables
or more). The solve is cstiffjax.statics.forward.forward_statics, cold start: from --start,
else from the ideal-cable pose of the lengths, or with fewer than 6 cables from the pose of
least potential energy (where a suspended platform hangs).

Prints the pose, the tensions at the exit points (and at the platform where they differ:
heavy cables), the slack cables, the residual wrench, the stiffness K = -dW/dx there (the
weight's term included; rows N, N·m; columns m, rad of a base-frame twist) and the stability
verdict: the equilibrium is stable when the symmetric part of K, rotations scaled by the
platform's size (every entry N/m), is positive definite (cstiffjax.statics.suspended.is_stable).
Inextensible cables (--law ideal) have no elastic stiffness: K and the verdict are left out.

Exit codes: 0 a stable equilibrium; 2 none found (the solve did not converge, e.g. every
cable slack: the lengths cannot hold the platform), or the one found is unstable (a saddle,
or a direction with no restoring force: the message gives the pose and the least scaled
eigen-stiffness); 1 bad input (as many lengths as cables, each > 0; a law the robot cannot
take). --json is written only with exit 0.
"""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from cstiffjax.cable.laws import CableLaw, law_names
from cstiffjax.commands.common import (
    check_input_status,
    check_outputs,
    finite_float,
    format_matrix,
    resolve_path,
    write_json,
)
from cstiffjax.core.errors import NoAnswerError
from cstiffjax.core.status import Status, code, describe
from cstiffjax.core.text import terminal
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.equilibrium import equilibrium_stiffness
from cstiffjax.statics.forward import StaticsProblem, forward_statics, wrench_scale
from cstiffjax.statics.suspended import is_stable, platform_size, scaled_stiffness

NAME = "statics"
HELP = "forward statics: the pose, tensions, stiffness and stability where the platform settles for given lengths"


def add_arguments(p):
    p.add_argument("robot", help="robot description TOML (or a bundled example name)")
    p.add_argument("--lengths", nargs="+", type=finite_float, required=True, metavar="L",
                   help="unstrained cable lengths, m, one per cable in the order of the [[cables]] tables")
    p.add_argument("--law", default=CableLaw.spring.name, metavar="LAW",
                   help=f"cable law: {law_names(CableLaw)} (default spring)")
    p.add_argument("--wrench", nargs=6, type=finite_float, default=None, metavar="W",
                   help="external wrench fx fy fz mx my mz on the platform, N and N·m (the weight is added)")
    p.add_argument("--start", nargs=6, type=finite_float, default=None, metavar=("X", "Y", "Z", "RX", "RY", "RZ"),
                   help="start pose of the solve, m and rad (default: see above)")
    p.add_argument("--json", metavar="OUT", help="write the equilibrium as JSON (cstiffjax/io/outputs.md)")


@eqx.filter_jit
def _solve(robot, l0, external, start, law: CableLaw):
    """``(ForwardStatics, K (6, 6) or None, stable or None, scaled K)`` in one program."""
    problem = StaticsProblem(robot, l0, external, law)
    fs = forward_statics(problem, pose0=start, throw=False, derivatives=False)
    if law is CableLaw.ideal:
        return fs, None, None, None
    K = equilibrium_stiffness(problem, fs)
    size = platform_size(robot)
    return fs, K, is_stable(K, size, wrench_scale(robot, external)), scaled_stiffness(K, size)


def _lengths(robot, values) -> np.ndarray:
    """The ``--lengths`` as an array, checked: one per cable, each > 0 (``ValueError`` naming the value)."""
    if len(values) != robot.num_cables:
        raise ValueError(f"--lengths: got {len(values)} value(s), robot {robot.name!r} has {robot.num_cables} cables "
                         f"(one unstrained length per cable, m, in the order of its [[cables]] tables)")
    for i, v in enumerate(values, 1):
        if not v > 0:
            raise ValueError(f"--lengths: cable {i}: {v:g} m; every unstrained length must be > 0 m")
    return np.asarray(values, dtype=float)


def run(args) -> int:
    robot_path = resolve_path(args.robot)
    check_outputs((robot_path,), files={"--json": args.json})
    robot = load_robot(robot_path)
    if robot.kind != "cdpr":
        raise ValueError(f"statics solves cable-driven parallel robots; {robot.name!r} is a {robot.kind} "
                         f"(see cstiffjax csjm)")
    law = CableLaw.parse(args.law)
    l0 = _lengths(robot, args.lengths)
    wrench = np.zeros(6) if args.wrench is None else np.asarray(args.wrench, dtype=float)
    start = None if args.start is None else jnp.asarray(args.start, dtype=jnp.float64)
    unnamed = dataclasses.replace(robot, name="robot")  # static name: robots of one shape share the program
    fs, K, stable, Ks = _solve(unnamed, jnp.asarray(l0), jnp.asarray(wrench), start, law)
    given = "--lengths " + " ".join(f"{v:g}" for v in l0)
    check_input_status(fs.result, given)
    pose = np.asarray(fs.pose)
    slack = [i + 1 for i in np.flatnonzero(np.asarray(fs.slack))]
    if len(slack) == robot.num_cables or code(fs.result) not in (code(Status.successful), code(Status.unstable)):
        raise NoAnswerError(_no_equilibrium(robot, given, fs, slack))
    eig = None if Ks is None else np.linalg.eigvalsh(np.asarray(Ks))
    if code(fs.result) == code(Status.unstable) or (stable is not None and not bool(stable)):
        raise NoAnswerError(
            f"the equilibrium found for {given} at pose {np.round(pose, 6).tolist()} is unstable: its stiffness "
            f"(the weight's term included, rotations scaled by the platform size {float(platform_size(robot)):.4g} m) "
            f"has the least eigenvalue {eig[0]:.4g} N/m (a saddle, or a direction with no restoring force): the "
            f"platform does not settle there; try another --start or other lengths")
    out = _report(robot, law, l0, wrench, fs, K, eig, slack)
    if args.json:
        write_json(args.json, out)
        print(terminal(f"wrote {args.json}"))
    return 0


def _no_equilibrium(robot, given, fs, slack) -> str:
    """The message of a solve that found no equilibrium, naming the slack cables where it stopped."""
    why = describe(fs.result)
    pose = np.asarray(fs.pose)
    where = f"pose {np.round(pose, 4).tolist()}" if np.all(np.isfinite(pose)) else "the solve diverged"
    if len(slack) == robot.num_cables:
        return (f"no equilibrium for {given}: every cable is slack where the solve stopped ({where}; solver: "
                f"{why}): these lengths are too long to hold the platform")
    cables = f"; cables {', '.join(map(str, slack))} slack there" if slack else ""
    return f"no equilibrium found for {given}: {why} ({where}{cables}); try --start near where the platform settles"


def _report(robot, law, l0, wrench, fs, K, eig, slack) -> dict:
    """Print the equilibrium; return its JSON document (cstiffjax/io/outputs.md, ``statics``)."""
    pose, t, t_att = (np.asarray(v) for v in (fs.pose, fs.tensions, fs.tensions_attachment))
    print(f"robot {terminal(robot.name)}: {robot.num_cables} cables, law {law.name}")
    print("pose [m, rad]:", " ".join(f"{v:.6g}" for v in pose))
    print("tensions at the exit points [N]:", " ".join(f"{v:.5g}" for v in t))
    if not np.allclose(t, t_att, rtol=1e-9, atol=1e-12):
        print("tensions at the platform [N]:", " ".join(f"{v:.5g}" for v in t_att))
    print("slack cables: " + (", ".join(map(str, slack)) if slack else "none"))
    print(f"residual wrench |W| = {float(np.linalg.norm(np.asarray(fs.residual))):.3g} N")
    out = {"robot": robot.name, "cables": robot.num_cables, "law": law.name, "lengths": l0, "wrench": wrench,
           "pose": pose, "tensions": t, "tensions_attachment": t_att, "slack_cables": slack,
           "residual": fs.residual, "status": describe(fs.result), "steps": fs.num_steps,
           "stable": None, "K": None, "scaled_eigenvalues": None, "platform_size_m": float(platform_size(robot))}
    if K is None:
        print("stability: not judged (inextensible cables have no elastic stiffness)")
        return out
    print("K (rows f[N], m[N·m]; columns dx[m], dtheta[rad]):")
    print(format_matrix(np.asarray(K)))
    print(f"stable: the scaled stiffness's eigenvalues are all positive, least {eig[0]:.4g} N/m "
          f"(rotations at the platform size {out['platform_size_m']:.4g} m)")
    out.update(stable=True, K=K, scaled_eigenvalues=eig)
    return out
