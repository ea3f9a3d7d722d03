"""Frequency response and natural frequencies of a CDPR with sagging cables (Yuan et al. 2015
Section 3.3, Figs 9-10, Table 4).

The platform hangs at --pose under its weight (plus --wrench). Static state: with --l0
the given unstrained lengths (--pose must then be their equilibrium; it is not solved
for); otherwise the sagging (elastic catenary) inverse statics
when the cables have mass, the spring lengths of the minimum-norm tensions when not.
Three models are compared:
  spring   massless spring cables, K = -dW/dx with M (Yuan et al. 2015 Table 4, "[28]")
  sagging  static catenary tangent stiffness with M, cable inertia ignored ("[19]")
  DSM      dynamic stiffness of every cable (Starossek), coupled with the platform:
           all natural frequencies in [fmin, fmax] (Wittrick-Williams, resolution --tol),
           each with its platform participation (share of modal kinetic energy).
The FRF X = [-w^2 M + K_M(w)]^-1 F is computed for a unit vertical force along the
platform z axis (the shaker of Fig. 8) on --n frequencies; figures and JSON go to --out.
Exit 2 when the cables cannot hold --pose (a non-positive tension), 1 for bad arguments.
"""

from pathlib import Path

import jax.numpy as jnp
import numpy as np

