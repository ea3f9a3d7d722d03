"""Drawing a placed robot (:func:`draw_scene`) from plain arrays: the frame the anchors
span, the anchors, the cables' shapes, the platform, arrows and highlighted cables.

numpy and a matplotlib 3-D axes only, no JAX and no other module of the toolkit: the
diagnosis's report draws its figures in a separate process that never imports JAX
(:mod:`fitting.diagnosis.figure_worker`). :func:`cstiffjax.plots.robot.robot_scene` computes
the scene of a robot at a pose (the physics); :func:`cstiffjax.plots.robot.draw_robot` draws it
with this module.

A scene is a dict: ``anchors`` ``(m, 3)`` m; ``shapes``: one ``(k, 3)`` array per cable,
anchor to attachment, base frame, m (empty without a pose); ``attachments`` ``(m, 3)``,
``position`` ``(3,)`` and ``com`` ``(3,)`` m, or None without a pose; optional ``up`` ``(3,)``
(the unit vector against gravity) and ``floor`` (its height along ``up``, m): with both, and
``up`` along a coordinate axis, the frame is drawn as a box from the floor (shaded) to the
highest anchor, so that "down" is plain even when every anchor is at one height.
"""

import numpy as np

LEAST_SPAN = 0.05  # an axis shorter than this fraction of the longest is opened to it (a flat drawing)
AXIS_TOL = 0.99  # |up| along its largest axis above this: the floor is drawn (gravity along a coordinate axis)
CABLE = "tab:blue"
HIGHLIGHT = "tab:red"
ARROW = "tab:orange"


def box_edges(lo, hi):
    """The 12 edges of the axis-aligned box ``[lo, hi]`` as pairs of points."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return [(corners[i], corners[j]) for i in range(8) for j in range(i + 1, 8)
            if np.sum(corners[i] != corners[j]) == 1]


def frame_box(anchors, up=None, floor=None):
    """``(lo, hi, k)``: the frame drawn around the anchors ``(m, 3)``: their bounding box,
    extended along the coordinate axis ``k`` of ``up`` down to the ``floor`` height (m along
    ``up``); ``k`` None (no floor) without them or when ``up`` is along no coordinate axis."""
    lo, hi = anchors.min(0).astype(float), anchors.max(0).astype(float)
    if up is None or floor is None:
        return lo, hi, None
    up = np.asarray(up, float)
    k = int(np.argmax(np.abs(up)))
    if abs(up[k]) < AXIS_TOL:
        return lo, hi, None
    if up[k] > 0:
        lo[k] = min(lo[k], floor / up[k])
    else:
        hi[k] = max(hi[k], floor / up[k])
    return lo, hi, k


def draw_floor(ax, lo, hi, k, up_k):
    """The floor, a shaded rectangle over the box ``[lo, hi]`` at its low end along axis ``k``
    (its high end where ``up_k < 0``), labelled with its height."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    level = lo[k] if up_k > 0 else hi[k]
    i, j = (a for a in range(3) if a != k)
    corners = []
    for u, v in ((lo[i], lo[j]), (hi[i], lo[j]), (hi[i], hi[j]), (lo[i], hi[j])):
        c = np.empty(3)
        c[[i, j, k]] = u, v, level
        corners.append(c)
    name = "xyz"[k]
    ax.add_collection3d(Poly3DCollection([corners], facecolor="0.6", alpha=0.25, edgecolor="0.45",
                                         label=f"floor ({name} = {level:.3g} m)"))
    return np.array(corners)


def platform_outline(points):
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


def draw_scene(ax, scene: dict, *, highlight=(), arrows=None, arrow_at="anchors", arrow_label=None,
               legend=True) -> float:
    """Draw ``scene`` (see the module) on the 3-D axes ``ax``.

    **Arguments:** ``highlight``: indices of cables drawn in red and thicker; ``arrows``
    ``(m, 3)`` m or None: vectors drawn at the anchors or the attachments (``arrow_at``),
    scaled so the longest is 15 % of the frame (the scale is in the legend, ``arrow_label``
    names them); ``legend``: draw the legend below the axes.

    **Returns:** the scale factor of the arrows (1 when there are none).
    """
    anchors = np.asarray(scene["anchors"], float)
    lo, hi, k = frame_box(anchors, scene.get("up"), scene.get("floor"))
    for e in box_edges(lo, hi):
        ax.plot(*np.array(e).T, color="0.75", lw=0.7)
    frame = np.vstack([lo, hi])
    if k is not None:
        frame = np.vstack([frame, draw_floor(ax, lo, hi, k, float(np.asarray(scene["up"])[k]))])
    ax.scatter(*anchors.T, color="k", marker="^", s=18, label="anchors")
    for i, a in enumerate(anchors):
        ax.text(*a, f" {i + 1}", fontsize=7, color="0.3")
    scale = 1.0
    points = np.vstack([anchors, frame])
    if scene.get("attachments") is not None:
        att = np.asarray(scene["attachments"], float)
        hot = {int(h) for h in highlight}
        labelled = set()
        for i, shape in enumerate(scene["shapes"]):
            label = "largest misfit" if i in hot else "cables"
            ax.plot(*np.asarray(shape).T, color=HIGHLIGHT if i in hot else CABLE, lw=2.2 if i in hot else 1.0,
                    label=None if label in labelled else label)
            labelled.add(label)
        ring = platform_outline(att)
        ax.plot(*ring.T, color="k", lw=1.5, label="platform")
        ax.scatter(*scene["position"], color="k", marker="+", s=40)
        ax.scatter(*scene["com"], color="tab:green", marker="o", s=14, label="centre of mass")
        points = np.vstack([points, att, *scene["shapes"]])
    if arrows is not None:
        base = anchors if arrow_at == "anchors" else np.asarray(scene["attachments"], float)
        v = np.asarray(arrows, float)
        longest = float(np.max(np.linalg.norm(v, axis=1))) if v.size else 0.0
        if longest > 0:
            scale = 0.15 * float(np.max(hi - lo)) / longest
            ax.quiver(*base.T, *(scale * v).T, color=ARROW, lw=1.5,
                      label=f"{arrow_label or 'offsets'} (x{scale:.3g})")
    stretched = equal_aspect(ax, points)
    ax.set(xlabel="x [m]", ylabel="y [m]")
    ax.set_zlabel("z [m]", labelpad=8)
    for n, f in stretched.items():
        getattr(ax, f"set_{n}label")(f"{n} [m] (scale x{f:.2g})")
    if legend:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=3, fontsize=7, frameon=False)
    return scale


def equal_aspect(ax, points, least: float = LEAST_SPAN):
    """Equal scale on the three axes around the bounding box of ``points`` (and what is
    drawn), except that an axis shorter than ``least`` times the longest is opened to it (a
    flat drawing, e.g. a planar robot without a floor, stays a 3-D view); nothing else is
    stretched. **Returns:** ``{axis name: stretch factor}`` of the stretched axes (empty:
    every scale equal)."""
    lo, hi = points.min(0), points.max(0)
    for name, (a, b) in zip("xyz", zip(lo, hi)):
        cur = getattr(ax, f"get_{name}lim")()
        getattr(ax, f"set_{name}lim")(min(a, cur[0]), max(b, cur[1]))
    spans = np.array([np.ptp(getattr(ax, f"get_{n}lim")()) for n in "xyz"], float)
    longest = float(spans.max()) if spans.max() > 0 else 1.0
    box = np.maximum(spans, least * longest)
    ax.set_box_aspect(box)
    return {n: float(b / s) for n, b, s in zip("xyz", box, spans) if s > 0 and b > 1.001 * s}
