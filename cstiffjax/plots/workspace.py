"""Figures of workspace sweeps (matplotlib, Agg): a 3-D view of the members coloured by
their margin and sections ``z = const``. Each function writes one PNG and returns its path."""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np


def _save(fig, path):
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_members_3d(axes, member, margin, path, title, label):
    """Members of a grid ``(nx, ny, nz)`` as a 3-D scatter coloured by ``margin``."""
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    m = np.asarray(member, bool)
    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    sc = ax.scatter(X[m], Y[m], Z[m], c=np.asarray(margin)[m], s=4, cmap="viridis")
    if m.any():
        fig.colorbar(sc, ax=ax, shrink=0.6, label=label)
    ax.set(xlabel="x [m]", ylabel="y [m]", zlabel="z [m]", title=f"{title} ({int(m.sum())} of {m.size} poses)")
    return _save(fig, path)


def plot_sections(axes, member, margin, path, title, label, count: int = 3):
    """``margin`` on ``count`` sections ``z = const`` (spread over the grid); non-members
    hatched in grey, members coloured."""
    z = np.asarray(axes[2])
    ks = np.unique(np.linspace(0, len(z) - 1, min(count, len(z))).round().astype(int))
    fig, axs = plt.subplots(1, len(ks), figsize=(4.5 * len(ks), 4), squeeze=False)
    mem = np.asarray(member, bool)
    vals = np.asarray(margin, float)
    finite = vals[mem & np.isfinite(vals)]
    vmin, vmax = (finite.min(), finite.max()) if finite.size else (0.0, 1.0)
    for ax, k in zip(axs[0], ks):
        ax.pcolormesh(axes[0], axes[1], (~mem[:, :, k]).T.astype(float), shading="nearest", cmap="Greys",
                      vmin=0, vmax=4)
        im = ax.pcolormesh(axes[0], axes[1], np.where(mem[:, :, k], vals[:, :, k], np.nan).T, shading="nearest",
                           cmap="viridis", vmin=vmin, vmax=vmax)
        ax.set(xlabel="x [m]", ylabel="y [m]", aspect="equal", title=f"z = {z[k]:.3f} m")
    fig.colorbar(im, ax=list(axs[0]), label=label, shrink=0.8)
    fig.suptitle(title)
    return _save(fig, path)
