"""Interference of cables with each other and with the platform, one pose (vmap for sweeps).

- **Cable–cable**: the minimum distance (m) between every pair of cables, each cable a
  straight segment exit point → attachment, or, when ``mass_per_length > 0``, the polyline
  through ``samples`` points of its elastic catenary (:mod:`cstiffjax.cable.catenary`) with the
  unstrained lengths that hold the pose (:func:`cstiffjax.statics.sag.sagging_inverse_statics`).
  Over a swivel pulley (formats.md §1 v2, :func:`cstiffjax.cable.path.cable_path`) the free
  span starts at the tangent point T, not at the anchor, and the cable is prefixed by
  ``ARC_POINTS`` points of its wrap on the pulley from the anchor to T (a chord polyline:
  within ``r (1 - cos(beta / (2 (ARC_POINTS - 1))))`` of the arc, 0.9 mm for
  ``r = 2.5`` cm and ``beta = 2.7`` rad); a straight cable of a robot with pulleys gets
  ``ARC_POINTS`` copies of its anchor there (zero-length segments).
  Segment–segment distances are exact (closest points with clamping, Ericson 2005,
  *Real-Time Collision Detection* §5.1.9). Pairs that share an anchor or an attachment
  point are left out (their distance is 0 by construction).
- **Cable–platform**: the platform is the convex hull of the attachment points
  (:func:`platform_hull`; a flat platform is the polygon with both faces). A cable leaves
  its attachment ``b_i`` (a hull vertex) along the unit tangent ``u_i``; since the hull is
  convex, a straight cable meets it only at ``b_i`` iff ``u_i`` leaves the tangent cone
  there, i.e. iff the **clearance** ``max_f a_f·u_i`` over the hull faces through ``b_i``
  (unit outward normals ``a_f``) is positive (it is the sine of the angle by which the
  cable clears the nearest such face plane; ``<= 0``: it enters or grazes the platform).
  Sagging cables are also checked point by point: the **depth** ``min_k max_f (a_f·x_k -
  c_f)`` over the profile samples other than the attachment (m, a lower bound on the
  distance to the hull, negative inside it).

A pose is interference-free when every pair distance exceeds the cable ``diameter``,
every clearance is positive and every depth is positive.
"""

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from cstiffjax.cable import catenary
from cstiffjax.cable.path import robot_paths
from cstiffjax.core.status import Status
from cstiffjax.statics.geometry import attachment_points, frame
from cstiffjax.statics.sag import sagging_inverse_statics

ARC_POINTS = 6
"""Points of a cable's wrap on its swivel pulley, anchor to tangent point (robots with pulleys)."""


class PlatformHull(eqx.Module):
    """Faces ``a_f·x <= c_f`` of the attachment points' convex hull (platform frame):
    ``normals`` ``(F, 3)`` unit outward, ``offsets`` ``(F,)`` m, ``incidence`` ``(F, m)``
    (face ``f`` passes through attachment ``i``)."""

    normals: Float[Array, "F 3"]
    offsets: Float[Array, " F"]
    incidence: Bool[Array, "F m"]


def _unique_planes(planes, tol):
    out = []
    for a, c in planes:
        if not any(np.allclose(a, b, atol=tol) and abs(c - d) <= tol for b, d in out):
            out.append((a, c))
    return out


def platform_hull(attachments, tol: float = 1e-9) -> PlatformHull:
    """Faces of the convex hull of ``attachments`` ``(m, 3)`` (m, platform frame), exact by
    enumeration: a plane through three points is a face when every point lies on one side
    (to ``tol`` times the platform size). Coplanar points give the polygon: both faces of
    its plane and an edge plane (normal in the plane) per polygon edge.

    **Raises** ``ValueError`` when the points are collinear (no platform to speak of).
    """
    b = np.asarray(attachments, dtype=np.float64)
    size = max(float(np.ptp(b, axis=0).max()), 1e-300)
    eps = tol * size
    centered = b - b.mean(axis=0)
    sv = np.linalg.svd(centered, compute_uv=False)
    if sv[1] <= tol * sv[0]:
        raise ValueError(f"platform_hull: the {len(b)} attachment points are collinear; no platform hull")
    planes = []
    if sv[2] > tol * sv[0]:
        for i, j, k in itertools.combinations(range(len(b)), 3):
            n = np.cross(b[j] - b[i], b[k] - b[i])
            if np.linalg.norm(n) <= eps * size:
                continue
            n = n / np.linalg.norm(n)
            side = (b - b[i]) @ n
            if np.all(side <= eps):
                planes.append((n, float(n @ b[i])))
            elif np.all(side >= -eps):
                planes.append((-n, float(-n @ b[i])))
    else:
        normal = np.linalg.svd(centered)[2][2]
        planes += [(normal, float(normal @ b[0])), (-normal, float(-normal @ b[0]))]
        for i, j in itertools.combinations(range(len(b)), 2):
            e = np.cross(normal, b[j] - b[i])
            if np.linalg.norm(e) <= eps:
                continue
            e = e / np.linalg.norm(e)
            side = (b - b[i]) @ e
            if np.all(side <= eps):
                planes.append((e, float(e @ b[i])))
            elif np.all(side >= -eps):
                planes.append((-e, float(-e @ b[i])))
    planes = _unique_planes(planes, 1e-9)
    A = np.array([a for a, _ in planes])
    c = np.array([d for _, d in planes])
    incidence = np.abs(b @ A.T - c).T <= eps
    return PlatformHull(jnp.asarray(A), jnp.asarray(c), jnp.asarray(incidence))


