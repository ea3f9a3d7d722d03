"""Static pose error of a CDPR with sagging (elastic catenary) cables, Yuan et al. 2015 §3.2.2 and §5.

At --pose the unstrained lengths are the ideal (straight) ones; the platform then settles
under its weight (plus --wrench) with spring cables and with sagging cables. Printed: the
pose errors (ideal -> spring = axial elasticity, spring -> catenary = sag) and the sagging
inverse statics (unstrained lengths and exit-point tensions that hold --pose exactly).

--load-sweep  pose error vs the suspended mass (10..86 kg as in Yuan et al. 2015 Fig. 7).
--map         vertical pose error over the pose's x and y +- 0.5 m (or --region) at the pose's
              z, rotation 0 (Figs 11-12: (a) total, (b) sag-introduced, (c) axial elasticity).
Figures (PNG) and sag.json go to --out DIR (default ./sag_out when --map or --load-sweep
asks for figures). Signs: z up; sag lifts the platform, stretch lowers it.
A pose the cables cannot hold is refused before any statics (exit 2, no valid answer): one
outside the anchors' horizontal frame, (6 cables) one whose unique balancing tensions
are not all positive, or (more cables) one that no tensions >= tension_min balance
(non-negative least squares). So is a pose whose spring or catenary statics did not converge. With
massless cables (every mass_per_length = 0) there is no sag: the spring pose error is
printed and the sag is reported as exactly 0 (--map and --load-sweep refused, exit 1).
Exit 2 also when the sagging inverse statics fails (what was computed is still printed and
written), 1 for unusable input (a non-finite value, an attachment on its anchor).
"""

from pathlib import Path

import jax.numpy as jnp
import numpy as np

from cstiffjax.commands.common import (
    EXIT_NO_ANSWER,
    EXIT_OK,
    add_region_argument,
    add_robot_pose_arguments,
    best_effort,
    check_input_status,
    check_outputs,
    finite_float,
    output_folder,
    pose_option,
    region_axes,
    report_problems,
    resolve_path,
    say_replacing,
    write_json,
)
from cstiffjax.core.errors import NoAnswerError
from cstiffjax.core.status import Status, describe
from cstiffjax.core.text import figure as figure_text
from cstiffjax.core.text import terminal
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.geometry import inverse_statics
from cstiffjax.statics.hold import check_holdable
from cstiffjax.statics.sag import load_sweep, pose_error, pose_error_map, sagging_inverse_statics

NAME = "sag"
HELP = "static pose error with sagging cables (spring vs catenary vs ideal)"
DEFAULT_OUT = "sag_out"


def add_arguments(p):
    add_robot_pose_arguments(p, "robot description TOML (or a bundled example, e.g. prototype_8mm.toml)",
                             "reference pose: position m, rotation vector rad")
    p.add_argument("--wrench", nargs=6, type=finite_float, default=None, metavar="W",
                   help="external wrench besides the platform weight: fx fy fz mx my mz (N, N·m)")
    p.add_argument("--load-sweep", action="store_true", help="pose error vs suspended mass (Fig. 7)")
    p.add_argument("--masses", nargs="+", type=finite_float, default=None, metavar="KG",
                   help="suspended masses for --load-sweep, kg (default 10..86 in 12 steps)")
    p.add_argument("--map", action="store_true", help="workspace map of the vertical pose error (Figs 11-12)")
    p.add_argument("--grid", type=int, default=11, help="points per axis for --map (default 11)")
    add_region_argument(p, "--map")
    p.add_argument("--out", metavar="DIR",
                   help=f"directory for figures and sag.json (default ./{DEFAULT_OUT} with --map or --load-sweep)")


def _mm(v):
    return " ".join(f"{1e3 * x:9.3f}" for x in np.asarray(v))


def _newtons(t) -> str:
    """Tensions, N, to four significant digits (a milli-newton tension is not 0.00)."""
    return " ".join(f"{v:9.4g}" for v in np.asarray(t))


def _print_error(pe):
    print("pose errors vs ideal model (position mm, rotation mrad):")
    print(f"  spring   (axial elasticity) {_mm(pe.error_axial)}")
    print(f"  sagging  (total)            {_mm(pe.error_catenary)}")
    print(f"  sag-introduced (sag - spr)  {_mm(pe.error_sag)}")
    print("  exit-point tensions spring   [N]:", _newtons(pe.tensions_spring))
    print("  exit-point tensions catenary [N]:", _newtons(pe.tensions_catenary))


def _figure():
    import matplotlib.pyplot as plt

    return plt


