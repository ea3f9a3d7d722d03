"""Figures for the dynamics (matplotlib only): platform and cable FRFs like Yuan et al. 2015
Figs 9-10, and the first natural frequency over a workspace grid like Fig. 13.

Each function takes plain arrays, writes one PNG and returns its path.
"""

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np


def _mark(ax, freqs, color, label, style="--"):
    for k, f in enumerate(np.asarray(freqs)):
        ax.axvline(f, color=color, ls=style, lw=0.8, alpha=0.7, label=label if k == 0 else None)


def _finish_frf(fig, ax, frequencies, title, path) -> Path:
    """Axes labels, limits, legend and grid of an FRF plot; save to ``path`` and close."""
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("acceleration / force [m s⁻² N⁻¹]")
    ax.set_xlim(float(frequencies[0]), float(frequencies[-1]))
    ax.set_title(title)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the curves, never on them
    ax.grid(True, which="both", alpha=0.3)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def plot_platform_frf(path, frequencies, accel, *, natural=None, spring=None, sagging=None,
                      title="Platform FRF") -> Path:
    """``|a|`` per unit force (m/s²/N, log scale) of the platform in its own frame.

    **Arguments:** ``frequencies`` (n,) Hz; ``accel`` (n, 3) complex accelerations
    ``[x, y, z]`` (platform frame); optional vertical markers: ``natural`` (DSM,
    platform-dominated), ``spring`` and ``sagging`` (classical models), Hz.
    """
    fig, ax = plt.subplots(figsize=(10, 4.5), layout="constrained")
    for k, name in enumerate("xyz"):
        ax.semilogy(frequencies, np.abs(accel[:, k]), lw=1.0, label=f"|a_{name}| / F")
    if natural is not None:
        _mark(ax, natural, "k", "DSM natural frequencies (platform-dominated)", ":")
    if spring is not None:
        _mark(ax, spring, "tab:red", "massless spring model")
    if sagging is not None:
        _mark(ax, sagging, "tab:green", "static sagging model", "-.")
    return _finish_frf(fig, ax, frequencies, title, path)


def plot_cable_frf(path, frequencies, accel, *, clamped=None, title="Cable FRF") -> Path:
    """Cable point acceleration per unit force (Yuan et al. 2015 Fig. 9): ``accel`` (n, 3) complex
    in the chord frame ``[chord, in-plane normal, out of plane]``; ``clamped`` marks the
    fixed-end cable frequencies (Hz)."""
    fig, ax = plt.subplots(figsize=(10, 4.5), layout="constrained")
    for k, name in enumerate(("chord", "in-plane", "out-of-plane")):
        ax.semilogy(frequencies, np.abs(accel[:, k]), lw=1.0, label=f"|a| {name}")
    if clamped is not None:
        _mark(ax, clamped, "k", "clamped-cable frequencies", ":")
    return _finish_frf(fig, ax, frequencies, title, path)


def plot_frequency_map(path, xs, ys, f1, *, title="First natural frequency [Hz]") -> Path:
    """Map of the first natural frequency ``f1`` (len(ys), len(xs)) Hz over ``x``, ``y`` (m)
    (Yuan et al. 2015 Fig. 13). Poses without a first frequency (``nan``: a cable tension not
    positive there) are drawn grey and counted under the map."""
    fig, ax = plt.subplots(figsize=(5.5, 4.8), layout="constrained")
    f1 = np.ma.masked_invalid(np.asarray(f1, dtype=float))
    cmap = plt.get_cmap("viridis").with_extremes(bad="0.82")
    im = ax.pcolormesh(xs, ys, f1, shading="auto", cmap=cmap)
    cs = ax.contour(xs, ys, f1, colors="w", linewidths=0.6)
    ax.clabel(cs, fontsize=7, fmt="%.2f")
    fig.colorbar(im, ax=ax, label="Hz")
    missing = int(np.ma.count_masked(f1))
    if missing:
        ax.text(0.5, -0.16, f"grey: no first frequency at {missing} of {f1.size} poses (a cable tension not positive)",
                transform=ax.transAxes, ha="center", va="top", fontsize=8)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=10)
    ax.set_aspect("equal")
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)
