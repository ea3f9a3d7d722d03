"""What a CDPR's on-board sensors read at a pose (formats.md §2, version 3).

- **Swivel encoders** (:func:`swivel_angles`): the angle of each pulley about its
  ``pulley_axis`` (right-hand rule) from the cable's ``swivel_zero`` to the pulley plane's
  direction ``u`` towards the attachment point: the same ``u`` as the cable path every law
  uses (:func:`cstiffjax.cable.path.robot_paths`).
- **AHRS** (:func:`ahrs_angles`): the sensor frame's orientation ``Z(yaw0) R M`` (``R`` the
  platform's, ``M`` the mounting ``ahrs_mounting``, ``Z(yaw0)`` a rotation about the base
  ``z`` axis by the session's yaw zero) as Z-Y-X Euler angles ``[roll, pitch, yaw]`` with
  ``Rz(yaw) Ry(pitch) Rx(roll)``.

Everything is written for one pose (``vmap`` for a batch) and is differentiable.
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from cstiffjax.cable.path import direction_angle, robot_paths
from cstiffjax.core import lie
from cstiffjax.statics.geometry import frame


def swivel_angles(robot, pose: Float[Array, "6"]) -> Float[Array, " m"]:
    """Swivel angle of every cable's pulley at ``pose`` (6: m, rad), rad in ``(-pi, pi]``;
    0 for a cable without ``pulley_axis`` or ``swivel_zero`` (nothing to read)."""
    p, R = frame(pose)
    paths = robot_paths(robot, p + robot.attachments @ R.T)
    angles = jax.vmap(direction_angle)(paths.swivel_direction, robot.pulley_axis, robot.swivel_zero)
    stated = jnp.any(robot.swivel_zero != 0, axis=1) & jnp.any(robot.pulley_axis != 0, axis=1)
    return jnp.where(stated, angles, 0.0)


def rotation_zyx(angles: Float[Array, "3"]) -> Float[Array, "3 3"]:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` of ``angles = [roll, pitch, yaw]``, rad."""
    roll, pitch, yaw = angles
    e = jnp.eye(3)
    return lie.exp(yaw * e[2]) @ lie.exp(pitch * e[1]) @ lie.exp(roll * e[0])


def euler_zyx(R: Float[Array, "3 3"]) -> Float[Array, "3"]:
    """``[roll, pitch, yaw]`` (rad) with ``R = Rz(yaw) Ry(pitch) Rx(roll)``; pitch in
    ``[-pi/2, pi/2]`` (a sensor pitched by 90 degrees has no unique roll and yaw)."""
    pitch = jnp.arcsin(jnp.clip(-R[2, 0], -1.0, 1.0))
    return jnp.stack([jnp.arctan2(R[2, 1], R[2, 2]), pitch, jnp.arctan2(R[1, 0], R[0, 0])])


def ahrs_angles(robot, pose: Float[Array, "6"], yaw_zero: Float[Array, ""] = 0.0) -> Float[Array, "3"]:
    """What the AHRS reads at ``pose`` (6: m, rad) with the session's ``yaw_zero`` (rad):
    ``[roll, pitch, yaw]`` of ``Rz(yaw_zero) R(pose) exp(ahrs_mounting)``, rad."""
    R = lie.exp(jnp.asarray(yaw_zero, dtype=jnp.float64) * jnp.eye(3)[2]) @ lie.exp(pose[3:])
    return euler_zyx(R @ lie.exp(robot.ahrs_mounting))


def angle_difference(a, b):
    """``a - b`` wrapped to ``(-pi, pi]``, rad (angles read modulo a turn)."""
    d = a - b
    return d - 2.0 * jnp.pi * jnp.round(d / (2.0 * jnp.pi))
