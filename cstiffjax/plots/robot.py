"""A 3-D picture of a cable robot (matplotlib): the frame the anchors span, the anchors
and their swivel pulleys, the cables (straight, or the elastic catenary each one hangs in),
the platform at a pose, and optional arrows (e.g. anchor or attachment offsets found by a
diagnosis) and highlighted cables (e.g. those with the largest misfit).

:func:`draw_robot` draws on a given 3-D axes (so the workspace and CSS views can draw the
robot under their members); :func:`plot_robot` writes one PNG and returns its path.
"""

from pathlib import Path

import equinox as eqx
import jax
import matplotlib.pyplot as plt
import numpy as np

from cstiffjax.cable.catenary import catenary, catenary_profile, free_span
from cstiffjax.cable.path import robot_paths
from cstiffjax.core.status import Status, code
from cstiffjax.statics.geometry import frame

CABLE = "tab:blue"
HIGHLIGHT = "tab:red"
ARROW = "tab:orange"


@eqx.filter_jit
def _placed(robot, pose):
    """``(p, R, attachments (m, 3), robot_paths)`` of ``robot`` at ``pose``, in one compiled
    program (computed op by op, these small arrays would compile ~70 one-operation programs:
    about 1 s on the command line's first figure)."""
    p, R = frame(pose)
    att = p + robot.attachments @ R.T
    return p, R, att, robot_paths(robot, att)


def _placed_host(robot, pose):
    """:func:`_placed` as numpy arrays (the paths' fields too)."""
    p, R, att, paths = _placed(robot, np.asarray(pose, dtype=np.float64))
    return np.asarray(p), np.asarray(R), np.asarray(att), jax.tree_util.tree_map(np.asarray, paths)


