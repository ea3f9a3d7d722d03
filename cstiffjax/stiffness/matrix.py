"""Stiffness of a CDPR by autodiff: ``K = -∂W/∂x`` and its split ``K = K1 + K2`` (Cui et al. 2019).

``x`` is the base-frame twist of :mod:`cstiffjax.statics.geometry` (``[δp, δθ]``). ``W`` is the
net wrench on the platform from the cables and gravity (the external wrench is held
fixed in the base frame, so it adds nothing). Seed 004 eq. (5):

    K = -(∂S/∂x T + S ∂T/∂x) = K1 + K2,  K1 = -∂S/∂x·T (controllable),
    K2 = S diag(∂t/∂l) Sᵀ (inherent, eq. 19).

For the spring law ``∂t_i/∂l_i = EA_i / l0_i`` with ``l0`` the unstrained length (Cui et al. 2019
eq. 17). Given tensions rather than lengths, ``l0 = l EA / (EA + t)`` (spring law solved
for l0), so ``EA/l0 = (EA + t)/l``. Gravity with a centre of mass off the reference point
adds ``K_g = -∂W_g/∂x``; it is zero when ``com = 0``.

Symmetry: with the twist coordinates above, the translation fields commute with each
other and with the rotation fields, so ``K - Kᵀ`` only involves the rotation brackets:
``K - Kᵀ = hat(m_c)`` with ``m_c`` the moment of the conservative forces (cables +
gravity) about the reference point; at equilibrium ``m_c = -m_ext``, so ``K`` is
symmetric at zero external moment. The covariant (Levi-Civita) stiffness
``K - ½ hat(m_c)`` is symmetric at every pose, loaded or not (see
:func:`covariant_stiffness`).
"""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec
from jaxtyping import Array, Float

from cstiffjax.cable.laws import CABLE_FORCE_LAWS, CableLaw, check_law
from cstiffjax.core import lie
from cstiffjax.core.status import Status, from_codes, raise_if_failed, solver_errors, to_codes
from cstiffjax.statics.geometry import (
    elastic_wrench_at,
    frame,
    geometry_status,
    gravity_wrench,
    lengths_at,
    structure_matrix_closed_form,
    twist_jacobian,
)
from cstiffjax.stiffness import kernel as css_kernel

BATCH = 64  # poses per pose-minor chunk of :func:`stiffness` (best of 32, 64, 128 measured interleaved)
STATUS_GROUP = 16  # K chunks per chunk of the status (measured faster than the K chunks)
SHARD_MIN = 16  # chunks per device below which :func:`stiffness` stays on one device
# the status codes of the pose-minor chunks (int32 host constants)
_SUCCESSFUL, _ZERO_LENGTH, _INVALID_INPUT = map(to_codes, (Status.successful, Status.zero_length, Status.invalid_input))


def _shard_devices(n_chunks: int) -> list:
    """Local devices to split ``n_chunks`` chunks over (decided at trace time): all of this
    process's devices when there are several (e.g. one per CPU core with
    ``XLA_FLAGS=--xla_force_host_platform_device_count=N``) and every one gets at least
    :data:`SHARD_MIN` chunks; else none (stay on the default device)."""
    if jax.process_count() != 1:
        return []
    devices = jax.local_devices()
    return devices if len(devices) > 1 and n_chunks >= SHARD_MIN * len(devices) else []


class Stiffness(eqx.Module):
    """Result of :func:`stiffness`.

    - ``K`` ``(..., 6, 6)``: the stiffness in base-frame twist coordinates, rows ``[f; m]``
      (N, N·m), columns ``[δp; δθ]`` (m, rad); not finite where ``result`` is not
      ``Status.successful``.
    - ``result``: a :class:`~cstiffjax.core.status.Status` of the batch's shape
      (:func:`pose_status`).
    """

    K: Float[Array, "*batch 6 6"]
    result: Status


class StiffnessSplit(eqx.Module):
    """``K = K1 + K2 + K_gravity`` (6x6, N/m, N, N·m/rad in the twist coordinates) and the
    :class:`~cstiffjax.core.status.Status` ``result`` of the pose (:func:`pose_status`)."""

    K1: Float[Array, "6 6"]
    K2: Float[Array, "6 6"]
    K_gravity: Float[Array, "6 6"]
    result: Status

    @property
    def K(self) -> Float[Array, "6 6"]:
        return self.K1 + self.K2 + self.K_gravity


def unstrained_lengths(robot, pose, tensions) -> Float[Array, " m"]:
    """Spring-law unstrained lengths that give ``tensions`` at ``pose``: ``l EA/(EA+t)``, m."""
    l = lengths_at(robot, *frame(pose))
    return l * robot.EA / (robot.EA + tensions)


