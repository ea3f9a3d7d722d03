"""Calibrate robot parameters on recordings (whitened least squares, optional emcee posterior).

Residuals are (measured - predicted)/sigma with the robot's [noise] sigmas; chi2/dof = 1
means the calibrated model explains the recordings down to the noise. Free parameters
(--free, comma separated; per cable unless "shared"):

  EA [N], mass_per_length [kg/m] (needs --law catenary), length_offset [m],
  tension_offset [N], anchors [m, x y z], attachments [m, x y z, platform frame],
  platform_mass [kg], com [m], frame_rotation [rad] and frame_translation [m] (the pose
  measurement's frame), pulley_radius [m], length_gain and tension_gain [1] (winch and
  load-cell gains), shared_pulley_radius, shared_length_gain, shared_tension_gain;
  on-board sensors (formats.md version 3): length_zero [m, per cable and session],
  yaw_zero [rad, per session], ahrs_mounting [rad], swivel_offset [rad, per cable and
  session]. length_zero (relative lengths) and yaw_zero (an AHRS) are always calibrated.

Copies of a sample (lengths, wrench and readings equal to within 1e-6 of each channel's
noise sigma) count once: the first of them is fitted and the others are named in a warning.
Pairs the recordings can hardly separate (a pulley radius and the anchors, a winch gain and
a length offset, ...) are named in a warning after the fit.
Standard deviations are Gauss-Newton (JᵀJ)⁻¹ at the optimum; --posterior adds emcee
intervals. The chain length is chosen from the measured autocorrelation time τ (extended
in chunks until 50 τ are kept, at most --max-chain steps); a fixed --steps N that turns
out shorter than 50 τ is refused with the number of steps needed.
"""

import warnings

import numpy as np

from cstiffjax.cable.laws import CableLaw
from cstiffjax.commands.common import (
    best_effort,
    check_outputs,
    output_folder,
    report_problems,
    resolve_path,
    say_replacing,
    write_json,
)
from cstiffjax.core.status import describe
from cstiffjax.core.text import terminal
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot_io import load_robot
from cstiffjax.io.screening import distinct, duplicate_groups, duplicate_samples
from fitting.calibration.models import FIT_LAWS, sensor_fields
from fitting.calibration.parameters import SESSION_PARAMETERS
from fitting.diagnosis.localize import rms as rms_of

NAME = "fit"
PLOT_FILES = ("residuals.png", "corner.png", "trace.png")  # written by --plots DIR (the last two with --posterior)
HELP = "calibrate parameters (EA, offsets, anchors, ...) on recordings"


def add_arguments(p):
    p.add_argument("robot", help="robot description TOML (or a bundled example name)")
    p.add_argument("recordings", help="recordings CSV (or a bundled example name)")
    p.add_argument("--free", default="EA", help="comma-separated free parameters (default: EA)")
    p.add_argument("--law", choices=[law.name for law in CableLaw if law in FIT_LAWS], default="spring",
                   help="cable law (default: spring)")
    p.add_argument("--max-steps", type=int, default=100, help="Levenberg-Marquardt iterations (default 100)")
    p.add_argument("--drop-invalid", action="store_true",
                   help="drop recordings rows with missing values (reported: count and file rows)")
    p.add_argument("--sort-by-time", action="store_true",
                   help="sort the samples by the time column when it goes backwards (else that is an error)")
    p.add_argument("--posterior", action="store_true", help="also sample the posterior with emcee")
    p.add_argument("--walkers", type=int, default=32, help="emcee walkers (default 32)")
    p.add_argument("--steps", type=int, default=None,
                   help="emcee steps (default: automatic, until 50 autocorrelation times, see --max-chain)")
    p.add_argument("--max-chain", type=int, default=20000,
                   help="cap of the automatic chain length, steps (default 20000)")
    p.add_argument("--seed", type=int, default=0, help="emcee seed (default 0)")
    p.add_argument("--json", metavar="OUT", help="write values, std, covariance, residuals as JSON")
    p.add_argument("--plots", metavar="DIR", help="write residual (and corner/trace) figures to DIR")