def _box_edges(lo, hi):
    """The 12 edges of the axis-aligned box ``[lo, hi]`` as pairs of points."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return [(corners[i], corners[j]) for i in range(8) for j in range(i + 1, 8)
            if np.sum(corners[i] != corners[j]) == 1]


def _platform_outline(points):
    """The attachments ``(m, 3)`` (base frame) in angular order about their centroid, in
    their best-fit plane, closed: the platform drawn as a polygon."""
    c = points.mean(0)
    d = points - c
    if len(points) < 3:
        return points
    _, _, vt = np.linalg.svd(d)
    a = np.arctan2(d @ vt[1], d @ vt[0])
    ring = points[np.argsort(a)]
    return np.vstack([ring, ring[:1]])


def cable_shapes(robot, pose, l0=None, points: int = 40) -> list[np.ndarray]:
    """Each cable's shape from its anchor to its attachment, ``(k, 3)`` points, base frame, m.

    Over a pulley the wrapped arc from the anchor to the tangent point comes first. A
    cable with mass and an unstrained length ``l0`` hangs in its elastic catenary (solved
    for its own end points; a cable whose catenary has no solution, e.g. a slack massless
    one, is drawn straight); otherwise it is the straight free span.

    **Arguments:** ``robot`` a CableRobot; ``pose`` (6,); ``l0`` (m,) unstrained lengths, m,
    or None (straight spans); ``points`` per span.
    """
    _, _, att, paths = _placed_host(robot, pose)
    g = np.asarray(robot.gravity)
    up = -g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 0.0, 1.0])
    shapes = []
    anchors, radius, mass = (np.asarray(v) for v in (robot.anchors, robot.pulley_radius, robot.mass_per_length))
    for i in range(robot.num_cables):
        a, t = anchors[i], paths.tangent_point[i]
        arc = _wrap_arc(a, t, paths.centre[i], float(radius[i])) if bool(paths.pulley[i]) else a[None]
        span = np.linspace(t, att[i], points)
        w = float(mass[i]) * float(np.linalg.norm(g))
        if l0 is not None and w > 0:
            span = _hanging(robot, i, att[i], float(l0[i]), up, w, points)
        shapes.append(np.vstack([arc, span]))
    return shapes


def _wrap_arc(anchor, tangent, centre, radius, k: int = 12):
    """Points on the pulley circle from the anchor to the tangent point (the wrapped cable)."""
    u, v = anchor - centre, tangent - centre
    n = np.cross(u, v)
    if radius <= 0 or np.linalg.norm(n) < 1e-15:
        return np.vstack([anchor, tangent])
    angle = np.arctan2(np.linalg.norm(n), u @ v)
    e1, e2 = u / np.linalg.norm(u), np.cross(n / np.linalg.norm(n), u / np.linalg.norm(u))
    s = np.linspace(0.0, angle, k)
    return centre + radius * (np.outer(np.cos(s), e1) + np.outer(np.sin(s), e2))


def _hanging(robot, i, attachment, l0, up, w, points):
    """The catenary of cable ``i`` from its tangent point to ``attachment``, or the straight
    span when it has no solution."""
    t, l_free = (np.asarray(v) for v in free_span(robot.anchors[i], attachment, l0, robot.EA[i],
                                                  robot.pulley_radius[i], robot.pulley_axis[i]))
    d = attachment - t
    sz = float(d @ up)
    horizontal = d - sz * up
    sx = float(np.linalg.norm(horizontal))
    straight = np.linspace(t, attachment, points)
    if sx < 1e-9 * np.linalg.norm(d) or not l_free > 0:
        return straight
    sol = catenary(sx, sz, float(l_free), float(robot.EA[i]), w, throw=False)
    if code(sol.result) != code(Status.successful):
        return straight
    s = np.linspace(0.0, float(l_free), points)
    x, z = (np.asarray(v) for v in catenary_profile(sol.H, sol.V_A, float(l_free), float(robot.EA[i]), w, s))
    ex = horizontal / sx
    return t + np.outer(x, ex) + np.outer(z, up)


def draw_robot(ax, robot, pose=None, *, l0=None, highlight=(), arrows=None, arrow_at="anchors",
               arrow_label=None, legend=True):
    """Draw ``robot`` on the 3-D axes ``ax``: frame, anchors and pulleys, and, at ``pose``,
    the cables and the platform.

    **Arguments:** ``pose`` (6,) or None (frame and anchors only); ``l0`` (m,) m: cables with
    mass hang in their catenary (default straight); ``highlight``: indices of cables drawn
    in red and thicker; ``arrows`` (m, 3) m or None: vectors drawn at the anchors or the
    attachments (``arrow_at``), scaled so the longest is 15 % of the frame (the scale is in
    the legend, ``arrow_label`` names them). **Returns:** the scale factor of the arrows (1
    when there are none).
    """
    anchors = np.asarray(robot.anchors)
    lo, hi = anchors.min(0), anchors.max(0)
    for e in _box_edges(lo, hi):
        ax.plot(*np.array(e).T, color="0.75", lw=0.7)
    ax.scatter(*anchors.T, color="k", marker="^", s=18, label="anchors")
    for i, a in enumerate(anchors):
        ax.text(*a, f" {i + 1}", fontsize=7, color="0.3")
    scale = 1.0
    points = anchors
    if pose is not None:
        p, R, att, _ = _placed_host(robot, pose)
        hot = {int(h) for h in highlight}
        labelled = set()
        for i, shape in enumerate(cable_shapes(robot, pose, l0)):
            label = "largest misfit" if i in hot else "cables"
            ax.plot(*shape.T, color=HIGHLIGHT if i in hot else CABLE, lw=2.2 if i in hot else 1.0,
                    label=None if label in labelled else label)
            labelled.add(label)
        ring = _platform_outline(att)
        ax.plot(*ring.T, color="k", lw=1.5, label="platform")
        ax.scatter(*p, color="k", marker="+", s=40)
        com = p + R @ np.asarray(robot.com)
        ax.scatter(*com, color="tab:green", marker="o", s=14, label="centre of mass")
        points = np.vstack([anchors, att])
    if arrows is not None:
        base = anchors if arrow_at == "anchors" else points[len(anchors):]
        v = np.asarray(arrows, float)
        longest = float(np.max(np.linalg.norm(v, axis=1))) if v.size else 0.0
        if longest > 0:
            scale = 0.15 * float(np.max(hi - lo)) / longest
            ax.quiver(*base.T, *(scale * v).T, color=ARROW, lw=1.5,
                      label=f"{arrow_label or 'offsets'} (x{scale:.3g})")
    stretched = _equal_aspect(ax, points)
    ax.set(xlabel="x [m]", ylabel="y [m]")
    ax.set_zlabel("z [m]", labelpad=8)
    for n, f in stretched.items():
        getattr(ax, f"set_{n}label")(f"{n} [m] (scale x{f:.2g})")
    if legend:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=3, fontsize=7, frameon=False)
    return scale


def _equal_aspect(ax, points, floor: float = 0.3):
    """Equal scale on the three axes around the bounding box of ``points`` (and what is
    drawn), except that an axis shorter than ``floor`` times the longest is stretched to it
    (a flat robot stays readable). **Returns:** ``{axis name: stretch factor}`` of the
    stretched axes (empty: every scale equal)."""
    lo, hi = points.min(0), points.max(0)
    for name, (a, b) in zip("xyz", zip(lo, hi)):
        cur = getattr(ax, f"get_{name}lim")()
        getattr(ax, f"set_{name}lim")(min(a, cur[0]), max(b, cur[1]))
    spans = np.array([np.ptp(getattr(ax, f"get_{n}lim")()) for n in "xyz"], float)
    longest = float(spans.max()) if spans.max() > 0 else 1.0
    box = np.maximum(spans, floor * longest)
    ax.set_box_aspect(box)
    return {n: float(b / s) for n, b, s in zip("xyz", box, spans) if s > 0 and b > 1.001 * s}


def plot_robot(robot, pose, path, title=None, *, format="png", **options):
    """Write a PNG (or ``format``) of ``robot`` at ``pose`` (see :func:`draw_robot` for
    ``options``) and return its path."""
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    draw_robot(ax, robot, pose, **options)
    ax.set_title(title or f"{robot.name}", fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight", format=format)
    plt.close(fig)
    return path
