"""Drawing the diagnosis report's figures from their plans: plain data (numpy arrays,
strings, numbers) that :mod:`fitting.diagnosis.report_figures` computes from a
:class:`~fitting.diagnosis.diagnose.Diagnosis`.

numpy, matplotlib, :mod:`cstiffjax.plots.scene` and :mod:`cstiffjax.io.atomic` only, never JAX: the command line draws
the figures in a separate process while the posterior check samples
(:mod:`fitting.diagnosis.figure_worker`), and the same functions draw them in the calling
process otherwise (``write_figures``, a notebook's ``open_figures``), so the two give the
same files byte for byte.

Every renderer takes ``(plan, path)``: it writes the figure to ``path`` and returns the
path, or returns the open figure when ``path`` is None. :data:`RENDERERS` maps each plan
kind to its renderer.
"""

from pathlib import Path

import numpy as np

from cstiffjax.io.atomic import best_effort
from cstiffjax.plots.scene import draw_scene


def finish(fig, path, **options):
    """Write ``fig`` to ``path`` and close it; with ``path`` None return it open (to show)."""
    if path is None:
        return fig
    import matplotlib.pyplot as plt

    fig.savefig(path, **options)
    plt.close(fig)
    return path


def _covariate_axis(ax, plan, rng):
    """x positions and the axis label of the covariate; a direction of length change
    (values -1/0/+1, ``plan["categories"]``) is drawn as three jittered categories."""
    x = np.asarray(plan["x"], dtype=float)
    ax.set_xlabel(plan["xlabel"])
    if not plan["categories"]:
        return x
    ax.set_xticks([-1, 0, 1], ["shortened\n(−1)", "unchanged\n(0)", "lengthened\n(+1)"])
    ax.set_xlim(-1.6, 1.6)
    return x + rng.uniform(-0.15, 0.15, size=x.shape)


def residuals(plan, path):
    """``residuals.png``: the localizing channel's whitened residual against its covariate,
    baseline and final model, each panel on its own scale (the final residual is often far
    smaller than the baseline's), the noise band and the outliers left out."""
    import matplotlib.pyplot as plt

    keep = np.asarray(plan["keep"], bool)
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.4), sharex=True, layout="constrained")
    rng = np.random.default_rng(0)
    for k, (r, title) in enumerate(plan["panels"]):
        xk = _covariate_axis(ax[k], plan, rng)
        ax[k].axhspan(-1, 1, color="0.92", zorder=0, label="±1 σ (noise level)")
        sessions = plan.get("sessions")
        if sessions is None:
            ax[k].scatter(xk[keep], r[keep], s=12, label="samples")
        else:  # each session's clock starts again: one colour and marker per session
            for n, sid in enumerate(np.unique(sessions)):
                sel = keep & (np.asarray(sessions) == sid)
                ax[k].scatter(xk[sel], r[sel], s=12, marker="osD^v<>p"[n % 8], label=f"session {sid}")
        if np.any(~keep):
            ax[k].scatter(xk[~keep], r[~keep], s=30, marker="x", color="red", label="outliers (left out)")
        ax[k].axhline(0, color="k", lw=0.5)
        ax[k].set_title(title)
        ax[k].set_ylabel(plan["ylabel"])
        ax[k].yaxis.set_tick_params(labelleft=True)
    fig.suptitle(plan["suptitle"])
    handles, names = ax[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="outside lower center", ncol=len(names), fontsize=8)
    return finish(fig, path, dpi=110)


def chi2_shares(plan, path):
    """``chi2_shares.png``: the absolute χ² of every channel, baseline against final model
    (log scale), with the noise level (χ² = the channel's number of values)."""
    import matplotlib.pyplot as plt

    idx = np.arange(len(plan["ticks"]))
    longest = max((len(t) for t in plan["ticks"]), default=1)  # room for the widest label (swivel_1)
    fig, ax = plt.subplots(figsize=(max(6.5, max(0.65, 0.1 * longest) * len(idx)), 4.4), layout="constrained")
    for k, (c, label) in enumerate(plan["bars"]):
        ax.bar(idx + 0.4 * k - 0.2, c, 0.4, label=label)
    ax.scatter(idx, plan["expected"], marker="_", s=400, color="k", zorder=3,
               label="noise level (χ² = number of values)")
    ax.set_yscale("log")
    ax.set_ylim(bottom=plan["bottom"])  # bars start well below the data
    ax.set_xticks(idx, plan["ticks"], rotation=90 if len(idx) > 16 else 0)
    ax.set_xlabel(plan["xlabel"])
    ax.set_ylabel("χ² of the channel (whitened, log scale)")
    ax.set_title(plan["title"])
    fig.legend(loc="outside lower center", ncol=2, fontsize=8)
    return finish(fig, path, dpi=110)


def robot(plan, path):
    """``robot.png``: the robot at a central recorded pose (:func:`cstiffjax.plots.scene.draw_scene`),
    the cables with the largest misfit in red, found offsets as scaled arrows."""
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(8, 6.5))
    ax = fig.add_subplot(projection="3d")
    draw_scene(ax, plan["scene"], highlight=plan["highlight"], arrows=plan["arrows"], arrow_at=plan["arrow_at"],
               arrow_label=plan["arrow_label"])
    ax.set_title(plan["title"], fontsize=9)
    return finish(fig, path, dpi=110, bbox_inches="tight")


def discovered(plan, path):
    """``discovered_<k>.png``: the localizing channel's residual against a discovered
    term's driver, before (baseline) and after (with the term)."""
    import matplotlib.pyplot as plt

    keep = np.asarray(plan["keep"], bool)
    x = np.asarray(plan["x"], dtype=float)
    fig, ax = plt.subplots(1, 2, figsize=(10, 4), sharex=True, sharey=True)
    for q, (r, title) in enumerate(plan["panels"]):
        ax[q].scatter(x[keep], r[keep], s=12)
        ax[q].axhline(0, color="k", lw=0.5)
        ax[q].set_xlabel(plan["xlabel"])
        ax[q].set_title(title)
    ax[0].set_ylabel("whitened residual (σ)")
    fig.suptitle(plan["suptitle"], fontsize=9)
    fig.tight_layout()
    return finish(fig, path, dpi=110)


RENDERERS = {"residuals": residuals, "chi2_shares": chi2_shares, "robot": robot, "discovered": discovered}


def render(kind: str, plan: dict, path):
    """Draw the plan ``plan`` of kind ``kind`` (a key of :data:`RENDERERS`) to ``path``
    (None: return the open figure)."""
    return RENDERERS[kind](plan, path)


def draw_plans(plans, out_dir, problems: list | None = None) -> list[str]:
    """Draw ``plans`` ``[(file name, kind, plan)]`` into the folder ``out_dir``; returns the
    file names written. With ``problems`` (a list), a figure that cannot be drawn is left out
    and the reason appended there (:func:`cstiffjax.io.atomic.best_effort`: an ``OSError``,
    e.g. a full disk, is raised); without it, the error is raised."""
    out, files = Path(out_dir), []
    for name, kind, plan in plans:
        if problems is None:
            render(kind, plan, out / name)
        elif not best_effort(problems, out / name, lambda: render(kind, plan, out / name)):  # noqa: B023
            continue
        files.append(name)
    return files