def run(args) -> int:
    from fitting.calibration.least_squares import IdentifiabilityWarning, calibrate
    from fitting.diagnosis.sample_checks import time_order
    from fitting.posterior.sampler import ChainTooShortError, plan, posterior_predictive_check, sample_posterior

    law = CableLaw.parse(args.law)  # (argparse's choices checked the name)
    robot_path, rec_path = resolve_path(args.robot), resolve_path(args.recordings)
    check_outputs((robot_path, rec_path), files={"--json": args.json}, folders={"--plots": (args.plots,
                                                                                          _plot_files(args))})
    robot = load_robot(robot_path)
    rec = load_recordings(rec_path, robot, drop_invalid=args.drop_invalid)
    rows, dropped = list(rec.rows), list(rec.dropped_rows)  # file line numbers, from the loader
    rec, rows, was_sorted = time_order(rec, sort_by_time=args.sort_by_time, rows=rows)
    read, groups = rec.num_samples, duplicate_groups(rec, robot.noise)
    copies = duplicate_samples(rec, groups, rows, noise=robot.noise)
    rec, rows = distinct(rec, rows, groups)  # each measurement counted once (copies would shrink every interval)
    print(terminal(f"robot {robot.name}: {robot.num_cables} cables; {read} samples")
          + (f" ({rec.num_samples} distinct)" if rec.num_samples < read else "")
          + (f"; dropped {len(dropped)} invalid rows: {dropped}" if dropped else "")
          + ("; sorted by time (--sort-by-time)" if was_sorted else ""))
    for w in copies:
        print(terminal(f"warning: {w}"))
    with warnings.catch_warnings():  # only these: printed below from fit.weak; a cache warning is shown
        warnings.filterwarnings("ignore", category=IdentifiabilityWarning)
        fit = calibrate(robot, rec, free=args.free, law=law, max_steps=args.max_steps)
    print(f"law {law.name}; free {', '.join(fit.spec.free)}; {int(fit.ls.num_steps)} LM steps")
    print(fit.summary())
    std, undetermined = _undetermined(fit)
    for w in undetermined:
        print(f"warning: {w}")
    r = np.asarray(fit.residuals)
    keep = np.ones(len(r), bool)
    rms = {k: v for k, v in rms_of(r, keep, robot.noise, rec, sensor_fields(rec)).items() if v is not None}
    units = {"position": "m", "rotation": "rad", "tension": "N", "swivel": "rad", "ahrs": "rad"}
    print("rms residuals: " + ", ".join(f"{k} {v:.3g} {units[k]}" for k, v in rms.items()))
    out = {"robot": robot.name, "samples": rec.num_samples, "law": law.name, "free": list(fit.spec.free),
           "names": list(fit.names), "values": {n: fit.values[n] for n in fit.spec.free},
           "std": std, "covariance": fit.covariance, "correlation": fit.correlation,
           "chi2": fit.chi2, "dof": fit.dof, "chi2_per_dof": fit.chi2_per_dof, "rms": rms,
           "warnings": copies + list(fit.weak) + undetermined, "residual_channels": list(fit.channels),
           "residuals": fit.residuals,
           "status": describe(fit.result), "dropped_rows": {"count": len(dropped), "rows": dropped},
           "sorted_by_time": was_sorted}
    if any(n in SESSION_PARAMETERS for n in fit.spec.free):  # the rows of the per-session values
        out["sessions"] = list(fit.spec.session_ids)
    if args.json:  # the fit is written before the posterior is sampled (rewritten with it below)
        write_json(args.json, out)
    post = None
    if args.posterior:
        print(_plan_line(plan(fit, nwalkers=args.walkers, nsteps=args.steps, max_steps=args.max_chain,
                              min_steps=min(1000, args.max_chain), seed=args.seed)), flush=True)
        post = sample_posterior(fit, nwalkers=args.walkers, nsteps=args.steps, seed=args.seed,
                                max_steps=args.max_chain, min_steps=min(1000, args.max_chain))
        try:
            s = post.summary()
        except ChainTooShortError as e:
            print(f"posterior: {e} (raise --max-chain, or give --steps)")
            out["posterior"] = {"error": str(e), "tau": post.tau}
        else:
            ppc = posterior_predictive_check(post, seed=args.seed)
            print(f"posterior: {post.num_walkers} walkers x {post.num_steps} steps (burn-in {post.burn}), "
                  f"acceptance {s['acceptance_fraction']:.2f}, max tau {np.max(s['tau']):.1f} steps, "
                  f"min ESS {np.min(s['ess']):.0f}, predictive p-value {ppc['p_value']:.2f}")
            print(f"{'parameter':<22}{'mean':>16}{'std':>12}{'5%':>16}{'95%':>16}")
            for i, n in enumerate(s["names"]):
                print(f"{n:<22}{s['mean'][i]:>16.8g}{s['std'][i]:>12.4g}{s['lower'][i]:>16.8g}{s['upper'][i]:>16.8g}")
            out["posterior"] = {k: s[k] for k in ("names", "mean", "std", "lower", "upper", "level", "tau", "ess",
                                                  "acceptance_fraction")}
            out["posterior"]["predictive_p_value"] = ppc["p_value"]
        out["posterior"].update(walkers=post.num_walkers, steps=post.num_steps, burn=post.burn)
    if args.json:
        if post is not None:
            write_json(args.json, out)
        print(terminal(f"wrote {args.json}"))
    problems = _plots(args.plots, _plot_files(args), fit, post) if args.plots else []
    return report_problems(NAME, problems)