class InterferenceModel(eqx.Module):
    """What :func:`interference` needs besides the robot: the platform hull, the cable
    pairs checked (static), the cable ``diameter`` (m), the profile ``samples`` per
    sagging cable (static), whether any cable sags (static) and whether any cable runs
    over a swivel pulley (static: its wrap is then part of the cable's polyline)."""

    hull: PlatformHull
    diameter: Float[Array, ""]
    pairs: tuple = eqx.field(static=True)
    samples: int = eqx.field(static=True)
    sagging: bool = eqx.field(static=True)
    pulleys: bool = eqx.field(static=True, default=False)


def interference_model(robot, *, diameter: float = 0.0, samples: int = 16) -> InterferenceModel:
    """Build the :class:`InterferenceModel` of a (concrete) robot.

    **Arguments:** ``diameter`` (m, >= 0): two cables interfere closer than this;
    ``samples`` (>= 2): points along each sagging cable (straight cables need 2).
    """
    if not diameter >= 0:
        raise ValueError(f"interference: diameter = {diameter!r} m must be >= 0")
    if int(samples) != samples or samples < 2:
        raise ValueError(f"interference: samples = {samples!r} must be an integer >= 2")
    a, b = np.asarray(robot.anchors), np.asarray(robot.attachments)
    m = len(a)
    pairs = tuple((i, j) for i, j in itertools.combinations(range(m), 2)
                  if not (np.allclose(a[i], a[j]) or np.allclose(b[i], b[j])))
    sagging = bool(np.any(np.asarray(robot.mass_per_length) > 0))
    pulleys = bool(np.any(np.asarray(robot.pulley_axis) != 0))
    return InterferenceModel(platform_hull(b), jnp.asarray(float(diameter)), pairs,
                             int(samples) if sagging else 2, sagging, pulleys)


class Interference(eqx.Module):
    """Interference at one pose: ``cable_distance`` ``(P,)`` m per pair of
    ``model.pairs``; ``platform_clearance`` ``(m,)`` (sine, > 0 clear); ``platform_depth``
    ``(m,)`` m (> 0 outside the hull); ``free``; ``margin`` = min distance - diameter (m);
    ``result``: the sagging statics' :class:`Status` (always successful for straight
    cables; a failed sag solve leaves ``free`` false)."""

    cable_distance: Float[Array, " P"]
    platform_clearance: Float[Array, " m"]
    platform_depth: Float[Array, " m"]
    free: Bool[Array, ""]
    margin: Float[Array, ""]
    result: Status


