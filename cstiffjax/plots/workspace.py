"""Figures of workspace sweeps (matplotlib): a 3-D view of the members coloured by
their margin, drawn inside the robot's frame, and sections ``z = const``. Each function
writes one PNG and returns its path."""

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np


def _save(fig, path):
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def colour_range(values, member):
    """``(vmin, vmax, constant)`` of ``values`` over the members: a constant value gets a
    range around it (a colour bar with one repeated tick says nothing) and ``constant`` its
    value, else ``None``."""
    v = np.asarray(values, float)[np.asarray(member, bool)]
    v = v[np.isfinite(v)]
    if not v.size:
        return 0.0, 1.0, None
    lo, hi = float(v.min()), float(v.max())
    if hi - lo <= 1e-12 * max(abs(lo), abs(hi), 1e-300):
        pad = 0.05 * abs(lo) if lo != 0 else 1.0
        return lo - pad, lo + pad, lo
    return lo, hi, None


def scatter_members(fig, ax, axes, member, values, label, robot=None):
    """Members of a grid ``(nx, ny, nz)`` as points coloured by ``values`` on the 3-D axes
    ``ax``; with ``robot``, its frame and anchors under them (equal aspect). The colour bar
    sits clear of the z label; a constant value is named in the legend instead of a bar."""
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    m = np.asarray(member, bool)
    vmin, vmax, constant = colour_range(values, m)
    if robot is not None:
        from cstiffjax.plots.robot import draw_robot

        draw_robot(ax, robot, legend=False)
    name = f"members ({int(m.sum())} of {m.size})" + ("" if constant is None else f", {label} = {constant:.4g}")
    sc = ax.scatter(X[m], Y[m], Z[m], c=np.asarray(values, float)[m], s=4, cmap="viridis", vmin=vmin, vmax=vmax,
                    label=name)
    if robot is not None and m.any():  # members below a frame of anchors at one height stay in view
        from cstiffjax.plots.scene import equal_aspect

        equal_aspect(ax, np.stack([X[m], Y[m], Z[m]], axis=1))
    if m.any() and constant is None:
        fig.colorbar(sc, ax=ax, shrink=0.6, pad=0.12, label=label)
    ax.set(xlabel="x [m]", ylabel="y [m]")
    ax.set_zlabel("z [m]", labelpad=6)
    handles, labels = ax.get_legend_handles_labels()
    ax.legend(handles, labels, loc="upper left", fontsize=7, frameon=False,
              title=f"{m.size - int(m.sum())} grid poses not members (not drawn)", title_fontsize=7)
    return sc


def plot_members_3d(axes, member, margin, path, title, label, robot=None):
    """Members of a grid ``(nx, ny, nz)`` as a 3-D scatter coloured by ``margin``, inside
    ``robot``'s frame when it is given."""
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    scatter_members(fig, ax, axes, member, margin, label, robot)
    ax.set_title(title, fontsize=10)
    return _save(fig, path)


def section_indices(z, count: int = 3, at=None):
    """Indices of the grid heights ``z`` to show: the ones nearest to the heights ``at`` (m,
    e.g. the target pose's z), else ``count`` spread over the grid."""
    z = np.asarray(z)
    if at is not None and len(at):
        return np.unique([int(np.argmin(np.abs(z - h))) for h in at])
    return np.unique(np.linspace(0, len(z) - 1, min(count, len(z))).round().astype(int))


def plot_sections(axes, member, margin, path, title, label, count: int = 3, at=None):
    """``margin`` on sections ``z = const`` (nearest to the heights ``at``, m, else ``count``
    spread over the grid); non-members grey, members coloured on one shared scale."""
    ks = section_indices(axes[2], count, at)
    fig, axs = plt.subplots(1, len(ks), figsize=(4.5 * len(ks) + 1, 4.2), squeeze=False, layout="constrained")
    mem = np.asarray(member, bool)
    vals = np.asarray(margin, float)
    vmin, vmax, constant = colour_range(vals, mem)
    for ax, k in zip(axs[0], ks):
        ax.pcolormesh(axes[0], axes[1], (~mem[:, :, k]).T.astype(float), shading="nearest", cmap="Greys",
                      vmin=0, vmax=4)
        im = ax.pcolormesh(axes[0], axes[1], np.where(mem[:, :, k], vals[:, :, k], np.nan).T, shading="nearest",
                           cmap="viridis", vmin=vmin, vmax=vmax)
        ax.set(xlabel="x [m]", ylabel="y [m]", aspect="equal",
               title=f"z = {float(axes[2][k]):.3f} m ({int(mem[:, :, k].sum())} members)")
    if constant is None:
        fig.colorbar(im, ax=list(axs[0]), label=label, shrink=0.8)
    fig.suptitle(title + ("" if constant is None else f"\n{label} = {constant:.4g} at every member")
                 + "\ngrey: not a member", fontsize=10)
    return _save(fig, path)