def _plot_sweep(path, masses, pe):
    plt = _figure()
    fig, ax = plt.subplots(figsize=(6, 4.6), layout="constrained")
    ax.plot(masses, 1e3 * np.asarray(pe.error_catenary[:, 2]), "o-", label="sagging cable model")
    ax.plot(masses, 1e3 * np.asarray(pe.error_axial[:, 2]), "s--", label="spring cable model")
    ax.axhline(0.0, color="k", lw=0.8, label="ideal cable model")
    ax.set_xlabel("suspended mass [kg]")
    ax.set_ylabel("pose error along z [mm]")
    ax.set_title("vertical pose error against the suspended mass")
    ax.grid(alpha=0.3)
    fig.legend(loc="outside lower center", ncol=3, fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot_map(path, x, y, pe, title):
    plt = _figure()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4), layout="constrained")
    panels = (("(a) total (sagging model)", pe.error_catenary), ("(b) sag-introduced", pe.error_sag),
              ("(c) axial elasticity (spring model)", pe.error_axial))
    for ax, (name, err) in zip(axes, panels):
        z = 1e3 * np.where(np.asarray(pe.converged), np.asarray(err[..., 2]), np.nan)
        im = ax.contourf(np.asarray(x), np.asarray(y), z, levels=15, cmap="viridis")
        fig.colorbar(im, ax=ax, label="z error [mm]")
        ax.set_title(name)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal")
    fig.suptitle(title)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _map_rows(robot, x, y, z, ext):
    """:func:`~cstiffjax.statics.sag.pose_error_map` on the grid ``x × y``, one row of y at a time
    (one compiled shape; the progress bar moves per row)."""
    import jax

    from cstiffjax.core.progress import bar

    rows = [pose_error_map(robot, x, y[i:i + 1], z, ext) for i in bar(range(len(y)), desc="sag map", unit="row")]
    return jax.tree.map(lambda *a: np.concatenate([np.asarray(v) for v in a]), *rows)


def _holdable(robot, pose, ext) -> None:
    """Raise ``ValueError`` on unusable input (a non-finite value, an attachment on its anchor),
    then :class:`NoAnswerError` when the cables cannot hold ``pose`` at all
    (:func:`cstiffjax.statics.hold.check_holdable`)."""
    where = pose_option(pose)
    inv = inverse_statics(robot, jnp.asarray(pose), ext, throw=False)
    check_input_status(inv.result, where)  # unusable input first: a cable of zero length is the precise cause
    check_holdable(robot, pose, ext, inv.tensions, where)


def _massless(robot, pe, args) -> int:
    """Report of a robot whose cables have no mass: the spring pose error, and no sag."""
    print("the cables have no mass (every mass_per_length = 0): they do not sag; the sagging (catenary) "
          "model is the spring model, the sag-introduced error is 0")
    print("pose errors vs ideal model (position mm, rotation mrad):")
    print(f"  spring   (axial elasticity) {_mm(pe.error_axial)}")
    print(f"  sag-introduced              {_mm(np.zeros(6))}")
    print("  exit-point tensions spring   [N]:", _newtons(pe.tensions_spring))
    if args.out:
        report = {"robot": robot.name, "pose": list(args.pose), "l0_ideal": pe.l0, "massless": True,
                  "error_spring": pe.error_axial, "error_catenary": pe.error_axial, "error_sag": np.zeros(6),
                  "converged": True}
        with output_folder(Path(args.out), ("sag.json",), on_replace=say_replacing) as tmp:
            write_json(tmp / "sag.json", report)
        print(terminal(f"wrote {Path(args.out) / 'sag.json'}"))
    return EXIT_OK


