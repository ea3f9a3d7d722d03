"""The diagnosis report's figures (matplotlib, Agg backend, imported lazily): the residual
of the localizing channel against its covariate, the χ² per channel and the robot with
its largest misfits. Text from the inputs (the robot's name, covariate names) is escaped
(:func:`cstiffjax.core.text.figure`).
"""

from pathlib import Path

import numpy as np

from cstiffjax.core.text import figure as figure_text
from cstiffjax.io import schema
from cstiffjax.io.atomic import best_effort
from fitting.diagnosis.discover_report import figures as discovered_figures
from fitting.diagnosis.localize import channel_labels


def _localizer(diagnosis):
    """(channel index, covariate name) that localized the mismatch (top channel)."""
    ch = diagnosis.localization["channels"]
    if not ch:
        return None, None
    labels = channel_labels(diagnosis.arrays["r_base"].shape[1] - 6)
    return labels.index(ch[0]["where"]), ch[0]["correlates_with"]


def _unit(name) -> str:
    """SI unit of a covariate of :func:`fitting.diagnosis.localize.covariates` ('' when unknown):
    a recordings column's from :mod:`cstiffjax.io.schema`, m/kg for the sag parameter ``sag_i``."""
    return "m/kg" if name.startswith("sag_") else schema.unit(name)


def _covariate_axis(ax, name, x, rng):
    """x positions and the axis label of a covariate; the direction of the last length
    change (``dir_i``, values -1/0/+1) is drawn as three categories (jittered)."""
    if not name.startswith("dir_"):
        ax.set_xlabel(figure_text(f"{name} ({_unit(name)})" if _unit(name) else name))
        return x
    ax.set_xticks([-1, 0, 1], ["shortened\n(−1)", "unchanged\n(0)", "lengthened\n(+1)"])
    ax.set_xlim(-1.6, 1.6)
    ax.set_xlabel(f"direction of the last length change of cable {name[4:]}")
    return x + rng.uniform(-0.15, 0.15, size=x.shape)


def _finish(fig, path, **options):
    """Write ``fig`` to ``path`` and close it; with ``path`` None return it open (to show)."""
    if path is None:
        return fig
    import matplotlib.pyplot as plt

    fig.savefig(path, **options)
    plt.close(fig)
    return path


def _residual_figure(diagnosis, j, cov, path):
    import matplotlib.pyplot as plt

    a = diagnosis.arrays
    keep = a["keep"]
    labels = channel_labels(a["r_base"].shape[1] - 6)
    # each panel on its own scale: the final residual is often far smaller than the baseline's
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.4), sharex=True, layout="constrained")
    rng = np.random.default_rng(0)
    x = a["covariates"][cov]
    for k, (r, c2, title) in enumerate(((a["r_base"], diagnosis.baseline["chi2_per_dof"], "baseline"),
                                        (a["r_final"], diagnosis.final["chi2_per_dof"],
                                         " + ".join(["baseline", *diagnosis.effects])))):
        xk = _covariate_axis(ax[k], cov, np.asarray(x, dtype=float), rng)
        ax[k].axhspan(-1, 1, color="0.92", zorder=0, label="±1 σ (noise level)")
        ax[k].scatter(xk[keep], r[keep, j], s=12, label="samples")
        if np.any(~keep):
            ax[k].scatter(xk[~keep], r[~keep, j], s=30, marker="x", color="red", label="outliers (left out)")
        ax[k].axhline(0, color="k", lw=0.5)
        ax[k].set_title(f"{title} (χ²/dof {c2:.3g})")
        ax[k].set_ylabel(f"whitened residual of {labels[j]} (σ)")
        ax[k].yaxis.set_tick_params(labelleft=True)
    fig.suptitle(f"{figure_text(diagnosis.robot)}: {labels[j]} against {figure_text(cov)}, before and after the "
                 f"diagnosis")
    handles, names = ax[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="outside lower center", ncol=len(names), fontsize=8)
    return _finish(fig, path, dpi=110)


