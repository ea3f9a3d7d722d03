"""The diagnosis report's figures: the residual of the localizing channel against its
covariate, the χ² per channel, the robot with its largest misfits, and the residual
against each discovered term's driver. Each is computed here as a *plan* (plain arrays
and text: :func:`figure_plans`) and drawn by :mod:`fitting.diagnosis.figure_render` (matplotlib,
Agg backend, imported lazily), in this process (:func:`write_figures`, :func:`open_figures`)
or in a separate one while the posterior samples (:mod:`fitting.diagnosis.figure_worker`).
Text from the inputs (the robot's name, covariate names) is escaped
(:func:`cstiffjax.core.text.figure`).
"""

import numpy as np

from cstiffjax.core.text import figure as figure_text
from cstiffjax.io import schema
from cstiffjax.io.atomic import not_written
from fitting.diagnosis.discover_report import figure_plans as discovered_plans
from fitting.diagnosis.figure_render import draw_plans, render
from fitting.diagnosis.localize import channel_labels


def _labels(diagnosis) -> list[str]:
    """The labels of the residual columns (:func:`fitting.diagnosis.localize.channel_labels`)."""
    a = diagnosis.arrays
    return channel_labels(a["robot"].num_cables, tuple(a.get("sensors", ())))


def _localizer(diagnosis):
    """(channel index, covariate name) that localized the mismatch (top channel)."""
    ch = diagnosis.localization["channels"]
    if not ch:
        return None, None
    return _labels(diagnosis).index(ch[0]["where"]), ch[0]["correlates_with"]


def _unit(name) -> str:
    """SI unit of a covariate of :func:`fitting.diagnosis.localize.covariates` ('' when unknown):
    a recordings column's from :mod:`cstiffjax.io.schema`, m/kg for the sag parameter ``sag_i``."""
    return "m/kg" if name.startswith("sag_") else schema.unit(name)


def _covariate_label(name) -> tuple[str, bool]:
    """The x-axis label of a covariate and whether it is a direction of length change
    (``dir_i``, values -1/0/+1, drawn as three categories)."""
    if name.startswith("dir_"):
        return f"direction of the last length change of cable {name[4:]}", True
    return figure_text(f"{name} ({_unit(name)})" if _unit(name) else name), False


def _residual_plan(diagnosis, j, cov) -> dict:
    """The plan of ``residuals.png`` (:func:`fitting.diagnosis.figure_render.residuals`);
    ``sessions`` the recordings' session id of each sample when there is more than one
    (drawn apart: each session's clock starts again), else None."""
    a = diagnosis.arrays
    labels = _labels(diagnosis)
    xlabel, categories = _covariate_label(cov)
    panels = [(np.asarray(r)[:, j], f"{title} (χ²/dof {c2:.3g})")
              for r, c2, title in ((a["r_base"], diagnosis.baseline["chi2_per_dof"], "baseline"),
                                   (a["r_final"], diagnosis.final["chi2_per_dof"],
                                    " + ".join(["baseline", *diagnosis.effects])))]
    session = a.get("session")
    several = session is not None and len(np.unique(session)) > 1
    return {"x": np.asarray(a["covariates"][cov], dtype=float), "keep": np.asarray(a["keep"], bool),
            "xlabel": xlabel, "categories": categories, "panels": panels,
            "sessions": np.asarray(session, dtype=int) if several else None,
            "ylabel": f"whitened residual of {labels[j]} (σ)",
            "suptitle": f"{figure_text(diagnosis.robot)}: {labels[j]} against {figure_text(cov)}, before and after "
                        f"the diagnosis"}


_GROUP_WORDS = (("position", "position"), ("orientation", "orientation"), ("tension", "cable tensions"),
                ("swivel angle", "swivel angles"), ("AHRS angle", "AHRS"))


def _chi2_plan(diagnosis) -> dict:
    """The plan of ``chi2_shares.png`` (:func:`fitting.diagnosis.figure_render.chi2_shares`):
    the recorded channels only (a channel without a recorded value has no χ² to draw)."""
    a = diagnosis.arrays
    keep = a["keep"]
    m, sensors = a["robot"].num_cables, a.get("sensors", ())
    recorded = np.count_nonzero(np.asarray(a["r_base"])[keep], axis=0)  # recorded values per channel
    shown = np.flatnonzero(recorded > 0)
    labels = [channel_labels(m, sensors)[k] for k in shown]
    bars = []
    for r, lab, c2 in ((a["r_base"], "baseline", diagnosis.baseline["chi2_per_dof"]),
                       (a["r_final"], " + ".join(["baseline", *diagnosis.effects]), diagnosis.final["chi2_per_dof"])):
        c = np.sum(np.asarray(r)[keep] ** 2, 0)
        bars.append((c[shown], f"{lab} (χ²/dof {c2:.3g}, total χ² {np.sum(c):.4g})"))
    low = min(float(np.min(c)) for c, _ in bars) if len(shown) else 1.0
    groups = [words for quantity, words in _GROUP_WORDS if any(lb.startswith(quantity + " ") for lb in labels)]
    return {"ticks": [lb.rpartition(" ")[2] for lb in labels], "bars": bars, "expected": recorded[shown],
            "bottom": 10.0 ** np.floor(np.log10(max(0.5 * low, 1e-3))),
            "xlabel": "channel (" + ", ".join(groups) + "; channels not recorded are not drawn)",
            "title": f"{figure_text(diagnosis.robot)}: χ² per channel, baseline vs final model"}