def run(args) -> int:
    robot_path = resolve_path(args.robot)
    names = ("sag.json",) + (("load_sweep.png",) if args.load_sweep else ()) + (
        ("pose_error_map.png",) if args.map else ())
    if (args.map or args.load_sweep) and not args.out:
        args.out = DEFAULT_OUT
        print(f"no --out DIR given: figures and sag.json go to ./{DEFAULT_OUT}/")
    check_outputs((robot_path,), folders={"--out": (args.out, names)})
    robot = load_robot(robot_path)
    pose = jnp.asarray(args.pose)
    ext = None if args.wrench is None else jnp.asarray(args.wrench)
    massless = not np.any(np.asarray(robot.mass_per_length) > 0)
    if massless and (args.map or args.load_sweep):
        raise ValueError(f"{'--map' if args.map else '--load-sweep'}: the cables of {robot_path} have no mass "
                         "(every mass_per_length = 0): there is no sag to map")
    _holdable(robot, args.pose, ext)
    out_dir = Path(args.out) if args.out else None
    figures = []  # (file, draw(path)), drawn once everything is computed
    print(f"robot {terminal(robot.name)}, pose {list(args.pose)}, platform {float(robot.platform_mass):g} kg")
    pe = pose_error(robot, pose, ext)
    check_input_status(pe.result_spring, pose_option(args.pose))
    print("ideal (straight) unstrained lengths [m]:", " ".join(f"{v:.4f}" for v in np.asarray(pe.l0)))
    if massless:
        if pe.result_spring != Status.successful:
            raise NoAnswerError(f"{pose_option(args.pose)}: the spring statics did not converge: "
                                f"{describe(pe.result_spring)}")
        return _massless(robot, pe, args)
    if not bool(pe.converged):
        raise NoAnswerError(f"{pose_option(args.pose)}: the statics did not converge (spring: "
                            f"{describe(pe.result_spring)}, catenary: {describe(pe.result_catenary)}); "
                            "no pose error to report")
    _print_error(pe)
    inv = sagging_inverse_statics(robot, pose, ext, throw=False)
    print(f"sagging inverse statics ({describe(inv.result)}):")
    print("  unstrained lengths [m]:", " ".join(f"{v:.4f}" for v in np.asarray(inv.l0)))
    print("  exit-point tensions [N]:", _newtons(inv.tensions))
    report = {"robot": robot.name, "pose": list(args.pose), "l0_ideal": pe.l0,
              "error_catenary": pe.error_catenary, "error_spring": pe.error_axial, "error_sag": pe.error_sag,
              "converged": pe.converged, "sagging_inverse": {"l0": inv.l0, "tensions": inv.tensions,
                                                             "status": describe(inv.result)}}
    if args.load_sweep:
        masses = np.asarray(args.masses if args.masses else np.linspace(10.0, 86.0, 12))
        sw = load_sweep(robot, pose, masses)
        print("load sweep: mass [kg] | z error sagging, spring, sag part [mm] | converged")
        for m, a, b, c, ok in zip(masses, np.asarray(sw.error_catenary[:, 2]), np.asarray(sw.error_axial[:, 2]),
                                  np.asarray(sw.error_sag[:, 2]), np.asarray(sw.converged)):
            print(f"  {m:7.1f} | {1e3 * a:9.3f} {1e3 * b:9.3f} {1e3 * c:9.3f} | {bool(ok)}")
        report["load_sweep"] = {"masses": masses, "z_catenary": sw.error_catenary[:, 2],
                                "z_spring": sw.error_axial[:, 2], "converged": sw.converged}
        figures.append(("load_sweep.png", lambda p: _plot_sweep(p, masses, sw)))
    if args.map:
        x, y = region_axes(args.region, args.pose, args.grid, "--grid")
        mp = _map_rows(robot, x, y, float(args.pose[2]), ext)
        conv = np.asarray(mp.converged)
        zc, zs, za = (1e3 * np.asarray(e[..., 2])[conv] for e in (mp.error_catenary, mp.error_sag, mp.error_axial))
        print(f"map z = {args.pose[2]} m, {conv.sum()}/{conv.size} poses converged; z error range [mm]:")
        print(f"  (a) total {zc.min():.3f} .. {zc.max():.3f}   (b) sag {zs.min():.3f} .. {zs.max():.3f}"
              f"   (c) axial {za.min():.3f} .. {za.max():.3f}")
        report["map"] = {"x": x, "y": y, "z_catenary": mp.error_catenary[..., 2], "z_sag": mp.error_sag[..., 2],
                         "z_axial": mp.error_axial[..., 2], "converged": mp.converged}
        title = (f"{figure_text(robot.name)}: vertical pose error, {float(robot.platform_mass):g} kg, "
                 f"z = {args.pose[2]} m")
        figures.append(("pose_error_map.png", lambda p: _plot_map(p, x, y, mp, title)))
    solved = bool(pe.converged) and inv.result == Status.successful
    if not out_dir:
        return EXIT_OK if solved else EXIT_NO_ANSWER
    problems = []
    with output_folder(out_dir, names, on_replace=say_replacing) as tmp:  # whole or not at all
        write_json(tmp / "sag.json", report)
        for fn, draw in figures:
            best_effort(problems, tmp / fn, lambda fn=fn, draw=draw: draw(tmp / fn))
    print(terminal("wrote " + ", ".join(str(out_dir / fn) for fn in ("sag.json", *(f for f, _ in figures))
                                        if not any(p.startswith(fn) for p in problems))))
    code = report_problems(NAME, problems)
    return code if code or solved else EXIT_NO_ANSWER