@eqx.filter_jit
def stiffness_from_lengths(robot, pose, l0, law: CableLaw = CableLaw.spring) -> Float[Array, "6 6"]:
    """``K = -∂W/∂x`` for cables of unstrained lengths ``l0`` under cable law ``law``
    (:data:`~cstiffjax.cable.laws.CABLE_FORCE_LAWS`).

    Autodiff through the cable law (for ``catenary`` through its implicit solve).
    """
    law = check_law(law, CABLE_FORCE_LAWS, "stiffness_from_lengths")
    l0 = jnp.asarray(l0, dtype=jnp.float64)
    return -twist_jacobian(lambda p, R: elastic_wrench_at(robot, p, R, l0, None, law), pose)


def pose_status(robot, pose, tensions) -> Status:
    """Whether the stiffness is defined at ``pose``: ``invalid_input`` for non-finite tensions,
    else :func:`~cstiffjax.statics.geometry.geometry_status` (``invalid_input`` for a
    non-finite pose, ``zero_length`` when an attachment sits on its anchor, to 1e-12 of the
    frame size)."""
    finite = jnp.all(jnp.isfinite(jnp.asarray(tensions, dtype=jnp.float64)))
    return Status.where(finite, geometry_status(robot, pose), Status.invalid_input)


@solver_errors
def stiffness(robot, pose: Float[Array, "*batch 6"], tensions: Float[Array, "*batch m"], *,
              throw: bool = True) -> Stiffness:
    """6x6 stiffness ``K = -∂W/∂x`` of spring cables holding ``tensions`` (N) at ``pose``.

    Forward-mode autodiff (one ``jvp`` per twist direction) of the wrench of spring cables
    at the unstrained lengths ``l EA/(EA + t)`` plus the weight, along the cable path
    (straight, or over swivel pulleys: length ``r·β + |P - T|``, force towards the tangent
    point T, formats.md §1 v2), written for a pose-minor batch
    (:func:`cstiffjax.stiffness.kernel.spring_stiffness`; the CSS kernel takes its ``K0``,
    ``K1``, ``K2`` from the same path). Give a whole batch at once for speed (poses are
    moved to the minor axis in chunks of :data:`BATCH`, where XLA vectorizes over them and
    the intermediates stay in cache; the status in chunks of up to :data:`STATUS_GROUP`
    of them; with several local devices, e.g. one per CPU core via
    ``XLA_FLAGS=--xla_force_host_platform_device_count=N``, a large batch's chunks are
    split over them, see :func:`_shard_devices`); ``vmap`` works too. A robot whose swivel
    axes are all zero (known before tracing) traces only the straight-cable geometry (bit
    for bit the formulas before pulleys; no pulley code in the program).

    **Arguments:** ``robot`` (:class:`~cstiffjax.io.robot.CableRobot`), ``pose`` ``(..., 6)``
    ``[x, y, z, rx, ry, rz]`` (m, rad), ``tensions`` ``(..., m)`` N (e.g. from inverse
    statics); ``throw``: raise (also under jit) where the stiffness is undefined
    (:func:`pose_status`; the message of the first such pose of a batch): a
    :class:`~cstiffjax.core.errors.SolverError` (under your own ``jax.jit``: JAX's error
    carrying the text, :mod:`cstiffjax.core.status`). Other shapes are a ``ValueError``.

    **Returns:** a :class:`Stiffness`: ``K`` ``(..., 6, 6)`` in base-frame twist
    coordinates (rows ``[f; m]``, N, N·m; columns ``[δp; δθ]``, m, rad) and ``result``,
    a :class:`~cstiffjax.core.status.Status` of the batch's shape (``K`` not finite where
    it is not ``Status.successful``).
    """
    pose, tensions = jnp.asarray(pose, dtype=jnp.float64), jnp.asarray(tensions, dtype=jnp.float64)
    m = robot.num_cables
    if pose.shape[-1:] != (6,) or tensions.shape != (*pose.shape[:-1], m):
        raise ValueError(f"stiffness: pose has shape {pose.shape} and tensions {tensions.shape}; poses (..., 6) "
                         f"[x, y, z, rx, ry, rz] and tensions (..., {m}) with the same leading axes are expected")
    return _stiffness(robot, pose, tensions, throw=throw, layout=css_kernel.pulley_layout(robot))


def _chunk_status(robot, P, T, size, layout):
    """:func:`pose_status` codes of a pose-minor chunk ``P (6, B)``, ``T (m, B)``."""
    # reductions over the small leading axes written out (elementwise over the poses, as css_kernel._sum)
    finite = functools.reduce(jnp.logical_and, [jnp.isfinite(x) for x in (*P, *T)])
    free = css_kernel.frame_paths(robot, P[:3], css_kernel.rotation(P[3:]), 1, layout)[3]  # |T - P|
    ok = functools.reduce(jnp.minimum, list(free)) > 1e-12 * (size + 1.0)
    return jnp.where(finite, jnp.where(ok, _SUCCESSFUL, _ZERO_LENGTH), _INVALID_INPUT)