def segment_distance(p1, q1, p2, q2) -> Float[Array, ""]:
    """Minimum distance between segments ``[p1, q1]`` and ``[p2, q2]`` (3-vectors, m).

    Closest points by Ericson §5.1.9: the unconstrained line–line parameters, clamped
    to ``[0, 1]`` one after the other; degenerate (point) segments and parallel
    segments are handled without division by zero.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    c, bb = d1 @ r, d1 @ d2
    tiny = 1e-300
    denom = a * e - bb * bb
    s = jnp.where(denom > 1e-14 * a * e, jnp.clip((bb * f - c * e) / jnp.maximum(denom, tiny), 0.0, 1.0), 0.0)
    t = jnp.where(e > tiny, (bb * s + f) / jnp.maximum(e, tiny), 0.0)
    s = jnp.where(t < 0, jnp.clip(-c / jnp.maximum(a, tiny), 0.0, 1.0),
                  jnp.where(t > 1, jnp.clip((bb - c) / jnp.maximum(a, tiny), 0.0, 1.0), s))
    s = jnp.where(a > tiny, s, 0.0)
    t = jnp.clip(t, 0.0, 1.0)
    return jnp.linalg.norm(p1 + s * d1 - (p2 + t * d2))


def pulley_arcs(robot, attachments, num: int = ARC_POINTS) -> Float[Array, "m num 3"]:
    """``num`` points of every cable's wrap on its swivel pulley, from the anchor (first) to
    the tangent point T (last), base frame, m: ``C + r (-cos(θ) u + sin(θ) e)`` for ``θ``
    from 0 to the wrap ``beta`` (:func:`cstiffjax.pulley.cable_path`); ``num`` copies of
    the anchor for a cable without a pulley. ``attachments`` (m, 3) base frame, m."""
    path = robot_paths(robot, attachments)
    e = robot.pulley_axis  # unit, or zero without a pulley (then u = 0, C = anchor)
    theta = path.wrap[:, None] * jnp.linspace(0.0, 1.0, num)[None, :]  # (m, num)
    r = robot.pulley_radius[:, None, None]
    return path.centre[:, None, :] + r * (-jnp.cos(theta)[..., None] * path.swivel_direction[:, None, :]
                                          + jnp.sin(theta)[..., None] * e[:, None, :])


def cable_points(robot, pose, external=None, samples: int = 2, pulleys: bool | None = None):
    """Points along every cable from the anchor (first) to the attachment (last), base
    frame, m, and the sag statics' :class:`Status`. The free span: straight chords for
    ``samples = 2`` with massless cables, the catenary profile (``samples`` points) otherwise,
    from the exit point (the anchor, or the tangent point T of a swivel pulley, for any
    robot). With ``pulleys`` (static; default: whether any cable of ``robot`` has a pulley
    axis, false for a robot whose arrays are traced, which :func:`interference` avoids by
    deciding in :func:`interference_model`) the free span is prefixed by the
    :data:`ARC_POINTS` points of :func:`pulley_arcs`: ``(m, ARC_POINTS + samples, 3)``;
    else ``(m, samples, 3)``."""
    if pulleys is None:
        try:
            pulleys = bool(np.any(np.asarray(robot.pulley_axis) != 0))
        except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
            pulleys = False
    att = attachment_points(robot, pose)
    if samples == 2 and not bool(np.any(np.asarray(robot.mass_per_length) > 0)):
        exits = robot_paths(robot, att).tangent_point  # the anchor itself for a straight cable
        pts, result = jnp.stack([exits, att], axis=1), Status.successful
    else:
        inv = sagging_inverse_statics(robot, pose, external, throw=False)
        frac = jnp.linspace(0.0, 1.0, samples)

        def one(anchor, b, l0, EA, rho, radius, axis):
            w = rho * jnp.linalg.norm(robot.gravity)
            force = catenary.catenary_force(anchor, b, l0, EA, rho, robot.gravity, radius, axis)
            start, l0_free = catenary.free_span(anchor, b, l0, EA, radius, axis)  # T and the free span's l0
            _, _, ex, up, _ = catenary.frame_3d(start, b, robot.gravity)
            H, VA = force.on_anchor @ ex, force.on_anchor @ up
            x, z = catenary.catenary_profile(H, VA, l0_free, EA, w, l0_free * frac)
            pts = start + x[:, None] * ex + z[:, None] * up
            return pts.at[-1].set(b)  # the end is the attachment (to the solve's accuracy)

        pts = jax.vmap(one)(robot.anchors, att, inv.l0, robot.EA, robot.mass_per_length, robot.pulley_radius,
                            robot.pulley_axis)
        result = inv.result
    if pulleys:
        pts = jnp.concatenate([pulley_arcs(robot, att), pts], axis=1)
    return pts, result


def _polyline_distance(P, Q):
    """Minimum distance between two polylines ``(k, 3)`` (all segment pairs)."""
    i, j = np.meshgrid(np.arange(len(P) - 1), np.arange(len(Q) - 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    return jnp.min(jax.vmap(segment_distance)(P[i], P[i + 1], Q[j], Q[j + 1]))


def interference(robot, model: InterferenceModel, pose, external=None) -> Interference:
    """Cable–cable and cable–platform interference at ``pose`` (6,) m / rad under
    ``external`` (6,) N / N·m (it shapes sagging cables only). See the module docstring."""
    pose = jnp.asarray(pose, dtype=jnp.float64)
    pts, result = cable_points(robot, pose, external, model.samples, model.pulleys)
    pi = np.array([p[0] for p in model.pairs], dtype=np.int64)
    pj = np.array([p[1] for p in model.pairs], dtype=np.int64)
    if len(pi):
        dist = jax.vmap(_polyline_distance)(pts[pi], pts[pj])
    else:
        dist = jnp.full((0,), jnp.inf)
    p, R = frame(pose)
    A = model.hull.normals @ R.T  # base frame (F, 3)
    c = model.hull.offsets + A @ p
    tangent = pts[:, -2] - pts[:, -1]  # from the attachment toward the anchor
    u = tangent / jnp.linalg.norm(tangent, axis=1, keepdims=True)
    clearance = jnp.max(jnp.where(model.hull.incidence.T, u @ A.T, -jnp.inf), axis=1)
    depth = jnp.min(jnp.max(pts[:, :-1] @ A.T - c, axis=2), axis=1)
    margin = jnp.min(dist) - model.diameter if len(pi) else jnp.inf
    free = ((margin > 0) & jnp.all(clearance > 0) & jnp.all(depth > 0) & (result == Status.successful))
    return Interference(dist, clearance, depth, free, margin, result)
