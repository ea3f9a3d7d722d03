"""Validate a robot description and (optionally) a recordings file, and summarize them.

Every problem is reported with the file, the key or line/column, the value and what is
allowed. With --drop-invalid, rows with a bad cell are dropped and listed (by file line
number) instead of being an error.

The robot must be able to hold a pose at all: its structure matrix (the wrenches the
cables can apply: 6 x m for a CDPR, the 3 x m moment Jacobian for a CSJM) must have full
rank at the reference pose (with fewer than 6 cables, a suspended robot whose weight closes
the equilibrium: rank m, every cable independent). The reference pose is the mean recorded pose when recordings
are given; otherwise the centre of the anchors' bounding box at mid height, unrotated (a
CSJM: no rotation). Because one pose can be singular by accident, the rank is also tested
at six poses around it; the check fails (exit code 1, an unusable input) only when the rank is short at all
seven, which is what duplicate cables, cables along one line, all anchors or all
attachments at one point do. The message names the cables involved.

The values the loaders accept but that cannot be what was meant are judged by
cstiffjax.io.plausibility, the checks the diagnosis uses: one cable's commanded lengths
(``l0_i``) a factor ~1000 off its anchor-attachment distance at the recorded poses (mm
against m), an anchor or attachment far outside the others (written in mm), or quantities
of the description that disagree (all anchors or all attachments in mm, a pulley radius, EA
or ``tension_max`` against the weight: formats.md §1 "Proportions") is an error naming the
column, cable or quantities and the values (exit 1). Gravity pointing up or not ~9.81 m/s²,
an implausible noise sigma (``noise.position = 20`` m) and lengths that would stretch a
cable by >11 % or leave it slack are ``warning:`` lines; the check still passes (exit 0).

The cable hardware of formats.md §1 v2 is summarized on one or two lines (and under
``hardware`` in --json): which cables run over swivel pulleys, their radii (m) and axes
(unit vectors, base frame), and which cables have a winch ``length_gain`` or load-cell
``tension_gain`` other than 1. A description without them says so on one line
(``hardware: no pulleys (...); gains all 1``).
"""

import dataclasses
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cstiffjax.cable.laws import CableLaw
from cstiffjax.commands.common import (
    best_effort,
    check_outputs,
    finite_float,
    report_problems,
    resolve_path,
    write_json,
)
from cstiffjax.core.errors import RecordingsError, RobotFileError
from cstiffjax.core.status import Status, code, describe
from cstiffjax.core.text import figure as figure_text
from cstiffjax.core.text import terminal
from cstiffjax.csjm import model as csjm
from cstiffjax.examples import describe_example, list_examples
from cstiffjax.io import schema
from cstiffjax.io.atomic import replacing
from cstiffjax.io.plausibility import cable_length_checks, geometry_checks
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot import robot_summary
from cstiffjax.io.robot_io import load_description
from cstiffjax.io.screening import recordings_warnings
from cstiffjax.statics import geometry as statics
from cstiffjax.statics.degeneracy import check_rank, poses_around, unit_free
from cstiffjax.statics.forward import StaticsProblem, forward_statics

NAME = "check"
HELP = "validate and summarize a robot TOML and a recordings CSV"


def add_arguments(p):
    p.add_argument("robot", nargs="?", help="robot description TOML (or a bundled example name)")
    p.add_argument("recordings", nargs="?", help="recordings CSV (optional)")
    p.add_argument("--drop-invalid", action="store_true", help="drop invalid rows instead of failing")
    p.add_argument("--json", metavar="OUT", help="also write the summary as JSON")
    p.add_argument("--list-examples", action="store_true", help="list the bundled example files")
    p.add_argument("--plot", metavar="PNG",
                   help="draw the robot (frame from the floor up, anchors and pulleys, cables, platform) at --pose, "
                        "else the description's reference_pose, else the mean recorded pose, else where it hangs "
                        "(the nominal gravity equilibrium)")
    p.add_argument("--pose", nargs=6, type=finite_float, metavar=("X", "Y", "Z", "RX", "RY", "RZ"),
                   help="the pose --plot draws: position m, rotation vector rad")


