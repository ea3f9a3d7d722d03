"""Figures of fits and posteriors (matplotlib; nothing else in ``fitting`` imports this)."""

import numpy as np


def corner(posterior, *, names=None, truths=None, bins: int = 30, max_params: int = 8, fig=None):
    """Corner-style plot: 1-D histograms on the diagonal, 2-D scatter below it.

    **Arguments:** ``posterior``: a :class:`~fitting.posterior.Posterior` (post-burn-in
    samples are shown) or an ``(N, p)`` array; ``names``: labels; ``truths``: values to
    mark (``(p,)``); ``max_params``: only the first ones are drawn.

    **Returns:** the matplotlib ``Figure``.
    """
    import matplotlib.pyplot as plt

    x = np.asarray(posterior) if isinstance(posterior, (np.ndarray, list, tuple)) else posterior.flat()
    names = list(names if names is not None else getattr(posterior, "names", [f"p{i}" for i in range(x.shape[1])]))
    p = min(x.shape[1], max_params)
    fig = fig or plt.figure(figsize=(2.0 * p + 1, 2.0 * p + 1))
    axes = fig.subplots(p, p, squeeze=False)
    for i in range(p):
        for j in range(p):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
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
                ax.set_xlabel(names[j], fontsize=8)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(names[i], fontsize=8)
            elif j > 0:
                ax.set_yticklabels([])
            ax.tick_params(labelsize=6)
    fig.tight_layout()
    return fig


def residual_plot(fit, *, fig=None):
    """Whitened residuals per sample and channel of a CDPR :class:`~fitting.least_squares.Fit`
    (one line per channel; ±1 band = the noise level).

    **Returns:** the matplotlib ``Figure``.
    """
    import matplotlib.pyplot as plt

    r = np.asarray(fit.residuals)
    r = r.reshape(r.shape[0], -1)
    fig = fig or plt.figure(figsize=(8, 4))
    ax = fig.subplots()
    labels = fit.channels or [f"c{i}" for i in range(r.shape[1])]
    for k in range(r.shape[1]):
        ax.plot(r[:, k], ".", ms=3, label=labels[k])
    ax.axhspan(-1, 1, color="0.9")
    ax.set_xlabel("sample")
    ax.set_ylabel("residual / σ")
    ax.set_title(f"χ²/dof = {float(fit.chi2_per_dof):.3g}")
    ax.legend(ncol=6, fontsize=6)
    fig.tight_layout()
    return fig


def trace_plot(posterior, *, max_params: int = 6, fig=None):
    """Walker traces of the first parameters (burn-in shaded). **Returns:** the ``Figure``."""
    import matplotlib.pyplot as plt

    p = min(posterior.samples.shape[-1], max_params)
    fig = fig or plt.figure(figsize=(8, 1.5 * p))
    axes = np.atleast_1d(fig.subplots(p, 1, sharex=True))
    for i, ax in enumerate(axes):
        ax.plot(posterior.samples[:, :, i], color="k", alpha=0.2, lw=0.5)
        ax.axvspan(0, posterior.burn, color="0.9")
        ax.set_ylabel(posterior.names[i], fontsize=7)
    axes[-1].set_xlabel("step")
    fig.tight_layout()
    return fig
