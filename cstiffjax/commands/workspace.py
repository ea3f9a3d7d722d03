"""Workspace of a CDPR over a pose grid: wrench-feasible, static-equilibrium, wrench-closure or
interference-free.

--kind wrench-feasible: every wrench of the required set (--wrench-box or
--wrench-vertices; N, N·m about the platform reference point, base frame, weight added)
is held with tensions inside [tension_min, tension_max]; exact (hyperplane shifting), with
the capacity margin (N, moments divided by --length-scale); 6 to 8 cables.
--kind static-equilibrium (fewer than 6 cables): the weight and every wrench of the set
(default none) are balanced with tensions inside the limits, the platform's rotation
--orientation free (where it hangs, stable; from --rotation) or given (--rotation);
margin: how far the tensions stay from both limits (N); a robot with no upper limit
(tension_max infinite, the default) needs only taut cables (tension >= tension_min), the
margin then the distance above tension_min (+inf: unbounded, an internal force). --kind wrench-closure: the
cables positively span the wrench space (limits ignored); margin: smallest tension of the
best unit internal force. --kind interference: no two cables closer than
--cable-diameter and no cable through the platform (convex hull of the attachments;
sagging cables sampled along their catenary under --load); margin: minimum cable
distance minus the diameter (m).

Writes DIR/results.npz (axes, member, margin, ...), DIR/summary.json (volume, margins)
and figures DIR/workspace_3d.png and DIR/workspace_sections.png.
"""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from cstiffjax.commands.common import (
    add_pose_grid_arguments,
    best_effort,
    check_outputs,
    output_folder,
    pose_grid,
    report_problems,
    resolve_path,
    say_replacing,
    write_json,
)
from cstiffjax.core.status import Status
from cstiffjax.core.text import figure as figure_text
from cstiffjax.core.text import terminal
from cstiffjax.io.robot_io import load_robot
from cstiffjax.workspace.interference import interference, interference_model
from cstiffjax.workspace.static_equilibrium import ORIENTATIONS, static_equilibrium
from cstiffjax.workspace.static_equilibrium import check_robot as check_equilibrium_robot
from cstiffjax.workspace.sweep import sweep
from cstiffjax.workspace.wrench_closure import check_cables as check_closure_cables
from cstiffjax.workspace.wrench_closure import wrench_closure
from cstiffjax.workspace.wrench_feasible import WrenchSet, wrench_feasible
from cstiffjax.workspace.wrench_feasible import check_cables as check_feasible_cables

NAME = "workspace"
HELP = "wrench-feasible, static-equilibrium, wrench-closure or interference-free workspace over a pose grid"
KINDS = ("wrench-feasible", "static-equilibrium", "wrench-closure", "interference")
WRENCH_KINDS = ("wrench-feasible", "static-equilibrium")
OUTPUTS = ("results.npz", "summary.json", "workspace_3d.png", "workspace_sections.png")
_LABELS = {"wrench-feasible": "capacity margin [N]", "static-equilibrium": "tension margin [N]",
           "wrench-closure": "closure margin [-]",
           "interference": "min cable distance - diameter [m]"}
_LABEL_NO_UPPER = "tension margin above tension_min [N]"  # static-equilibrium with no upper limit


def add_arguments(p):
    p.add_argument("robot", help="robot description TOML (or a bundled example name, e.g. tcpr8.toml)")
    p.add_argument("--kind", choices=KINDS, required=True, help="which workspace")
    add_pose_grid_arguments(p)
    p.add_argument("--orientation", choices=ORIENTATIONS, default=None,
                   help="static-equilibrium: the platform's rotation is where it hangs (free, the default: sought "
                        "from --rotation) or --rotation itself (given)")
    p.add_argument("--wrench-box", nargs=12, type=float, default=None,
                   metavar=("FXMIN", "FXMAX", "FYMIN", "FYMAX", "FZMIN", "FZMAX",
                            "MXMIN", "MXMAX", "MYMIN", "MYMAX", "MZMIN", "MZMAX"),
                   help="required wrench box (N, N·m), min and max per component (wrench-feasible, static-equilibrium)")
    p.add_argument("--wrench-vertices", metavar="CSV", default=None,
                   help="required wrench set as vertices: a CSV file, one wrench fx,fy,fz,mx,my,mz per row")
    p.add_argument("--length-scale", type=float, default=1.0,
                   help="L (m) of the margin metric |f|^2 + |m/L|^2 (wrench-feasible; default 1)")
    p.add_argument("--load", nargs=6, type=float, default=None, metavar="W",
                   help="external wrench shaping sagging cables (interference; N, N·m)")
    p.add_argument("--cable-diameter", type=float, default=0.0, help="cable diameter, m (interference)")
    p.add_argument("--samples", type=int, default=16, help="points per sagging cable (interference)")
    p.add_argument("--chunk-size", type=int, default=None,
                   help="poses per chunk (default: 65536 on a CPU, 2^20 per device on a GPU or TPU)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")


