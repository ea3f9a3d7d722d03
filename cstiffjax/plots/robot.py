"""A 3-D picture of a cable robot (matplotlib): the frame the anchors span, the anchors
and their swivel pulleys, the cables (straight, or the elastic catenary each one hangs in),
the platform at a pose, and optional arrows (e.g. anchor or attachment offsets found by a
diagnosis) and highlighted cables (e.g. those with the largest misfit).

:func:`draw_robot` draws on a given 3-D axes (so the workspace and CSS views can draw the
robot under their members); :func:`plot_robot` writes one PNG and returns its path;
:func:`robot_scene` is what they draw, as plain arrays (the physics, here; the drawing,
:mod:`cstiffjax.plots.scene`).
"""

from pathlib import Path

import equinox as eqx
import jax
import numpy as np

from cstiffjax.cable.catenary import catenary, catenary_profile, free_span
from cstiffjax.cable.path import robot_paths
from cstiffjax.core.status import Status, code
from cstiffjax.plots.scene import draw_scene
from cstiffjax.statics.equilibrium import floor_height, up_direction
from cstiffjax.statics.geometry import frame


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
    up = up_direction(g)
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


def robot_scene(robot, pose=None, l0=None) -> dict:
    """What :func:`draw_robot` draws, as plain arrays (a :mod:`cstiffjax.plots.scene` dict):
    the anchors and, at ``pose`` (6,) (None: the anchors only), each cable's shape
    (:func:`cable_shapes`, ``l0`` as there), the attachments, the platform's position and
    its centre of mass, base frame, m; ``up`` against gravity and the ``floor``'s height
    along it (:func:`cstiffjax.statics.equilibrium.floor_height` of everything drawn: the
    base frame's origin, or the lowest point drawn where it is lower)."""
    anchors = np.asarray(robot.anchors, float)
    up = up_direction(robot.gravity)
    scene = {"anchors": anchors, "shapes": [], "attachments": None, "position": None, "com": None, "up": up,
             "floor": floor_height(anchors, up)}
    if pose is not None:
        p, R, att, _ = _placed_host(robot, pose)
        shapes = cable_shapes(robot, pose, l0)
        scene.update(shapes=shapes, attachments=att, position=p, com=p + R @ np.asarray(robot.com),
                     floor=floor_height(np.vstack([anchors, att, *shapes]), up))
    return scene


def draw_robot(ax, robot, pose=None, *, l0=None, highlight=(), arrows=None, arrow_at="anchors",
               arrow_label=None, legend=True):
    """Draw ``robot`` on the 3-D axes ``ax``: frame, anchors and pulleys, and, at ``pose``,
    the cables and the platform (:func:`robot_scene` drawn by
    :func:`cstiffjax.plots.scene.draw_scene`).

    **Arguments:** ``pose`` (6,) or None (frame and anchors only); ``l0`` (m,) m: cables with
    mass hang in their catenary (default straight); ``highlight``: indices of cables drawn
    in red and thicker; ``arrows`` (m, 3) m or None: vectors drawn at the anchors or the
    attachments (``arrow_at``), scaled so the longest is 15 % of the frame (the scale is in
    the legend, ``arrow_label`` names them). **Returns:** the scale factor of the arrows (1
    when there are none).
    """
    return draw_scene(ax, robot_scene(robot, pose, l0), highlight=highlight, arrows=arrows, arrow_at=arrow_at,
                      arrow_label=arrow_label, legend=legend)


def plot_robot(robot, pose, path, title=None, *, format="png", **options):
    """Write a PNG (or ``format``) of ``robot`` at ``pose`` (see :func:`draw_robot` for
    ``options``) and return its path."""
    import matplotlib.pyplot as plt  # lazy: the report's scene (robot_scene) needs no matplotlib

    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    draw_robot(ax, robot, pose, **options)
    ax.set_title(title or f"{robot.name}", fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight", format=format)
    plt.close(fig)
    return path
