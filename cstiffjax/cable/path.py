"""The path of one cable from its exit point to the platform: straight, or over a swivel
pulley (formats.md §1, version 2; the swivel-pulley model of Pott's book and cdpyr).

Every cable law, the structure matrix, the statics, stiffness, sag, tensions and the
fits take a cable's geometry from :func:`cable_path` and nowhere else.

Geometry of one cable with a pulley of radius ``r`` whose swivel axis passes through
the ``anchor`` A along the unit vector ``e`` (``pulley_axis``: the direction in which the
cable travels as it arrives at A). With ``d = P - A``, ``d_a = d·e`` and
``d_p = d - d_a e``, the pulley plane is spanned by ``e`` and the swivel direction
``u = d_p / |d_p|``; the centre is ``C = A + r u``. In that plane, with
``x = (P - C)·u = |d_p| - r`` and ``z = (P - C)·e = d_a``, the free span has length
``L = sqrt(x² + z² - r²)`` and the wrap angle is

    beta = atan2(x, z) + atan2(r, L)

(the cable leaves A along ``e``, bends towards C and leaves tangentially at
``T = C + r (-cos(beta) u + sin(beta) e)`` along ``t = sin(beta) u + cos(beta) e``, so
``P = T + L t``). The path length is ``r beta + L``; the force on the platform points
from P to T, i.e. along ``-t``. For ``r = 0`` this is the straight cable
(``beta`` = angle between ``e`` and ``d``, ``T = A``).

A cable without a pulley is marked by ``pulley_axis = 0`` (the default of a version-1
robot description); it takes the straight branch, selected with ``jnp.where``, whose
numbers are exactly those of the straight-cable formulas (bit for bit).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from cstiffjax.core import config as _config  # noqa: F401


class CablePath(eqx.Module):
    """Geometry of one cable (base frame, SI).

    ``length``: path length from the anchor to the attachment, ``r beta + |P - T|``, m.
    ``free_length``: ``|P - T|``, m. ``tangent_point``: T, where the free span starts
    (the anchor for a straight cable), m. ``direction``: unit vector from P towards T.
    ``wrap``: wrap angle ``beta`` on the pulley, rad (0 for a straight cable). ``swivel_direction``: ``u``, unit,
    perpendicular to the axis (zero for a straight cable). ``centre``: pulley centre C, m.
    ``pulley``: true when the cable runs over a pulley.
    """

    length: Float[Array, ""]
    free_length: Float[Array, ""]
    tangent_point: Float[Array, "3"]
    direction: Float[Array, "3"]
    wrap: Float[Array, ""]
    swivel_direction: Float[Array, "3"]
    centre: Float[Array, "3"]
    pulley: Bool[Array, ""]


def _safe_norm(v, floor=0.0):
    sq = jnp.sum(v * v)
    return jnp.sqrt(jnp.where(sq > floor, sq, 1.0))


def norm_and_divisor(sq):
    """``(|v|, divisor)`` from ``sq = |v|²``: the norm, exactly 0 for a zero vector and NaN
    for a NaN one, with a NaN derivative too (never a made-up value), and a divisor for ``v / divisor`` that
    is the norm where it is positive and 1 elsewhere (a zero vector then gives the zero
    direction). Derivatives stay finite at a zero vector (the square root is taken of a
    positive number only: the "safe sqrt" of autodiff); the status functions
    (:func:`cstiffjax.statics.geometry.pose_status`) flag the zero length.

    **Arguments:** ``sq``: squared norm(s), any shape, m².

    **Returns:** ``(norm, divisor)`` of ``sq``'s shape, m.
    """
    divisor = jnp.sqrt(jnp.where(sq > 0, sq, 1.0))
    # not > 0 and not 0: NaN. Return sq itself there, not a NaN constant: its derivative is then
    # NaN as well (a constant's is 0, which made the structure matrix of a NaN pose all zeros)
    return jnp.where(sq > 0, divisor, jnp.where(sq == 0, 0.0, sq)), divisor


def _straight(anchor, attachment):
    d = anchor - attachment
    length, divisor = norm_and_divisor(jnp.sum(d * d))
    return length, anchor, d / divisor


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def pulley_span(anchor, attachment, radius, axis):
    """The over-pulley geometry of the module docstring, written on components so that one
    cable and a pose-minor batch share the code.

    **Arguments:** ``anchor``, ``attachment``, ``axis``: 3-sequences of arrays (x, y, z
    components, m / unit) of one broadcast shape -- scalars for one cable, ``(m, B)`` for
    ``m`` cables at ``B`` poses (:mod:`cstiffjax.stiffness.kernel`); ``radius`` of that shape, m.

    **Returns:** ``(length, free, tangent, direction, beta, u, centre)``: path length
    ``r beta + |P - T|`` and free span ``|P - T|`` (m), wrap ``beta`` (rad), and as
    3-tuples of components the tangent point T (m), the unit vector P -> T, the swivel
    direction ``u`` and the centre C (m).
    """
    ne = jnp.sqrt(jnp.where(_dot(axis, axis) > 0, _dot(axis, axis), 1.0))
    e = [c / ne for c in axis]
    d = [attachment[k] - anchor[k] for k in range(3)]
    d_a = _dot(d, e)
    d_p = [d[k] - d_a * e[k] for k in range(3)]
    sq = _dot(d_p, d_p)
    dp_len = jnp.sqrt(jnp.where(sq > 1e-30, sq, 1.0))
    u = [c / dp_len for c in d_p]
    x, z = dp_len - radius, d_a
    rho2 = x * x + z * z
    free = jnp.sqrt(jnp.maximum(rho2 - radius * radius, 1e-30))
    # beta = atan2(x, z) + atan2(r, free), its sine and cosine by the angle-sum formulas
    # (one arctan2, no sin/cos: XLA's CPU transcendentals are scalar calls, ~30-60 ns each)
    inv = 1.0 / jnp.sqrt(jnp.where(rho2 > 0, rho2, 1.0) * (radius * radius + free * free))
    sb, cb = (x * free + z * radius) * inv, (z * free - x * radius) * inv
    beta = jnp.arctan2(sb, cb)
    beta = jnp.where((x >= 0) & (beta < 0), beta + 2 * jnp.pi, beta)  # beta in (pi, 3 pi / 2]
    centre = [anchor[k] + radius * u[k] for k in range(3)]
    tangent = tuple(centre[k] + radius * (-cb * u[k] + sb * e[k]) for k in range(3))
    direction = tuple(-(sb * u[k] + cb * e[k]) for k in range(3))
    return radius * beta + free, free, tangent, direction, beta, tuple(u), tuple(centre)


def _over_pulley(anchor, attachment, radius, axis):
    length, free, tangent, dirn, beta, u, centre = pulley_span(anchor, attachment, radius, axis)
    return length, free, jnp.stack(tangent), jnp.stack(dirn), beta, jnp.stack(u), jnp.stack(centre)


def cable_path(anchor: Float[Array, "3"], attachment: Float[Array, "3"], radius: Float[Array, ""],
               axis: Float[Array, "3"]) -> CablePath:
    """Path of one cable from its exit point to the platform (module docstring).

    **Arguments:** ``anchor`` (3,): exit point (with a pulley: where the cable enters it,
    on the swivel axis), base frame, m; ``attachment`` (3,): attachment point in the base
    frame, m; ``radius``: pulley radius, m (0: straight); ``axis`` (3,): swivel axis, the
    cable's direction of travel as it arrives at the anchor (unit; zero: no pulley).

    **Returns:** a :class:`CablePath`. Everything is differentiable; the derivative of
    ``length`` with respect to ``attachment`` is ``-direction``.
    """
    has = jnp.sum(axis * axis) > 0
    l_s, t_s, u_s = _straight(anchor, attachment)
    l_p, free, tangent, dirn, beta, u, centre = _over_pulley(anchor, attachment, radius, axis)
    return CablePath(
        length=jnp.where(has, l_p, l_s), free_length=jnp.where(has, free, l_s),
        tangent_point=jnp.where(has, tangent, t_s), direction=jnp.where(has, dirn, u_s),
        wrap=jnp.where(has, beta, 0.0), swivel_direction=jnp.where(has, u, 0.0),
        centre=jnp.where(has, centre, anchor), pulley=has,
    )


def cable_paths(anchors: Float[Array, "m 3"], attachments: Float[Array, "m 3"], radius: Float[Array, " m"],
                axis: Float[Array, "m 3"]) -> CablePath:
    """:func:`cable_path` of ``m`` cables (fields gain a leading ``m`` axis): the same
    arithmetic on ``(m,)`` components (:func:`pulley_span`), not a ``vmap`` of the one-cable
    function, whose batching rules doubled the tracing of every program holding the
    geometry (bit-for-bit the same numbers, ``tests/test_pulley.py``)."""
    has = jnp.sum(axis * axis, axis=-1) > 0
    d = anchors - attachments
    l_s, divisor = norm_and_divisor(jnp.sum(d * d, axis=-1))
    u_s = d / divisor[:, None]
    cols = lambda a: [a[:, k] for k in range(3)]  # noqa: E731
    l_p, free, tangent, dirn, beta, u, centre = pulley_span(cols(anchors), cols(attachments), radius, cols(axis))
    pick = lambda p, s: jnp.where(has[:, None], jnp.stack(p, axis=-1), s)  # noqa: E731
    return CablePath(
        length=jnp.where(has, l_p, l_s), free_length=jnp.where(has, free, l_s),
        tangent_point=pick(tangent, anchors), direction=pick(dirn, u_s),
        wrap=jnp.where(has, beta, 0.0), swivel_direction=pick(u, 0.0),
        centre=pick(centre, anchors), pulley=has,
    )


def robot_paths(robot, attachments: Float[Array, "m 3"]) -> CablePath:
    """Paths of all cables of ``robot`` to the base-frame ``attachments`` (m, 3), m."""
    return cable_paths(robot.anchors, attachments, robot.pulley_radius, robot.pulley_axis)


def swivel_angle(path: CablePath, axis: Float[Array, "3"], reference: Float[Array, "3"]) -> Float[Array, ""]:
    """Swivel angle of the pulley, rad: the angle about ``axis`` from ``reference``
    (projected perpendicular to the axis) to the swivel direction ``u``, positive
    counter-clockwise about the axis (right-handed frame ``x = reference``,
    ``y = axis × x``)."""
    return direction_angle(path.swivel_direction, axis, reference)


def direction_angle(u: Float[Array, "3"], axis: Float[Array, "3"], reference: Float[Array, "3"]) -> Float[Array, ""]:
    """The angle (rad) about ``axis`` from ``reference`` to the direction ``u`` (both
    projected perpendicular to the axis; right-hand rule), in ``(-pi, pi]``."""
    e = axis / _safe_norm(axis)
    x = reference - (reference @ e) * e
    x = x / _safe_norm(x)
    y = jnp.cross(e, x)
    return jnp.arctan2(u @ y, u @ x)


def vertical_axes(anchors: Float[Array, "m 3"], centre_height: float | None = None) -> Float[Array, "m 3"]:
    """Swivel axes assumed for a description that states none: vertical, ``+z`` for
    anchors above the workspace centre and ``-z`` below (the usual frame layout: cables
    come up the frame to the top pulleys and down to the bottom ones).

    **Arguments:** ``anchors`` (m, 3), m; ``centre_height``: z of the workspace centre, m
    (the diagnosis passes the mean recorded platform height; default the mean anchor
    height, right for a frame with anchors both above and below the workspace).

    **Returns:** (m, 3) unit axes ``(0, 0, ±1)``, a NumPy array for NumPy ``anchors`` (on
    the host, no small programs compiled, :mod:`cstiffjax.core.arrays`), else a JAX array.
    """
    xp = np if isinstance(anchors, np.ndarray) else jnp
    z = anchors[:, 2]
    centre = xp.mean(z) if centre_height is None else centre_height
    sign = xp.where(z >= centre, 1.0, -1.0).astype(anchors.dtype)  # (a strong dtype, as the leaves)
    return xp.stack([xp.zeros_like(sign), xp.zeros_like(sign), sign], axis=1)