# --------------------------------------------------------------------------- rank rule
def reference_pose(robot, rec=None) -> np.ndarray:
    """The pose at which the rank is tested: ``[x y z rx ry rz]`` (CDPR) or ``[rx ry rz]`` (CSJM).

    The mean recorded pose when ``rec`` is given, else (CDPR) the centre of the anchors'
    bounding box (x, y and mid height z) unrotated, (CSJM) no rotation. Recordings without
    ``x y z`` (formats.md §2 version 3): the nominal robot's equilibrium for the mean recorded
    lengths (the frame's centre if it has none), with any measured component's mean.
    """
    if robot.kind == "csjm":
        return np.asarray(rec.pose).mean(axis=0)[3:] if rec is not None else np.zeros(3)
    a = np.asarray(robot.anchors)
    frame = np.concatenate([(a.min(0) + a.max(0)) / 2, np.zeros(3)])
    if rec is None:
        return frame
    pose, mask = np.asarray(rec.pose), np.asarray(rec.pose_mask)
    if not rec.has_position:  # on-board sensors only: where the nominal robot hangs for the mean lengths
        fs = forward_statics(StaticsProblem(robot, np.asarray(rec.l0).mean(axis=0), np.zeros(6), CableLaw.spring),
                             throw=False)
        if bool(fs.result == Status.successful):
            frame = np.asarray(fs.pose)
    measured = mask.any(axis=0)
    return np.where(measured, np.sum(pose * mask, axis=0) / np.maximum(mask.sum(axis=0), 1), frame)


@eqx.filter_jit
def _structure_matrices(robot, poses):
    if robot.kind == "csjm":
        return jax.vmap(lambda q: csjm.jacobian(robot, q).T)(poses)
    return jax.vmap(lambda q: statics.structure_matrix_closed_form(robot, q))(poses)


def wrench_matrices(robot, poses) -> np.ndarray:
    """Structure matrices at ``poses`` (one compiled call), moment rows divided by the
    platform size (CDPR, 6 x m each), or the moment Jacobians transposed divided by it
    (CSJM, 3 x m each): unit-free entries, so one relative tolerance fits both rows
    (:func:`cstiffjax.statics.degeneracy.unit_free`)."""
    unnamed = dataclasses.replace(robot, name="")  # one compile per kind and cable count
    return unit_free(robot, np.array(_structure_matrices(unnamed, jnp.asarray(np.stack(poses)))))


# --------------------------------------------------------------------------- hardware
def _cable_ranges(cables) -> str:
    """``"1-4, 6"`` of 1-based cable numbers (sorted)."""
    out, run = [], []
    for c in sorted(cables):
        if run and c != run[-1] + 1:
            out.append(run)
            run = []
        run.append(c)
    out += [run] if run else []
    return ", ".join(f"{r[0]}-{r[-1]}" if len(r) > 2 else ", ".join(map(str, r)) for r in out)


def _grouped(values, cables, fmt) -> str:
    """``"A on cables 1-4, B on cables 5-8"``: the cables of each distinct value (first-seen order)."""
    groups: dict[str, list[int]] = {}
    for v, c in zip(values, cables, strict=True):
        groups.setdefault(fmt(v), []).append(c)
    if len(groups) == 1:
        return next(iter(groups))
    return ", ".join(f"{k} on cable{'s' if len(cs) > 1 else ''} {_cable_ranges(cs)}" for k, cs in groups.items())


def hardware(robot) -> tuple[list[str], dict]:
    """Text lines and JSON entry of the swivel pulleys and gains of ``robot`` (formats.md §1 v2).

    **Returns:** ``(lines, entry)``. ``entry`` holds ``pulleys`` (``count``, 1-based
    ``cables`` with ``pulley_radius > 0``, ``radius_m`` and ``axis`` of each of them,
    ``radius_min_m``/``radius_max_m``, ``None`` without pulleys), ``length_gain`` and
    ``tension_gain`` (one value per cable) and ``non_unit_gains`` (``{field: {cable: gain}}``
    for the gains other than 1).
    """
    radius, axis = np.asarray(robot.pulley_radius), np.asarray(robot.pulley_axis)
    on = [int(i) + 1 for i in np.flatnonzero(radius > 0)]
    m = robot.num_cables
    gains = {k: np.asarray(getattr(robot, k)) for k in ("length_gain", "tension_gain")}
    odd = {k: {int(i) + 1: float(g[i]) for i in np.flatnonzero(g != 1.0)} for k, g in gains.items()}
    r_on, a_on = radius[radius > 0], axis[radius > 0]
    entry = {"pulleys": {"count": len(on), "cables": on, "radius_m": r_on.tolist(), "axis": a_on.tolist(),
                         "radius_min_m": float(r_on.min()) if on else None,
                         "radius_max_m": float(r_on.max()) if on else None},
             **{k: g.tolist() for k, g in gains.items()}, "non_unit_gains": {k: v for k, v in odd.items() if v}}
    if on:
        which = (f"all {m} cables run" if len(on) == m else
                 f"{len(on)} of {m} cables (cable{'s' if len(on) > 1 else ''} {_cable_ranges(on)}) run")
        pulleys = (f"pulleys: {which} over swivel pulleys; radius "
                   + _grouped(r_on, on, lambda v: f"{v:.4g} m") + "; axis "
                   + _grouped(a_on, on, lambda v: "[" + ", ".join(f"{c:.4g}" for c in v + 0.0) + "]"))
    else:
        pulleys = "pulleys: none (every cable leaves straight from its anchor)"
    parts = [f"{k} " + ", ".join(f"{g:.6g} (cable {c})" for c, g in v.items()) for k, v in odd.items() if v]
    gain_text = "gains: " + ("; ".join(parts) + "; the others 1" if parts else "all 1")
    if not on and not parts:
        return ["hardware: no pulleys (every cable leaves straight from its anchor); gains all 1"], entry
    return [pulleys, gain_text], entry