def _read_vertices(path: Path) -> np.ndarray:
    rows = []
    for no, line in enumerate(path.read_text().splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = [p for p in text.replace(",", " ").split() if p]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            vals = None
        if vals is None or len(vals) != 6:
            raise ValueError(f"{path}: row {no}: expected 6 numbers fx fy fz mx my mz, got {text!r}")
        rows.append(vals)
    if not rows:
        raise ValueError(f"{path}: no wrench vertices (one row of 6 numbers per vertex)")
    return np.asarray(rows)


def _wrench_set(args) -> WrenchSet | None:
    given = [n for n, v in (("--wrench-box", args.wrench_box), ("--wrench-vertices", args.wrench_vertices))
             if v is not None]
    if args.kind not in WRENCH_KINDS:
        if given:
            raise ValueError(f"{given[0]}: only used with --kind {' or '.join(WRENCH_KINDS)} (got --kind {args.kind})")
        return None
    if len(given) > 1 or (args.kind == "wrench-feasible" and not given):
        raise ValueError(f"--kind {args.kind} needs {'exactly' if args.kind == 'wrench-feasible' else 'at most'} "
                         f"one of --wrench-box and --wrench-vertices")
    if not given:
        return None
    if args.wrench_box is not None:
        b = np.asarray(args.wrench_box).reshape(6, 2)
        return WrenchSet.box(b[:, 0], b[:, 1])
    return WrenchSet.vertices(_read_vertices(resolve_path(args.wrench_vertices)))


def _evaluator(args, robot, wset):
    """``(fn, vectorized, cpu_batch)`` of the chosen kind (``cpu_batch``: poses per step on a CPU)."""
    if args.kind == "wrench-feasible":
        check_feasible_cables(robot)
        if not args.length_scale > 0:
            raise ValueError(f"--length-scale: {args.length_scale!r} must be > 0 (m)")

        def fn(P):
            r = wrench_feasible(robot, P, wset, length_scale=args.length_scale)
            return {"member": r.member, "margin": r.margin, "singular": r.singular}

        return fn, True, 64
    if args.kind == "static-equilibrium":
        check_equilibrium_robot(robot, args.orientation)

        def fn(pose):
            r = static_equilibrium(robot, pose, wset, orientation=args.orientation)
            return {"member": r.member, "margin": r.margin, "residual": r.residual, "stable": r.stable,
                    "solved": r.solved, "equilibrium_rotation": r.rotation}

        return fn, False, 256
    if args.kind == "wrench-closure":
        check_closure_cables(robot)

        def fn(P):
            r = wrench_closure(robot, P)
            return {"member": r.member, "margin": r.margin, "singular": r.singular}

        return fn, True, 64
    model = interference_model(robot, diameter=args.cable_diameter, samples=args.samples)
    load = None if args.load is None else jnp.asarray(args.load)

    def fn(pose):
        r = interference(robot, model, pose, load)
        return {"member": r.free, "margin": r.margin, "clearance": jnp.min(r.platform_clearance),
                "solved": r.result == Status.successful}

    return fn, False, 256


def _limits_text(robot) -> str:
    """Which tension limits were used, in words (summary.json ``limits`` and the printed line)."""
    lo, hi = float(robot.tension_min), float(robot.tension_max)
    if np.isfinite(hi):
        return f"tension limits {lo:g} <= t <= {hi:g} N"
    return f"tension limit t >= {lo:g} N only (no finite tension_max in [limits]: no upper limit)"


def _finite_stats(v):
    v = v[np.isfinite(v)]
    return {"min": float(v.min()), "max": float(v.max()), "mean": float(v.mean())} if v.size else None


def run(args) -> int:
    robot_path = resolve_path(args.robot)
    inputs = [robot_path] + ([resolve_path(args.wrench_vertices)] if args.wrench_vertices else [])
    check_outputs(inputs, folders={"--out": (args.out, OUTPUTS)})
    robot = load_robot(robot_path)
    grid = pose_grid(args)
    if args.orientation is not None and args.kind != "static-equilibrium":
        raise ValueError(f"--orientation: only used with --kind static-equilibrium (got --kind {args.kind})")
    args.orientation = args.orientation or "free"
    wset = _wrench_set(args)
    fn, vectorized, cpu_batch = _evaluator(args, robot, wset)
    out = sweep(fn, grid, chunk_size=args.chunk_size, vectorized=vectorized,
                batch_size=cpu_batch if jax.devices()[0].platform == "cpu" else "auto",
                progress=False if args.no_progress else None, desc=args.kind)
    shape = grid.shape
    res = {k: np.asarray(v).reshape(shape + np.shape(v)[1:]) for k, v in out.items()}
    member, margin = res["member"], res["margin"]
    axes = grid.axes()
    extra = {} if wset is None else {"wrench_center": np.asarray(wset.center), "wrench_radii": np.asarray(wset.radii),
                                     "wrench_offsets": np.asarray(wset.offsets)}
    count, volume = int(member.sum()), grid.volume(member)
    info = {"robot": robot.name, "kind": args.kind, "poses": len(grid), "members": count,
            "volume_m3": volume, "cell_volume_m3": grid.cell_volume,
            "grid": list(args.pose_grid), "rotation": list(args.rotation),
            "margin_members": _finite_stats(margin[member]), "margin_all": _finite_stats(margin),
            "margin_unit": _LABELS[args.kind]}
    if "singular" in res:
        info["singular_poses"] = int(res["singular"].sum())
    limits = _limits_text(robot)
    if args.kind in WRENCH_KINDS:
        hi = float(robot.tension_max)
        info.update(wrench_box=None if args.wrench_box is None else list(args.wrench_box),
                    wrench_vertices=args.wrench_vertices,
                    tension_limits_N=[float(robot.tension_min), hi if np.isfinite(hi) else None], limits=limits)
    if args.kind == "wrench-feasible":
        info.update(length_scale_m=args.length_scale)
    if args.kind == "static-equilibrium":
        info.update(orientation=args.orientation, no_equilibrium_poses=int((~res["solved"]).sum()),
                    unstable_poses=int((res["solved"] & ~res["stable"]).sum()),
                    unbounded_margin_poses=int((margin == np.inf).sum()))
        if not np.isfinite(float(robot.tension_max)):
            info["margin_unit"] = _LABEL_NO_UPPER
    if args.kind == "interference":
        info.update(cable_diameter_m=args.cable_diameter, load=args.load,
                    sag_statics_failed=int((~res["solved"]).sum()))
    title = f"{args.kind} workspace of {figure_text(robot.name)}"
    from cstiffjax.plots import (
        workspace as plots_workspace,  # lazy: matplotlib costs every other command 0.3 s at start
    )

    outdir, problems = Path(args.out), []
    with output_folder(outdir, OUTPUTS, on_replace=say_replacing) as tmp:  # whole or not at all
        np.savez_compressed(tmp / "results.npz", x=axes[0], y=axes[1], z=axes[2], rotation=np.asarray(args.rotation),
                            cell_volume=grid.cell_volume, **res, **extra)
        write_json(tmp / "summary.json", info)
        label = info["margin_unit"]
        best_effort(problems, tmp / "workspace_3d.png", lambda: plots_workspace.plot_members_3d(
            axes, member, margin, tmp / "workspace_3d.png", title, label, robot=robot))  # inside the robot's frame
        best_effort(problems, tmp / "workspace_sections.png", lambda: plots_workspace.plot_sections(
            axes, member, margin, tmp / "workspace_sections.png", title, label))
    print(f"{args.kind}: {count} of {len(grid)} poses, volume {volume:.4g} m^3; margin over "
          f"members: {info['margin_members']}" + (f"; {limits}" if args.kind in WRENCH_KINDS else ""))
    print(terminal(f"wrote {outdir}/" + ", ".join(OUTPUTS)))
    return report_problems(NAME, problems)
