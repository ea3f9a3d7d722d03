"""Figures of fits and posteriors (matplotlib; nothing else in ``fitting`` imports this).

Every parameter is drawn unless the caller limits the count with ``max_params``; then the
figure says which were left out. Legends sit outside the data axes; layouts are
``constrained`` (no cut titles or labels).
"""

import numpy as np


def _left_out(names, p) -> str:
    rest = list(names[p:])
    if not rest:
        return ""
    shown = ", ".join(rest[:6]) + (f", … ({len(rest)} in all)" if len(rest) > 6 else "")
    return f"first {p} of {len(names)} parameters shown; left out: {shown}"


def _units(posterior, names) -> list[str]:
    """The unit of each named parameter of a Posterior (from its fit's parameter spec), or ''."""
    spec = getattr(getattr(posterior, "fit", None), "spec", None)
    if spec is None:
        return [""] * len(names)
    out = []
    for n in names:
        try:
            out.append(spec.unit(n.split("[")[0].split(".")[0]))
        except (KeyError, ValueError, AttributeError):
            out.append("")
    return out


def _label(name, unit) -> str:
    return f"{name} [{unit}]" if unit and unit != "1" else name


def corner(posterior, *, names=None, truths=None, bins: int = 30, max_params: int | None = None, fig=None,
           units=None):
    """Corner-style plot: 1-D histograms on the diagonal, 2-D scatter below it; axis labels
    with units, at most three ticks per axis (no colliding labels).

    **Arguments:** ``posterior``: a :class:`~fitting.posterior.sampler.Posterior` (post-burn-in
    samples are shown) or an ``(N, p)`` array; ``names``: labels; ``truths``: values to
    mark (``(p,)``); ``max_params``: draw only the first ones (default all; the figure
    title names those left out); ``units``: one per parameter (default: the fit's).

    **Returns:** the matplotlib ``Figure``.
    """
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    x = np.asarray(posterior) if isinstance(posterior, (np.ndarray, list, tuple)) else posterior.flat()
    names = list(names if names is not None else getattr(posterior, "names", [f"p{i}" for i in range(x.shape[1])]))
    units = list(units) if units is not None else _units(posterior, names)
    p = x.shape[1] if max_params is None else min(x.shape[1], max_params)
    size = min(1.8 * p + 1, 24)
    fig = fig or plt.figure(figsize=(size, size), layout="constrained")
    axes = fig.subplots(p, p, squeeze=False)
    for i in range(p):
        for j in range(p):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            ax.ticklabel_format(useOffset=False)  # an offset text would sit on the axis labels
            ax.xaxis.set_major_locator(MaxNLocator(3))
            ax.yaxis.set_major_locator(MaxNLocator(3))
            if i == j:
                ax.hist(x[:, i], bins=bins, histtype="step", color="k")
                ax.set_yticks([])
            else:
                ax.plot(x[:, j], x[:, i], ",", alpha=0.3, color="k")
                if truths is not None:
                    ax.axhline(truths[i], color="tab:red", lw=0.8)
            if truths is not None:
                ax.axvline(truths[j], color="tab:red", lw=0.8)
            if i == p - 1:
                ax.set_xlabel(_label(names[j], units[j]), fontsize=8)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(_label(names[i], units[i]), fontsize=8)
            elif j > 0:
                ax.set_yticklabels([])
            ax.tick_params(labelsize=6)
            ax.tick_params(axis="x", labelrotation=45)
    note = _left_out(names, p)
    title = "posterior samples" + (" (red: reference values)" if truths is not None else "")
    fig.suptitle(title + (f"\n{note}" if note else ""), fontsize=9)
    return fig


def _channel_groups(labels):
    """``[(title, [channel indices])]``: position, orientation, tensions, other."""
    groups = {"position": [], "orientation": [], "tension": [], "other": []}
    for k, lab in enumerate(labels):
        key = ("position" if lab in ("x", "y", "z") else "orientation" if lab in ("rx", "ry", "rz")
               else "tension" if lab.startswith("t_") else "other")
        groups[key].append(k)
    return [(title, idx) for title, idx in groups.items() if idx]