def _screened_status(robot, P, T, size, layout):
    """:func:`_chunk_status` of a chunk, skipped (``lax.cond``) when a rotation-free bound
    already clears every pose: finite inputs and every free span ``|P_i - T_i| >=
    |A_i - p| - |b_i| - 2 r_i`` above the zero-length tolerance (the attachment is within
    ``|b_i|`` of ``p``, the tangent point within ``2 r_i`` of the anchor ``A_i``: the pulley's
    centre is ``r_i`` from it). Same codes either way."""
    finite = functools.reduce(jnp.logical_and, [jnp.isfinite(x) for x in (*P, *T)])
    reach = jnp.sqrt(_cable_sum(robot.attachments**2)) + 2.0 * jnp.abs(robot.pulley_radius)  # (m,)
    gaps = [jnp.sqrt(sum((robot.anchors[i, k] - P[k]) ** 2 for k in range(3))) - reach[i]
            for i in range(robot.num_cables)]
    clear = finite & (functools.reduce(jnp.minimum, gaps) > 1e-12 * (size + 1.0))
    ok = jnp.full(P.shape[1:], _SUCCESSFUL, dtype=jnp.int32)
    return jax.lax.cond(jnp.all(clear), lambda pt: ok,
                        lambda pt: _chunk_status(robot, *pt, size, layout).astype(jnp.int32), (P, T))


def _cable_sum(x):
    """Row sums of an ``(m, 3)`` array."""
    return x[:, 0] + x[:, 1] + x[:, 2]


def _chunked(P, T, bs):
    """``(n, 6)`` poses and ``(n, m)`` tensions as pose-minor chunks ``(n/bs, 6, bs)``, ``(n/bs, m, bs)``."""
    return jnp.moveaxis(P.reshape(-1, bs, 6), 2, 1), jnp.moveaxis(T.reshape(-1, bs, T.shape[1]), 2, 1)


