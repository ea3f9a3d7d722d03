"""Constant stiffness space (Cui et al. 2019): poses of a grid where some feasible tensions keep K
within eps of a target stiffness k_c.

k_c is the stiffness at --stiffness-at with the tensions at the centroid of its cable
tension feasible region (under --stiffness-load, default none). Every grid pose (fixed
--rotation) is then tested under --load: membership is exact (a 2-D linear feasibility
problem in the null-space coordinates). Needs a robot with 6 to 8 cables (the CTFR
centroid for k_c needs 8). Writes DIR/results.npz (axes, member, stability mu, tensions,
k_c, volume, U), DIR/summary.json and figures (3-D view, section, CTFR).
"""

import jax.numpy as jnp
import numpy as np

from cstiffjax.commands.common import (
    add_pose_grid_arguments,
    best_effort,
    check_outputs,
    finite_float,
    format_matrix,
    output_folder,
    pose_grid,
    report_problems,
    resolve_path,
    say_replacing,
    write_json,
)
from cstiffjax.core.errors import NoAnswerError
from cstiffjax.core.status import Status, describe
from cstiffjax.core.text import terminal
from cstiffjax.io.robot_io import load_robot
from cstiffjax.stiffness import css
from cstiffjax.stiffness.tensions import ctfr
from cstiffjax.workspace.sweep import sweep

NAME = "css"
OUTPUT_FILES = ("results.npz", "summary.json", "css_3d.png", "css_section.png", "ctfr.png")
HELP = "constant stiffness space over a pose grid (Cui et al. 2019)"


def add_arguments(p):
    p.add_argument("robot", help="robot description TOML (or a bundled example name, e.g. tcpr8.toml)")
    add_pose_grid_arguments(p)
    p.add_argument("--stiffness-at", nargs=6, type=finite_float, required=True,
                   metavar=("X", "Y", "Z", "RX", "RY", "RZ"), help="pose whose stiffness is the target k_c")
    p.add_argument("--stiffness-load", nargs=6, type=finite_float, default=None, metavar="W",
                   help="external wrench at the --stiffness-at pose (N, N·m); default none")
    p.add_argument("--eps", type=float, default=0.05, help="relative accuracy (default 0.05)")
    p.add_argument("--load", nargs=6, type=finite_float, default=None, metavar="W",
                   help="external wrench fx fy fz mx my mz on the grid poses (N, N·m), weight excluded")
    p.add_argument("--norm", choices=css.NORMS, default="scaled",
                   help="accuracy criterion (default scaled: |K-kc|_ij <= eps sqrt(kc_ii kc_jj))")
    p.add_argument("--inherent", choices=css.INHERENT, default="spring",
                   help="K2 = EA/l0 with spring-law l0 (default) or EA/l as in Cui et al. 2019 ('paper')")
    p.add_argument("--chunk-size", type=int, default=None,
                   help="poses per chunk (default: 65536 on a CPU, 2^20 per device on a GPU or TPU)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")


def run(args) -> int:
    from pathlib import Path

    robot_path = resolve_path(args.robot)
    check_outputs((robot_path,), folders={"--out": (args.out, OUTPUT_FILES)})
    robot = load_robot(robot_path)
    css.check_cables(robot)
    if not args.eps > 0:
        raise ValueError(f"--eps: {args.eps!r} must be > 0")
    grid = pose_grid(args)
    pose0 = jnp.asarray(args.stiffness_at)
    target = css.target_stiffness(robot, pose0, args.stiffness_load, inherent=args.inherent, throw=False)
    if target.result != Status.successful:
        raise NoAnswerError(f"--stiffness-at {list(args.stiffness_at)}: no target stiffness: {describe(target.result)}")
    kc = target.K
    load = None if args.load is None else jnp.asarray(args.load)

    def fn(poses):  # pose-minor batch (6, b): the fast form of css_point
        return css.css_point(robot, poses, kc, args.eps, load, norm=args.norm, inherent=args.inherent)

    out = sweep(fn, grid, chunk_size=args.chunk_size, vectorized=True,
                progress=False if args.no_progress else None, desc="css")
    shape = grid.shape
    member = out.member.reshape(shape)
    mu = out.stability.reshape(shape)
    summary = css.summarize(member, mu, grid.point_volumes())
    outdir, problems = Path(args.out), []
    axes = grid.axes()
    info = {"robot": robot.name, "poses": len(grid), "members": int(summary.count),
            "volume_m3": float(summary.volume), "U": float(summary.stability), "eps": args.eps,
            "norm": args.norm, "inherent": args.inherent, "stiffness_at": list(args.stiffness_at),
            "load": args.load, "kc": np.asarray(kc), "target_tensions": np.asarray(target.tensions),
            "srcc": float(target.srcc)}
    from cstiffjax.plots import css as plots_css  # lazy: matplotlib only when figures are drawn

    region = ctfr(robot, pose0, args.stiffness_load, throw=False)
    with output_folder(outdir, OUTPUT_FILES, on_replace=say_replacing) as tmp:  # whole or not at all
        np.savez_compressed(
            tmp / "results.npz", x=axes[0], y=axes[1], z=axes[2], rotation=np.asarray(args.rotation),
            member=member, stability=mu, tensions=out.tensions.reshape(*shape, -1), kc=np.asarray(kc),
            target_tensions=np.asarray(target.tensions), eps=args.eps, volume=float(summary.volume),
            U=float(summary.stability), cell_volume=grid.cell_volume,
        )
        write_json(tmp / "summary.json", info)
        best_effort(problems, tmp / "css_3d.png", lambda: plots_css.plot_css_3d(axes, member, mu, tmp / "css_3d.png",
                                                                                   robot=robot))
        best_effort(problems, tmp / "css_section.png", lambda: plots_css.plot_section(
            axes, member, mu, float(args.stiffness_at[2]), tmp / "css_section.png"))  # at the target pose's height
        best_effort(problems, tmp / "ctfr.png", lambda: plots_css.plot_ctfr(
            region, tmp / "ctfr.png", title=f"CTFR at {list(args.stiffness_at)}"))
    print(f"robot {terminal(robot.name)}: target k_c at {list(args.stiffness_at)} (psi = {float(target.srcc):.3f}),"
          f" tensions [N]: " + " ".join(f"{t:.1f}" for t in np.asarray(target.tensions)))
    print(format_matrix(kc, "{:10.2f}"))
    print(f"CSS: {int(summary.count)} of {len(grid)} poses, volume {float(summary.volume):.4g} m^3, "
          f"U = {float(summary.stability):.4f}  (eps {args.eps}, norm {args.norm}, inherent {args.inherent})")
    print(terminal(f"wrote {outdir / 'results.npz'}, summary.json, css_3d.png, css_section.png, ctfr.png"))
    return report_problems(NAME, problems)