def _recorded(fit, r):
    """``(mask (n, k), session ids (n,) or None)`` of a CDPR fit's residuals: where a value
    was recorded (:func:`~fitting.calibration.models.measured_mask`; all true for other
    models) and each sample's session id in the recordings (None for one session)."""
    from fitting.calibration.models import measured_mask

    args = getattr(fit, "args", None)
    rec = args[1] if isinstance(args, tuple) and len(args) > 1 and hasattr(args[1], "pose_mask") else None
    if rec is None:
        return np.ones(r.shape, bool), None
    mask = measured_mask(rec, getattr(fit.residual_fn, "sensors", ()))
    if mask.shape != r.shape:
        return np.ones(r.shape, bool), None
    index = np.asarray(rec.session, dtype=int)  # 0..S-1 in a fit: the rows of spec.session_ids
    ids = np.array([fit.spec.session_id(i) for i in range(int(index.max()) + 1)])
    return mask, (ids[index] if len(ids) > 1 else None)


def residual_plot(fit, *, fig=None):
    """Whitened residuals per sample of a CDPR :class:`~fitting.calibration.least_squares.Fit`,
    one panel per channel group (position, orientation, tensions) so no two channels of a
    panel share a colour; each panel on its own scale with the grey ±1 σ noise band. Only
    recorded values are drawn (a channel never recorded gets no panel or legend entry);
    with several recording sessions, dashed lines separate them, labelled with the
    recordings' session ids.

    **Returns:** the matplotlib ``Figure``.
    """
    import matplotlib.pyplot as plt

    r = np.asarray(fit.residuals)
    r = r.reshape(r.shape[0], -1)
    mask, sessions = _recorded(fit, r)
    labels = list(fit.channels) or [f"c{i}" for i in range(r.shape[1])]
    shown = [k for k in range(r.shape[1]) if mask[:, k].any()]
    groups = [(title, [k for k in idx if k in shown]) for title, idx in _channel_groups(labels)]
    groups = [(title, idx) for title, idx in groups if idx]
    r = np.where(mask, r, np.nan)
    fig = fig or plt.figure(figsize=(9, 2.4 * len(groups) + 0.8), layout="constrained")
    axes = np.atleast_1d(fig.subplots(len(groups), 1, sharex=True))
    for ax, (title, idx) in zip(axes, groups):
        colours = plt.get_cmap("tab10" if len(idx) <= 10 else "tab20").colors
        ax.axhspan(-1, 1, color="0.9", zorder=0)
        for n, k in enumerate(idx):
            ax.plot(r[:, k], ".", ms=3, color=colours[n % len(colours)], label=labels[k])
        ax.set_ylabel(f"{title}\nresidual / σ", fontsize=8)
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0), ncol=1 if len(idx) <= 10 else 2)
    if sessions is not None:
        starts = [0, *(np.flatnonzero(np.diff(sessions) != 0) + 1)]
        for ax in axes:
            for s0 in starts[1:]:
                ax.axvline(s0 - 0.5, color="0.4", ls="--", lw=0.8)
        for s0 in starts:
            axes[0].annotate(f"session {sessions[s0]}", (s0 - 0.5, 1.0), xycoords=("data", "axes fraction"),
                             xytext=(2, 2), textcoords="offset points", fontsize=7, va="bottom")
    axes[-1].set_xlabel("sample" + (" (dashed: a new recording session)" if sessions is not None else ""))
    fig.suptitle(f"whitened residuals per channel group, χ²/dof = {float(fit.chi2_per_dof):.3g} (grey: ±1 σ)",
                 fontsize=10)
    return fig


def trace_plot(posterior, *, max_params: int | None = None, fig=None):
    """Walker traces of every parameter (burn-in shaded); ``max_params`` limits the count
    (the title then names those left out). **Returns:** the ``Figure``."""
    import matplotlib.pyplot as plt

    names = list(posterior.names)
    p = len(names) if max_params is None else min(len(names), max_params)
    fig = fig or plt.figure(figsize=(8, min(1.3 * p + 1, 40)), layout="constrained")
    axes = np.atleast_1d(fig.subplots(p, 1, sharex=True))
    for i, ax in enumerate(axes):
        ax.plot(posterior.samples[:, :, i], color="k", alpha=0.2, lw=0.5)
        ax.axvspan(0, posterior.burn, color="0.9")
        ax.set_ylabel(names[i], fontsize=7)
        ax.tick_params(labelsize=6)
    axes[-1].set_xlabel("step")
    note = _left_out(names, p)
    fig.suptitle(f"walker traces ({posterior.num_walkers} walkers; grey: burn-in, {posterior.burn} steps)"
                 + (f"\n{note}" if note else ""), fontsize=9)
    return fig