def _undetermined(fit) -> tuple[dict, list[str]]:
    """The standard deviations to report, and one warning per positive (log-transformed) free
    value that the recordings do not determine: fitted to 0 or not finite, or a standard
    deviation above :data:`~fitting.diagnosis.selection.EA_LOG_STD_MAX` times the value (an
    ``EA`` of a cable that carries almost no tension in every sample). Their standard
    deviations are reported as ``None`` (unknown), their values as fitted, flagged.

    **Returns:** ``({name: list of std or None}, [warning])``.
    """
    from fitting.diagnosis.selection import EA_LOG_STD_MAX

    std, warns = {}, []
    for name, sd in fit.std.items():
        sd = np.atleast_1d(np.asarray(sd, dtype=float))
        val = np.atleast_1d(np.asarray(fit.values[name], dtype=float))
        out = sd.tolist()
        if fit.spec.transform(name) == "log":
            for i, (v, s) in enumerate(zip(val.ravel(), sd.ravel(), strict=True)):
                if np.isfinite(v) and v > 0 and np.isfinite(s) and s > 0 and s <= EA_LOG_STD_MAX * v:
                    continue
                out[i] = None
                label = f"{name}[{i + 1}]" if val.size > 1 else name
                warns.append(f"{label}: the recordings do not determine it (fitted {v:.3g} "
                             f"{fit.spec.unit(name)}, standard deviation unknown); e.g. a cable that carries "
                             f"almost no tension in every sample")
        std[name] = out if np.ndim(fit.std[name]) else out[0]
    return std, warns


def _plot_files(args) -> tuple[str, ...]:
    """The figures this run draws into ``--plots DIR`` (corner and trace only with ``--posterior``)."""
    return PLOT_FILES if args.posterior else PLOT_FILES[:1]


def _plots(directory, names, fit, post) -> list[str]:
    """The figures ``names`` (:func:`_plot_files`), in a folder that appears whole
    (:func:`~cstiffjax.commands.common.output_folder`): only these files of ``directory``
    are replaced, nothing else there is removed. Returns the figures that could not be drawn."""
    from pathlib import Path

    from fitting import plots

    d, problems = Path(directory), []
    with output_folder(d, names, on_replace=say_replacing) as tmp:
        figures = [("residuals.png", plots.residual_plot, fit)]
        if post is not None:
            figures += [("corner.png", plots.corner, post), ("trace.png", plots.trace_plot, post)]
        for name, draw, what in figures:
            best_effort(problems, tmp / name, lambda n=name, f=draw, w=what: f(w).savefig(tmp / n, dpi=120))
    print(terminal(f"wrote figures to {d}"))
    return problems


def _plan_line(p) -> str:
    """One line saying how long the posterior will sample, before it starts."""
    per_k = 1000 * p["s_per_step"]
    if p["steps_min"] == p["steps_max"]:
        return (f"posterior: {p['walkers']} walkers x {p['steps_max']} steps, about "
                f"{p['steps_max'] * p['s_per_step']:.0f} s ({per_k:.2g} s per 1000 steps)")
    return (f"posterior: {p['walkers']} walkers, {p['steps_min']} steps first, extended until 50 autocorrelation "
            f"times are kept, at most {p['steps_max']} steps: {p['steps_min'] * p['s_per_step']:.0f} s to "
            f"{p['steps_max'] * p['s_per_step']:.0f} s ({per_k:.2g} s per 1000 steps)")

