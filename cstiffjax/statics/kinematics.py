"""Forward kinematics with inextensible, straight cables: the pose whose cable lengths match
given lengths (least squares). The start pose of :func:`cstiffjax.statics.forward.forward_statics`
and its ``ideal`` law.
"""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from cstiffjax.core.status import Status, raise_if_failed, solver_errors
from cstiffjax.statics.geometry import apply_twist, lengths_at, moved_frame
from cstiffjax.statics.root_finding import dense_lm


class ForwardKinematics(eqx.Module):
    """Result of :func:`forward_kinematics`: ``pose`` (6,) m / rad and ``result`` a
    :class:`Status` (``not_converged`` where the lengths cannot be matched to 1e-9 m)."""

    pose: Float[Array, "6"]
    result: Status


def _kinematic_residual(twist, args):
    robot, pose0, l0 = args
    return lengths_at(robot, *moved_frame(pose0, twist)) - l0


def _initial_pose(robot):
    c = jnp.mean(robot.anchors, axis=0)
    return jnp.concatenate([c.at[2].set(jnp.min(robot.anchors[:, 2]) - 1.0), jnp.zeros(3)])


@solver_errors
@eqx.filter_jit
def forward_kinematics(robot, l0, pose0=None, *, solver=None, max_steps: int = 256,
                       throw: bool = True) -> ForwardKinematics:
    """Pose whose straight-line cable lengths best match ``l0`` (least squares), m / rad.

    **Arguments:** ``robot``, ``l0`` (m,) cable lengths (m), ``pose0`` the start (default
    below the anchors' centre), ``solver`` an optimistix least-squares solver (default the
    dense LM), ``max_steps``, ``throw``: raise (also under jit) unless successful.

    **Returns:** a :class:`ForwardKinematics`; its ``result`` is ``not_converged`` if the
    lengths cannot be matched to 1e-9 m (over-constrained robots with inconsistent lengths).
    """
    l0 = jnp.asarray(l0, dtype=jnp.float64)
    pose0 = _initial_pose(robot) if pose0 is None else jnp.asarray(pose0, dtype=jnp.float64)
    args = (robot, pose0, l0)
    if solver is None:
        tw, _, ok, _ = dense_lm(lambda z: _kinematic_residual(z, args), jnp.zeros(6), max_steps, 1e-12, 1e-12)
    else:
        import optimistix as optx  # optimistix only when traced (cstiffjax.cable.newton2's module doc)

        sol = optx.least_squares(_kinematic_residual, solver, jnp.zeros(6), args=args, max_steps=max_steps,
                                 throw=False)
        tw, ok = sol.value, sol.result == optx.RESULTS.successful
    err = jnp.max(jnp.abs(_kinematic_residual(tw, args)))
    ok = ok & (err < 1e-9)
    result = Status.where(ok, Status.successful, Status.not_converged)
    pose = apply_twist(pose0, tw)
    return raise_if_failed(result, ForwardKinematics(pose, result), throw)