# --------------------------------------------------------------------------- command
def _print_recordings(rec, m) -> dict:
    n = rec.num_samples
    print(f"recordings OK: {n} samples, {m} cables, "
          f"tensions {'recorded' if rec.has_tensions else 'not recorded'}")
    if rec.dropped_rows:
        print(f"  dropped {len(rec.dropped_rows)} invalid row(s), file lines {list(rec.dropped_rows)}:")
        for line, why in zip(rec.dropped_rows, rec.drop_reasons, strict=True):
            print(f"    line {line}: {terminal(why)}")
    if rec.covariate_names:
        print(f"  covariates: {', '.join(map(terminal, rec.covariate_names))}")
    pose, mask = np.asarray(rec.pose), np.asarray(rec.pose_mask)
    lo = np.where(mask.any(0), np.where(mask, pose, np.inf).min(0), np.nan)
    hi = np.where(mask.any(0), np.where(mask, pose, -np.inf).max(0), np.nan)
    for j, nm in enumerate(schema.field_columns("pose", m)):
        print(f"  {nm:>2}: {lo[j]: .5g} .. {hi[j]: .5g}" if mask[:, j].any() else f"  {nm:>2}: not recorded")
    onboard = {}
    for field in ("swivel", "ahrs"):
        vals, got = np.asarray(getattr(rec, field)), np.asarray(getattr(rec, field + "_mask"))
        for j, nm in enumerate(schema.field_columns(field, m)):
            if got[:, j].any():
                v = vals[got[:, j], j]
                onboard[nm] = (float(v.min()), float(v.max()))
                print(f"  {nm}: {v.min(): .5g} .. {v.max(): .5g} rad")
    if len(rec.sessions) > 1:
        print(f"  sessions: {', '.join(map(str, rec.sessions))}")
    return dict(samples=n, dropped_rows=list(rec.dropped_rows), drop_reasons=list(rec.drop_reasons),
                covariates=list(rec.covariate_names), pose_min=_or_null(lo), pose_max=_or_null(hi),
                sessions=list(rec.sessions),
                onboard_ranges=onboard)


def _or_null(a) -> list:
    """``a`` as a list with ``None`` (JSON ``null``) for a ``nan`` (a component not recorded)."""
    return [None if np.isnan(v) else float(v) for v in np.asarray(a, dtype=float)]


def _check_poses(robot, rec) -> np.ndarray:
    """The poses the commanded lengths are judged at: the recorded ones, or without ``x y z``
    (on-board sensors only) the reference pose for every sample (then only units are judged)."""
    if rec.has_position:
        return np.asarray(rec.pose)
    return np.tile(reference_pose(robot, rec), (rec.num_samples, 1))