from cstiffjax.cable.dsm import cable_frame, cable_parameters, clamped_cable_frequencies
from cstiffjax.cable.laws import CableLaw
from cstiffjax.commands.common import (
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
from cstiffjax.core.status import Status
from cstiffjax.core.text import figure as figure_text
from cstiffjax.core.text import terminal
from cstiffjax.dynamics import frf as dy
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.geometry import frame, inverse_statics
from cstiffjax.stiffness.matrix import unstrained_lengths

NAME = "frf"
HELP = "FRF and natural frequencies with sagging cables (dynamic stiffness matrix)"


def add_arguments(p):
    add_robot_pose_arguments(p)
    p.add_argument("--l0", nargs="+", type=finite_float, metavar="L", help="unstrained cable lengths m (one per cable)")
    p.add_argument("--wrench", nargs=6, type=finite_float, default=None, metavar="W",
                   help="external static wrench fx fy fz mx my mz (N, N·m), e.g. a carried load")
    p.add_argument("--fmin", type=float, default=0.2, help="lowest frequency Hz (default 0.2)")
    p.add_argument("--fmax", type=float, default=20.0, help="highest frequency Hz (default 20)")
    p.add_argument("--n", type=int, default=2000, help="number of FRF frequencies (default 2000)")
    p.add_argument("--xi", type=float, default=0.01, help="cable damping ratio (default 0.01)")
    p.add_argument("--tol", type=float, default=1e-4, help="natural-frequency resolution Hz (default 1e-4)")
    p.add_argument("--participation", type=float, default=0.2,
                   help="platform share of modal energy above which a mode is listed as a robot mode (default 0.2)")
    p.add_argument("--cable", type=int, default=5, help="cable (1-based) for the cable FRF (default 5, as Fig. 9)")
    p.add_argument("--s", type=float, default=0.25, help="chord fraction of the cable sensor from the anchor")
    p.add_argument("--sweep", type=int, default=0, metavar="N",
                   help="also map the first natural frequency on an N x N grid over the pose's x and y +- 0.5 m "
                        "(or --region) at its z and rotation (Fig. 13)")
    add_region_argument(p, "--sweep")
    p.add_argument("--out", default="frf_out", help="output folder (figures, frf.json)")


def _static_state(robot, pose, args):
    inv = inverse_statics(robot, pose, args.wrench, throw=False)
    check_input_status(inv.result, pose_option(pose))
    t = inv.tensions
    if not np.all(np.asarray(t) > 0):
        raise NoAnswerError(f"inverse statics gives non-positive tensions {np.round(np.asarray(t), 3).tolist()} N "
                         "at this pose: the cables cannot hold it")
    massive = bool(np.any(np.asarray(robot.mass_per_length) > 0))
    if args.l0 is not None:
        if len(args.l0) != robot.num_cables:
            raise ValueError(f"--l0: got {len(args.l0)} values, the robot has {robot.num_cables} cables")
        l0, source = jnp.asarray(args.l0), "given"
    elif massive:
        cl = dy.catenary_lengths(robot, pose, args.wrench, throw=False)
        l0 = cl.l0
        source = "catenary inverse statics" + ("" if bool(cl.result == Status.successful) else " (NOT CONVERGED)")
    else:
        l0, source = unstrained_lengths(robot, pose, t), "spring inverse statics"
    st = dy.cable_statics_from_lengths(robot, pose, l0, CableLaw.catenary if massive else CableLaw.spring)
    if not np.all(np.isfinite(np.asarray(st.tension))) or not np.all(np.asarray(st.tension) > 0):
        raise NoAnswerError(f"cables of lengths {np.round(np.asarray(l0), 4).tolist()} m do not all pull at this pose")
    return t, l0, st, source, massive


def _clamped(robot, pose, st, k, fmax):
    p, R = frame(pose)
    att = p + R @ robot.attachments[k]
    fr = cable_frame(dy.span_starts(robot, p + robot.attachments @ R.T)[k], att, robot.gravity)
    _, lam2, _, _ = cable_parameters(fr.length, fr.cos_alpha, st.tension[k], robot.EA[k], robot.mass_per_length[k],
                                     float(np.linalg.norm(robot.gravity)))
    c = clamped_cable_frequencies(fr.length, st.tension[k], robot.mass_per_length[k], lam2, num=40)
    allf = np.sort(np.concatenate([np.asarray(v) for v in c.values()]))
    return allf[allf < fmax], float(lam2)


def _fmt(fs):
    return " ".join(f"{f:.2f}" for f in np.asarray(fs)) or "-"


def run(args) -> int:
    robot_path = resolve_path(args.robot)
    names = ("frf.json", "frf_platform.png", f"frf_cable{args.cable}.png") + (
        ("first_frequency_map.png",) if args.sweep else ())
    check_outputs((robot_path,), folders={"--out": (args.out, names)})
    robot = load_robot(robot_path)
    pose = jnp.asarray(args.pose)
    if args.n < 2 or args.fmax <= args.fmin or args.fmin < 0:
        raise ValueError(f"need 0 <= --fmin < --fmax and --n >= 2 (got {args.fmin}, {args.fmax}, {args.n})")
    if not 1 <= args.cable <= robot.num_cables:
        raise ValueError(f"--cable {args.cable}: allowed 1..{robot.num_cables}")
    out = Path(args.out)
    if args.sweep:
        xs, ys = region_axes(args.region, args.pose, args.sweep, "--sweep")
    t, l0, st, source, massive = _static_state(robot, pose, args)
    print(f"robot {terminal(robot.name)}, pose {list(args.pose)}; l0 from {source}")
    print("l0 [m]:            ", " ".join(f"{v:.4f}" for v in np.asarray(l0)))
    print("tensions (massless) [N]:", " ".join(f"{v:.1f}" for v in np.asarray(t)))
    print("chord tension tau [N]: ", " ".join(f"{v:.1f}" for v in np.asarray(st.tension)))

    spring = np.asarray(dy.spring_modes(robot, pose, t).frequencies)
    sagging = np.asarray(dy.sagging_modes(robot, pose, l0).frequencies) if massive else spring
    nat = np.asarray(dy.natural_frequencies(robot, pose, st, args.fmax, args.fmin, tol=args.tol))
    part = np.asarray(dy.platform_modes(robot, pose, st, jnp.asarray(nat)).participation) if nat.size else nat
    robot_modes = nat[part >= args.participation]

    def in_band(f):
        return f[(f >= args.fmin) & (f < args.fmax)]

    print(f"natural frequencies in [{args.fmin}, {args.fmax}) Hz:")
    print(f"  massless spring model : {_fmt(in_band(spring))}")
    print(f"  static sagging model  : {_fmt(in_band(sagging))}")
    print(f"  DSM, platform share >= {args.participation}: {_fmt(robot_modes)}")
    print(f"  DSM, all coupled modes: {nat.size} (resolution {args.tol:g} Hz)")

    freqs = np.linspace(args.fmin, args.fmax, args.n)
    _, R = frame(pose)
    force = jnp.concatenate([R[:, 2], jnp.zeros(3)])
    X = dy.frf(robot, pose, st, jnp.asarray(freqs), args.xi, force)
    acc = np.asarray(dy.point_acceleration(pose, X, jnp.asarray(freqs)))
    k = args.cable - 1
    cab = np.asarray(dy.cable_response(robot, pose, st, X, jnp.asarray(freqs), args.xi, cable=k, s=args.s))
    clamped, lam2 = _clamped(robot, pose, st, k, args.fmax)
    from cstiffjax.plots.dynamics import plot_cable_frf, plot_frequency_map, plot_platform_frf

    name = figure_text(robot.name)
    figures = [  # (file, draw(path)), drawn once everything is computed
        ("frf_platform.png", lambda p: plot_platform_frf(
            p, freqs, acc, natural=robot_modes, spring=in_band(spring), sagging=in_band(sagging) if massive else None,
            title=f"{name}: platform acceleration / vertical force (xi = {args.xi:g})")),
        (f"frf_cable{args.cable}.png", lambda p: plot_cable_frf(
            p, freqs, cab, clamped=clamped, title=f"{name}: cable {args.cable} at s = {args.s:g} (tau = "
                                                  f"{float(st.tension[k]):.1f} N, lambda^2 = {lam2:.3g})")),
    ]
    payload = {"robot": robot.name, "pose": list(args.pose), "l0": l0, "l0_source": source, "tensions_massless": t,
               "chord_tension": st.tension, "xi": args.xi, "resolution_hz": args.tol,
               "spring_modes_hz": spring, "sagging_modes_hz": sagging, "dsm_natural_frequencies_hz": nat,
               "dsm_platform_participation": part, "dsm_robot_modes_hz": robot_modes,
               f"cable{args.cable}_clamped_frequencies_hz": clamped,
               "frf": {"frequencies_hz": freqs, "abs_accel_platform_frame": np.abs(acc),
                       f"abs_accel_cable{args.cable}": np.abs(cab)}}
    if args.sweep:
        poses = jnp.asarray([[x, y, *args.pose[2:]] for y in ys for x in xs])
        from cstiffjax.core.progress import bar

        n = args.sweep
        f1 = np.concatenate([np.asarray(dy.first_frequency_map(robot, poses[i * n:(i + 1) * n], fmax=args.fmax))
                             for i in bar(range(n), desc="frequency map", unit="row")]).reshape(n, n)
        figures.append(("first_frequency_map.png", lambda p: plot_frequency_map(
            p, xs, ys, f1, title=f"{name}: first natural frequency [Hz], z = {args.pose[2]} m")))
        payload["sweep"] = {"x": xs, "y": ys, "first_frequency_hz": f1}
        print(f"first natural frequency over the grid: {np.nanmin(f1):.3f} .. {np.nanmax(f1):.3f} Hz")
    problems = []
    with output_folder(out, names, on_replace=say_replacing) as tmp:  # whole or not at all
        write_json(tmp / "frf.json", payload)
        for fn, draw in figures:
            best_effort(problems, tmp / fn, lambda fn=fn, draw=draw: draw(tmp / fn))
    drawn = [str(out / fn) for fn, _ in figures if not any(p.startswith(fn) for p in problems)]
    print(terminal("wrote " + ", ".join([*drawn, str(out / "frf.json")])))
    return report_problems(NAME, problems)
