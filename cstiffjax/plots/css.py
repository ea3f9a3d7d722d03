"""Figures for tension distribution and the constant stiffness space (matplotlib).

Seed 004 (``004_b946b1caf1c3d79b.txt``) figures: the CTFR polygon (Fig. 4), the CSS as a
3-D point cloud coloured by the local stability μ (Figs. 10, 14), μ on a section
``z = const`` (Figs. 11, 13), and volume / global stability per case (Tables 5, 8).
Every function writes one PNG and returns its path; nothing here is imported by the
physics modules.
"""

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np


def _save(fig, path):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")  # keeps suptitles and colorbars whole
    plt.close(fig)
    return path


def plot_ctfr(region, path, title="CTFR"):
    """The CTFR polygon in null-space coordinates φ (N) with its centroid (Cui et al. 2019 Fig. 4).

    ``region``: a :class:`cstiffjax.stiffness.tensions.CTFR` (one pose).
    """
    v = np.asarray(region.polygon.vertices)[: int(region.polygon.count)]
    fig, ax = plt.subplots(figsize=(5, 5), layout="constrained")
    if len(v):
        closed = np.vstack([v, v[:1]])
        ax.fill(closed[:, 0], closed[:, 1], alpha=0.3)
        ax.plot(closed[:, 0], closed[:, 1], "-o", ms=3)
    c = np.asarray(region.centroid)
    ax.plot(*c, "k+", ms=12)
    ax.set(xlabel="φ1 [N]", ylabel="φ2 [N]", aspect="equal",  # the key in the title: nothing covers the polygon
           title=f"{title}\n+ centroid (area {float(region.area):.4g} N²)")
    return _save(fig, path)


def plot_css_3d(axes, member, stability, path, title="Constant stiffness space", robot=None):
    """CSS members of a grid as a 3-D scatter coloured by μ (Cui et al. 2019 Figs. 10, 14), inside
    ``robot``'s frame when it is given.

    ``axes``: the three coordinate vectors (m); ``member``/``stability``: ``(nx, ny, nz)``.
    """
    from cstiffjax.plots.workspace import scatter_members

    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    scatter_members(fig, ax, axes, member, stability, "local stability μ", robot)
    ax.set_title(title, fontsize=10)
    return _save(fig, path)


def plot_section(axes, member, stability, z, path, title=None):
    """μ on the grid section nearest to ``z`` (m, e.g. the target pose's height); non-members
    grey (Cui et al. 2019 Figs. 11, 13)."""
    from cstiffjax.plots.workspace import colour_range

    k = int(np.argmin(np.abs(np.asarray(axes[2]) - z)))
    mem = np.asarray(member, bool)[:, :, k]
    mu = np.where(mem, np.asarray(stability)[:, :, k], np.nan)
    vmin, vmax, constant = colour_range(stability, member)
    fig, ax = plt.subplots(figsize=(6.5, 4.8), layout="constrained")
    ax.pcolormesh(axes[0], axes[1], (~mem).T.astype(float), shading="nearest", cmap="Greys", vmin=0, vmax=4)
    im = ax.pcolormesh(axes[0], axes[1], mu.T, shading="nearest", cmap="viridis", vmin=vmin, vmax=vmax)
    if constant is None:
        fig.colorbar(im, ax=ax, label="local stability μ")
    ax.set(xlabel="x [m]", ylabel="y [m]", aspect="equal")
    ax.set_title((title or f"CSS section z = {float(axes[2][k]):.3f} m ({int(mem.sum())} members)")
                 + ("" if constant is None else f"\nμ = {constant:.4g} at every member") + "\ngrey: not a member",
                 fontsize=10)
    return _save(fig, path)


def plot_cases(names, volumes, stabilities, path, title="CSS per case"):
    """Volume (m³) and global stability U per case, side by side (Cui et al. 2019 Tables 5, 8)."""
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.5))
    x = np.arange(len(names))
    a.bar(x, np.asarray(volumes) * 1e3)
    a.set(xticks=x, xticklabels=names, ylabel="volume [10⁻³ m³]")
    b.bar(x, stabilities, color="tab:orange")
    b.set(xticks=x, xticklabels=names, ylabel="global stability U")
    fig.suptitle(title)
    return _save(fig, path)
