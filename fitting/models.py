"""Measurement models: predicted poses/tensions of a CDPR and whitened residuals.

The CDPR model maps the *inputs* of a recording (commanded unstrained lengths ``l0``
and external wrench) to the *measurements* (pose and exit-point tensions) by forward
statics (:func:`cstiffjax.statics.forward_statics`, seed 003 "direct kinematics").

Residual layout (:func:`residual_channels`): per sample ``6 + m`` columns

====================  =========================================================
``x, y, z``           ``(p_meas - p_pred) / σ_position``
``rx, ry, rz``        ``log(R_meas R_predᵀ) / σ_rotation`` (base frame; its norm is
                      the geodesic ``rotation_distance`` of seed 000 eq. 63)
``t_1 … t_m``         ``(t_meas - t_pred) / σ_tension`` where a tension was
                      recorded, ``0`` elsewhere
====================  =========================================================
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from cstiffjax import lie
from cstiffjax.statics import forward_statics
from jaxtyping import Array, Float


def residual_channels(m: int) -> tuple[str, ...]:
    """Names of the ``6 + m`` residual columns of :func:`cdpr_residuals`."""
    return ("x", "y", "z", "rx", "ry", "rz", *(f"t_{i}" for i in range(1, m + 1)))


def predict_cdpr(robot, l0: Float[Array, "n m"], wrench: Float[Array, "n 6"], *, law: str = "spring",
                 pose0: Float[Array, "n 6"] | None = None, solver=None, max_steps: int = 256):
    """Forward statics of every sample (vmapped, ``throw=False``).

    **Arguments:** ``robot`` a :class:`~cstiffjax.robot.CableRobot`; ``l0`` ``(n, m)``
    unstrained lengths, m; ``wrench`` ``(n, 6)`` external wrench (N, N·m); ``law``
    ``"spring"``, ``"catenary"`` or ``"ideal"``; ``pose0`` ``(n, 6)`` per-sample start
    poses (use the measured poses: the solve then starts next to the answer), default
    the ideal-cable pose.

    **Returns:** ``(pose (n, 6), tensions (n, m) at the exit points, result (n,))``;
    ``result`` a batched :class:`~cstiffjax.status.Status` to check.
    """
    l0 = jnp.asarray(l0, dtype=jnp.float64)
    wrench = jnp.asarray(wrench, dtype=jnp.float64)

    def one(l, w, p0):
        fs = forward_statics(robot, l, w, p0, law=law, solver=solver, max_steps=max_steps, throw=False)
        return fs.pose, fs.tensions, fs.result

    if pose0 is None:
        return jax.vmap(lambda l, w: one(l, w, None))(l0, wrench)
    return jax.vmap(one)(l0, wrench, jnp.asarray(pose0, dtype=jnp.float64))


def rotation_difference(rv_meas: Float[Array, "3"], rv_pred: Float[Array, "3"]) -> Float[Array, "3"]:
    """``log(R_meas R_predᵀ)``: the base-frame rotation taking the prediction to the
    measurement, rad (``‖·‖`` = geodesic distance, seed 000 eq. 63)."""
    return lie.log(lie.exp(rv_meas) @ lie.exp(rv_pred).T)


def cdpr_residuals(pred_pose: Float[Array, "n 6"], pred_tensions: Float[Array, "n m"], recordings,
                   noise) -> Float[Array, "n 6+m"]:
    """Whitened residuals ``(measured - predicted)/σ`` of every sample (see module docstring).

    **Arguments:** predictions from :func:`predict_cdpr`; ``recordings`` a
    :class:`~cstiffjax.recordings.Recordings` (its ``pose``, ``tensions``,
    ``tension_mask``); ``noise`` a :class:`~cstiffjax.robot.Noise` (σ's, m, rad, N).

    **Returns:** ``(n, 6 + m)`` residuals, columns named by :func:`residual_channels`.
    """
    meas = recordings.pose
    dp = (meas[:, :3] - pred_pose[:, :3]) / noise.position
    dr = jax.vmap(rotation_difference)(meas[:, 3:], pred_pose[:, 3:]) / noise.rotation
    dt = jnp.where(recordings.tension_mask, (recordings.tensions - pred_tensions) / noise.tension, 0.0)
    return jnp.concatenate([dp, dr, dt], axis=1)


def num_effective(recordings) -> int:
    """Number of recorded scalars: 6 pose components per sample plus the recorded tensions."""
    return int(6 * recordings.num_samples + jnp.sum(recordings.tension_mask))


@eqx.filter_jit
def cdpr_model_residuals(robot, recordings, *, law: str = "spring", solver=None, max_steps: int = 256):
    """Residuals of ``robot`` on ``recordings`` with per-sample start at the measured pose.

    **Returns:** ``(residuals (n, 6+m), result (n,))``.
    """
    pose, t, res = predict_cdpr(robot, recordings.l0, recordings.wrench, law=law, pose0=recordings.pose,
                                solver=solver, max_steps=max_steps)
    return cdpr_residuals(pose, t, recordings, robot.noise), res