def _chi2_figure(diagnosis, path):
    import matplotlib.pyplot as plt

    a = diagnosis.arrays
    keep = a["keep"]
    m, sensors = a["robot"].num_cables, a.get("sensors", ())
    labels = channel_labels(m, sensors)
    idx = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(max(6.5, 0.65 * len(labels)), 4.4), layout="constrained")
    for k, (r, lab, c2) in enumerate(((a["r_base"], "baseline", diagnosis.baseline["chi2_per_dof"]),
                                      (a["r_final"], " + ".join(["baseline", *diagnosis.effects]),
                                       diagnosis.final["chi2_per_dof"]))):
        c = np.sum(r[keep] ** 2, 0)
        ax.bar(idx + 0.4 * k - 0.2, c, 0.4, label=f"{lab} (χ²/dof {c2:.3g}, total χ² {np.sum(c):.4g})")
    expected = np.count_nonzero(a["r_base"][keep], axis=0)  # recorded values per channel
    ax.scatter(idx, expected, marker="_", s=400, color="k", zorder=3, label="noise level (χ² = number of values)")
    ax.set_yscale("log")
    low = min(np.min(np.sum(r[keep] ** 2, 0)) for r in (a["r_base"], a["r_final"]))
    ax.set_ylim(bottom=10.0 ** np.floor(np.log10(max(0.5 * low, 1e-3))))  # bars start well below the data
    ax.set_xticks(idx, [lb.rpartition(" ")[2] for lb in labels], rotation=90 if len(labels) > 16 else 0)
    ax.set_xlabel("channel (" + ", ".join(["position", "orientation", "cable tensions",
                                           *(("swivel angles",) if "swivel" in sensors else ()),
                                           *(("AHRS",) if "ahrs" in sensors else ())]) + ")")
    ax.set_ylabel("χ² of the channel (whitened, log scale)")
    ax.set_title(f"{figure_text(diagnosis.robot)}: χ² per channel, baseline vs final model")
    fig.legend(loc="outside lower center", ncol=2, fontsize=8)
    return _finish(fig, path, dpi=110)


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


def _robot_figure(diagnosis, path):
    import matplotlib.pyplot as plt

    from cstiffjax.plots.robot import draw_robot

    robot = diagnosis.arrays["robot"]
    pose, highlight, arrows, label = robot_view(diagnosis)
    fig = plt.figure(figsize=(8, 6.5))
    ax = fig.add_subplot(projection="3d")
    draw_robot(ax, robot, pose, highlight=highlight, arrows=None if arrows is None else arrows[0],
               arrow_at="anchors" if arrows is None else arrows[1], arrow_label=label)
    cables = ", ".join(str(i + 1) for i in highlight)
    ax.set_title(f"{figure_text(diagnosis.robot)} at a central recorded pose\nred: cable{'s' * (len(highlight) > 1)} "
                 f"{cables}, the largest tension misfit of the baseline", fontsize=9)
    return _finish(fig, path, dpi=110, bbox_inches="tight")


def open_figures(diagnosis) -> dict:
    """The report's figures as open matplotlib figures, ``{file name: Figure}`` (a notebook
    shows them; :func:`write_figures` writes them)."""
    out = {}
    j, cov = _localizer(diagnosis)
    if j is not None and cov in diagnosis.arrays["covariates"]:
        out["residuals.png"] = _residual_figure(diagnosis, j, cov, None)
    out["chi2_shares.png"] = _chi2_figure(diagnosis, None)
    if "robot" in diagnosis.arrays and getattr(diagnosis.arrays["robot"], "kind", "") == "cdpr":
        out["robot.png"] = _robot_figure(diagnosis, None)
    return out


def write_figures(diagnosis, out_dir, problems: list | None = None) -> list[str]:
    """``residuals.png`` (baseline and final residual of the localizing channel against the
    covariate that localized it, each panel on its own scale; the direction of the last length
    change as three categories), ``chi2_shares.png`` (absolute χ² per channel, baseline
    vs final, with the noise level) and ``robot.png`` (the robot at a central recorded pose,
    the cables with the largest misfit in red, found anchor/attachment offsets as scaled
    arrows: :func:`robot_view`). Returns the file names written.

    With ``problems`` (a list), a figure that cannot be drawn is left out and the reason
    appended there (:func:`cstiffjax.io.atomic.best_effort`); without it, the error is raised."""
    out = Path(out_dir)
    files = []

    def draw(name, fn):
        if problems is None:
            fn()
        elif not best_effort(problems, out / name, fn):
            return
        files.append(name)

    j, cov = _localizer(diagnosis)
    if j is not None and cov in diagnosis.arrays["covariates"]:
        draw("residuals.png", lambda: _residual_figure(diagnosis, j, cov, out / "residuals.png"))
    draw("chi2_shares.png", lambda: _chi2_figure(diagnosis, out / "chi2_shares.png"))
    if "robot" in diagnosis.arrays and getattr(diagnosis.arrays["robot"], "kind", "") == "cdpr":
        draw("robot.png", lambda: _robot_figure(diagnosis, out / "robot.png"))
    try:  # the residual against each discovered driver
        files += discovered_figures(diagnosis, out)
    except Exception as e:
        if problems is None or isinstance(e, OSError):
            raise
        for f in out.glob("discovered_*.png"):
            f.unlink()
        problems.append(f"discovered_*.png: not written ({type(e).__name__}: {e})")
    return files