def run(args) -> int:
    if args.list_examples or args.robot is None:
        print("bundled examples:\n" + "\n".join(f"  {name:26s} {describe_example(name)}" for name in list_examples()))
        return 0
    robot_path = resolve_path(args.robot)
    rec_path = resolve_path(args.recordings) if args.recordings else None
    check_outputs((robot_path, rec_path), files={"--json": args.json, "--plot": args.plot})
    if args.pose is not None and not args.plot:
        raise ValueError("--pose: the pose --plot draws; give --plot PNG too")
    robot, stated = load_description(robot_path)
    errors, plausible = geometry_checks(robot, str(robot_path))
    if errors:
        raise RobotFileError("; ".join(errors))
    rec = None
    if rec_path is not None:
        rec = load_recordings(rec_path, robot, drop_invalid=args.drop_invalid)
        if robot.kind == "cdpr":
            errors, more = cable_length_checks(robot, rec.l0, _check_poses(robot, rec), str(rec_path),
                                               units_only=not rec.has_position)
            if errors:
                raise RecordingsError("; ".join(errors))
            plausible += more
    pose = reference_pose(robot, rec)
    matrices = wrench_matrices(robot, [pose, *poses_around(robot, pose)])
    rank, best, warnings = check_rank(robot, pose, matrices, robot_path)
    warnings = warnings + plausible
    if rec is not None:  # readings no cable produces, copied samples (cstiffjax.io.screening)
        warnings += recordings_warnings(rec, robot)
    at = f"at the reference pose {np.round(pose, 4).tolist()}"
    print(f"robot OK: {terminal(robot_summary(robot, hardware=False))}; structure matrix rank {rank} {at}"
          + ("" if rank == best else f" (a singular pose), {best} around it")
          + ("" if robot.kind == "csjm" or robot.num_cables >= 6 else
             f" ({robot.num_cables} cables: under-constrained, the platform's weight closes the equilibrium)"))
    lines, hw = hardware(robot)
    for line in lines:
        print(f"  {line}")
    for w in warnings:
        print(f"  warning: {terminal(w)}")
    summary = {"robot": robot.name, "kind": robot.kind, "cables": robot.num_cables,
               "structure_rank": rank, "structure_rank_around": best, "reference_pose": pose, "warnings": warnings,
               "hardware": hw}
    if rec is not None:
        summary.update(_print_recordings(rec, robot.num_cables))
    if args.json:
        write_json(args.json, summary)
        print(terminal(f"wrote {args.json}"))
    if args.plot:
        return _plot(robot, *plot_pose(robot, rec, stated, args.pose), args.plot)
    return 0


def plot_pose(robot, rec=None, stated=None, given=None) -> tuple[np.ndarray, str]:
    """``(pose (6,), what it is)``: where ``--plot`` draws ``robot``: ``given`` (``--pose``),
    else ``stated`` (the description's ``reference_pose``), else with recordings
    :func:`reference_pose` (the mean recorded pose; without ``x y z`` the nominal equilibrium
    of the mean recorded lengths), else the nominal gravity equilibrium
    (:func:`cstiffjax.statics.equilibrium.nominal_equilibrium`: where the platform hangs on
    spring cables of the lengths at :func:`~cstiffjax.statics.equilibrium.hanging_guess`),
    or that guess when no equilibrium is found (said in ``what``)."""
    if given is not None:
        return np.asarray(given, dtype=float), "--pose"
    if stated is not None:
        return np.asarray(stated, dtype=float), "the description's reference_pose"
    if rec is not None:
        what = "the mean recorded pose" if rec.has_position else "the equilibrium of the mean recorded lengths"
        return reference_pose(robot, rec), what
    from cstiffjax.statics.equilibrium import hanging_guess, nominal_equilibrium

    fs = nominal_equilibrium(robot)
    if code(fs.result) == code(Status.successful):
        return np.asarray(fs.pose), "where it hangs: the nominal gravity equilibrium"
    return hanging_guess(robot), f"no nominal gravity equilibrium found ({describe(fs.result)}): the frame's middle"


def _plot(robot, pose, what, path) -> int:
    """Draw the robot at ``pose`` (``what`` it is, in the title) into ``path`` (written
    atomically); a CSJM has no such view."""
    if robot.kind != "cdpr":
        raise ValueError(f"--plot draws cable-driven parallel robots; {robot.name!r} is a {robot.kind}")
    from cstiffjax.plots.robot import plot_robot  # lazy: matplotlib only when a figure is drawn
    from cstiffjax.statics.sag import sagging_inverse_statics

    l0 = None
    if float(np.max(np.asarray(robot.mass_per_length))) > 0:  # heavy cables hang in their catenary
        inv = sagging_inverse_statics(robot, pose, throw=False)
        l0 = np.asarray(inv.l0) if code(inv.result) == code(Status.successful) else None
    title = f"{figure_text(robot.name)} at {(np.round(pose, 3) + 0.0).tolist()}\n{what}" + (
        "" if l0 is None else "; cables hanging in their elastic catenary")

    def draw():
        with replacing(path) as tmp:  # appears whole or not at all
            plot_robot(robot, pose, tmp, title, l0=l0)

    problems = []
    best_effort(problems, Path(path), draw)
    if not problems:
        print(f"{terminal(f'wrote {path}')} (the robot at {(np.round(pose, 4) + 0.0).tolist()}: {what})")
    return report_problems(NAME, problems)