def robot_view(diagnosis):
    """What ``robot.png`` shows: ``(pose, highlight, arrows, arrow_label)``: the recorded
    pose nearest to the samples' mean position; the cables whose tension channels carry
    the most baseline χ² (the top one, and the second when it has at least half as much);
    the anchor or attachment offsets the diagnosis found (``arrows`` None when it found none)."""
    a = diagnosis.arrays
    poses, keep = np.asarray(a["poses"]), a["keep"]
    centre = poses[keep, :3].mean(0)
    pose = poses[int(np.argmin(np.where(keep, np.linalg.norm(poses[:, :3] - centre, axis=1), np.inf)))]
    chi2 = np.sum(np.asarray(a["r_base"])[keep, 6:] ** 2, 0)
    order = np.argsort(chi2)[::-1]
    highlight = [int(order[0])] + ([int(order[1])] if len(order) > 1 and chi2[order[1]] >= 0.5 * chi2[order[0]]
                                   else [])
    for effect, where in (("anchor_offset", "anchors"), ("attachment_offset", "attachments")):
        if effect in diagnosis.effects:
            offset = np.asarray(diagnosis.final["parameters"][effect]["offset"]["value"], float)
            return pose, highlight, (offset, where), effect.replace("_", " ") + "s found"
    return pose, highlight, None, None


def _robot_plan(diagnosis) -> dict:
    """The plan of ``robot.png`` (:func:`fitting.diagnosis.figure_render.robot`): the scene
    of :func:`robot_view`'s pose (:func:`cstiffjax.plots.robot.robot_scene`)."""
    from cstiffjax.plots.robot import robot_scene

    robot = diagnosis.arrays["robot"]
    pose, highlight, arrows, label = robot_view(diagnosis)
    cables = ", ".join(str(i + 1) for i in highlight)
    return {"scene": robot_scene(robot, pose), "highlight": highlight,
            "arrows": None if arrows is None else arrows[0], "arrow_at": "anchors" if arrows is None else arrows[1],
            "arrow_label": label,
            "title": f"{figure_text(diagnosis.robot)} at a central recorded pose\nred: "
                     f"cable{'s' * (len(highlight) > 1)} {cables}, the largest tension misfit of the baseline"}


def _builders(diagnosis) -> list:
    """``[(file name, kind, build)]``: the figures of ``diagnosis``, each with the function
    that computes its plan."""
    out = []
    j, cov = _localizer(diagnosis)
    if j is not None and cov in diagnosis.arrays["covariates"]:
        out.append(("residuals.png", "residuals", lambda: _residual_plan(diagnosis, j, cov)))
    out.append(("chi2_shares.png", "chi2_shares", lambda: _chi2_plan(diagnosis)))
    if "robot" in diagnosis.arrays and getattr(diagnosis.arrays["robot"], "kind", "") == "cdpr":
        out.append(("robot.png", "robot", lambda: _robot_plan(diagnosis)))
    return out


def figure_plans(diagnosis, problems: list | None = None) -> list:
    """``[(file name, kind, plan)]``: every figure of the report, computed and ready to draw
    (:func:`fitting.diagnosis.figure_render.render`). With ``problems`` (a list), a figure
    whose plan cannot be computed is left out and named there
    (:func:`cstiffjax.io.atomic.not_written`, as :func:`write_figures` names a figure it
    cannot draw); without it, the error is raised."""

    def attempt(name, build, default):
        if problems is None:
            return build()
        try:
            return build()
        except Exception as e:  # the results must not be lost to a figure
            problems.append(not_written(name, e))
            return default

    plans = [(name, kind, plan) for name, kind, build in _builders(diagnosis)
             if (plan := attempt(name, build, None)) is not None]
    discovered = attempt("discovered_*.png", lambda: discovered_plans(diagnosis), [])
    return plans + [(name, "discovered", plan) for name, plan in discovered]


def open_figures(diagnosis) -> dict:
    """The report's figures as open matplotlib figures, ``{file name: Figure}`` (a notebook
    shows them; :func:`write_figures` writes them)."""
    return {name: render(kind, plan, None) for name, kind, plan in figure_plans(diagnosis)}


def write_figures(diagnosis, out_dir, problems: list | None = None) -> list[str]:
    """Draw the report's figures into the folder ``out_dir`` and return the file names
    written: ``residuals.png`` (baseline and final residual of the localizing channel against
    the covariate that localized it, each panel on its own scale; the direction of the last
    length change as three categories), ``chi2_shares.png`` (absolute χ² per channel,
    baseline vs final, with the noise level), ``robot.png`` (the robot at a central recorded
    pose, the cables with the largest misfit in red, found anchor/attachment offsets as
    scaled arrows: :func:`robot_view`) and ``discovered_<k>.png`` (the residual against each
    discovered term's driver).

    With ``problems`` (a list), a figure that cannot be drawn is left out and the reason
    appended there (:func:`cstiffjax.io.atomic.best_effort`); without it, the error is raised."""
    return draw_plans(figure_plans(diagnosis, problems), out_dir, problems)