@eqx.filter_jit
def _stiffness(robot, pose, tensions, *, throw, layout):
    pose = jnp.asarray(pose, dtype=jnp.float64)
    tensions = jnp.asarray(tensions, dtype=jnp.float64)
    batch = pose.shape[:-1]
    P, T = pose.reshape(-1, 6), tensions.reshape(-1, robot.num_cables)
    size = jnp.max(jnp.linalg.norm(robot.anchors, axis=1)) + jnp.max(jnp.linalg.norm(robot.attachments, axis=1))
    n = P.shape[0]
    bs = min(n, BATCH)
    nc = -(-n // bs)
    devices = _shard_devices(nc)
    if devices:  # whole chunks on every device
        nc = -(-nc // len(devices)) * len(devices)
    P = jnp.concatenate([P, jnp.broadcast_to(P[:1], (nc * bs - n, 6))])  # pad with a valid pose
    T = jnp.concatenate([T, jnp.broadcast_to(T[:1], (nc * bs - n, T.shape[1]))])

    def local(P, T):  # this device's poses (k bs, 6), tensions (k bs, m)
        k = P.shape[0] // bs
        K = jax.lax.map(lambda pt: css_kernel.spring_stiffness(robot, *pt, 1, layout), _chunked(P, T, bs))
        # the status in chunks of up to STATUS_GROUP * bs poses: in the K chunks it measured slower
        sb = math.gcd(k, STATUS_GROUP) * bs
        codes = jax.lax.map(lambda pt: _screened_status(robot, *pt, size, layout), _chunked(P, T, sb))
        return jnp.moveaxis(K, 3, 1).reshape(k * bs, 6, 6), codes.reshape(-1)  # (k bs, 6, 6), (k bs,)

    if devices:  # each device maps over its share of the chunks, no communication
        spec = PartitionSpec("chunks")
        local = jax.shard_map(local, mesh=Mesh(np.array(devices), ("chunks",)), in_specs=spec, out_specs=spec,
                              check_vma=False)
    K, codes = local(P, T)
    K = K[:n].reshape(*batch, 6, 6)
    codes = codes.reshape(-1)[:n]
    if throw:
        K = raise_if_failed(from_codes(codes[jnp.argmax(codes != _SUCCESSFUL)]), K, True)
    return Stiffness(K, from_codes(codes.reshape(batch)))


@solver_errors
@eqx.filter_jit
def stiffness_split(robot, pose, tensions, *, throw: bool = True) -> StiffnessSplit:
    """Controllable/inherent split of Cui et al. 2019 eqs (5)-(19), each term by autodiff.

    ``K1 = -∂S/∂x · T`` with ``T`` fixed, ``K2 = S diag(EA/l0) Sᵀ`` with
    ``l0 = l EA/(EA + t)`` and ``K_gravity = -∂W_g/∂x``. ``throw`` as for
    :func:`stiffness`.

    **Returns:** a :class:`StiffnessSplit` (its ``result``: :func:`pose_status`).
    """
    tensions = jnp.asarray(tensions, dtype=jnp.float64)

    def cable_wrench(p, R):
        pose_vec = jnp.concatenate([p, lie.log(R)])
        return structure_matrix_closed_form(robot, pose_vec) @ tensions

    def grav(p, R):
        return gravity_wrench(robot, jnp.concatenate([p, lie.log(R)]))

    K1 = -twist_jacobian(cable_wrench, pose)
    S = structure_matrix_closed_form(robot, pose)
    k = robot.EA / unstrained_lengths(robot, pose, tensions)
    K2 = (S * k) @ S.T
    K_gravity = -twist_jacobian(grav, pose)
    status = pose_status(robot, pose, tensions)
    K1, K2, K_gravity = raise_if_failed(status, (K1, K2, K_gravity), throw)
    return StiffnessSplit(K1, K2, K_gravity, status)


def covariant_stiffness(K: Float[Array, "6 6"], moment: Float[Array, "3"]) -> Float[Array, "6 6"]:
    """Covariant (Levi-Civita) stiffness ``K - ½ hat(m)`` in the rotation block.

    ``m`` is the moment of the conservative forces on the platform about the reference
    point (cables + gravity; ``-m_ext`` at equilibrium), N·m. With the base-frame rotation
    fields ``X_a`` of the twist coordinates, ``[X_a, X_b] = -X_{a×b}``, so ``K - Kᵀ =
    hat(m)``, and the connection term ``½[X, Y]U`` of the bi-invariant Levi-Civita
    connection removes exactly that: the result is the Riemannian Hessian of the
    potential energy, symmetric at every pose (tests check it).
    """
    return K.at[3:, 3:].add(-0.5 * lie.hat(moment))


def _rpy_matrix(a):
    ca, sa = jnp.cos(a), jnp.sin(a)
    Rx = jnp.array([[1, 0, 0], [0, ca[0], -sa[0]], [0, sa[0], ca[0]]])
    Ry = jnp.array([[ca[1], 0, sa[1]], [0, 1, 0], [-sa[1], 0, ca[1]]])
    Rz = jnp.array([[ca[2], -sa[2], 0], [sa[2], ca[2], 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def euler_angles(pose) -> Float[Array, "3"]:
    """Fixed-axis X-Y-Z angles (α, β, γ) with ``R = Rz(γ) Ry(β) Rx(α)``, rad."""
    R = lie.exp(jnp.asarray(pose)[3:])
    return jnp.array([jnp.arctan2(R[2, 1], R[2, 2]), -jnp.arcsin(jnp.clip(R[2, 0], -1, 1)),
                      jnp.arctan2(R[1, 0], R[0, 0])])


@eqx.filter_jit
def to_euler_coordinates(robot, pose, l0, external=None, law: CableLaw = CableLaw.spring) -> Float[Array, "6 6"]:
    """Stiffness in Cui et al.'s coordinates ``q = (x, y, z, α, β, γ)`` (rad; multiply the
    rotation columns by π/180 for the paper's degrees).

    Seed 004 does not print its angle convention (Fig. 3 only says "angular
    displacement"); we take fixed-axis X-Y-Z (roll-pitch-yaw) angles, which coincide with
    the twist coordinates to first order at zero rotation. ``K_q = -∂W_q/∂q`` with the
    generalized force ``W_q = Bᵀ W``, ``B = ∂twist/∂q``; the ``∂B/∂q · W`` term vanishes at
    equilibrium, and is included here. ``law``: one of
    :data:`~cstiffjax.cable.laws.CABLE_FORCE_LAWS`.
    """
    law = check_law(law, CABLE_FORCE_LAWS, "to_euler_coordinates")
    l0 = jnp.asarray(l0, dtype=jnp.float64)
    pos = jnp.asarray(pose)[:3]
    q0 = jnp.concatenate([pos, euler_angles(pose)])

    def generalized_force(q):
        R = _rpy_matrix(q[3:])
        p = q[:3]
        # B maps dq to the base-frame twist: dθ = vee(dR Rᵀ)
        def twist_of(dq):
            return jnp.concatenate([dq[:3], lie.vee(jax.jvp(_rpy_matrix, (q[3:],), (dq[3:],))[1] @ R.T)])

        B = jax.jacfwd(twist_of)(jnp.zeros(6))
        return B.T @ elastic_wrench_at(robot, p, R, l0, external, law)

    return -jax.jacfwd(generalized_force)(q0)
