"""Wrench-closure workspace: do the cables positively span the wrench space? (exact, batched)

A pose is *wrench-closure* when ``S`` has rank 6 and some strictly positive tensions are
in its null space (``S t = 0``, ``t > 0``): then any wrench can be resisted by adding
enough internal force. With ``N`` the orthonormal null basis (m x r, ``r = m - 6``,
:func:`cstiffjax.stiffness.kernel.null_space`) every internal-force tension vector of unit
2-norm is ``t = N φ`` with ``|φ| = 1``, and the **closure margin** is

    μ_c = max_{|φ| = 1} min_i (N φ)_i        (dimensionless, in [-1, 1]),

the smallest tension of the best unit internal force: ``μ_c > 0`` iff wrench-closure;
``μ_c < 0`` measures how far every internal force is from being all-positive.

For ``r = 2`` the function ``g(φ) = min_i n_i·φ`` on the unit circle is a minimum of
sinusoids, so its maximum is at the peak of one piece (``φ = n_i/|n_i|``) or where two
pieces cross (``φ ⊥ n_i - n_j``, either sign): evaluating ``g`` at these ``m + m(m-1)``
candidates is exact. For ``r = 1``, ``μ_c = max(min_i N_i, min_i -N_i)``. A 6-cable robot
(``r = 0``) has no internal force and is never wrench-closure. Written for pose-minor
batches like :mod:`cstiffjax.stiffness.kernel` (one pose ``(6,)`` or ``(6, B)``).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from cstiffjax.stiffness import kernel as css_kernel
from cstiffjax.workspace.wrench_feasible import _tree_min


class WrenchClosure(eqx.Module):
    """``member`` (wrench-closure), ``margin`` μ_c (dimensionless; ``-inf`` when
    singular), ``singular`` (rank of ``S`` below 6), each with the batch shape."""

    member: Bool[Array, "*batch"]
    margin: Float[Array, "*batch"]
    singular: Bool[Array, "*batch"]


def _candidates(N):
    """Unit directions ``(C, 2, ...)`` at which ``g`` may peak (``r = 2``)."""
    m = N.shape[0]
    nn = jnp.sqrt(N[:, 0] ** 2 + N[:, 1] ** 2)
    ok = nn > 0
    peaks = jnp.where(ok[:, None], N / jnp.where(ok, nn, 1.0)[:, None], jnp.array([1.0, 0.0]).reshape(
        (1, 2) + (1,) * (N.ndim - 2)))
    i, j = np.triu_indices(m, 1)
    d = N[i] - N[j]  # (P, 2, ...)
    nd = jnp.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2)
    safe = jnp.where(nd > 0, nd, 1.0)
    perp = jnp.stack([-d[:, 1] / safe, d[:, 0] / safe], axis=1)
    return jnp.concatenate([peaks, perp, -perp])


def closure_margin(N):
    """μ_c of an orthonormal null basis ``N`` ``(m, r, ...)``, ``r`` in {1, 2}."""
    r = N.shape[1]
    if r == 1:
        return jnp.maximum(_tree_min(N[:, 0]), _tree_min(-N[:, 0]))
    if r != 2:
        raise ValueError(f"wrench closure: implemented for 7 or 8 cables (r = 1, 2), got r = {r}")
    phi = _candidates(N)  # (C, 2, ...)
    g = N[:, None, 0] * phi[None, :, 0] + N[:, None, 1] * phi[None, :, 1]  # (m, C, ...)
    return -_tree_min(-_tree_min(g))


def check_cables(robot) -> None:
    """Raise ``ValueError`` with the reason unless ``robot`` has at least 7 cables (wrench
    closure: positive tensions in the null space of ``S``, which fewer cables lack)."""
    m = robot.num_cables
    if m < 7:
        why = ("6 cables have no internal force: S t = 0 only for t = 0" if m == 6 else
               f"{m} cables span at most {m} of the 6 wrench directions: the platform is held only where gravity "
               f"closes the equilibrium, never against every wrench")
        raise ValueError(f"wrench closure needs at least 7 cables; robot '{robot.name}' has {m} ({why})")


def wrench_closure(robot, pose: Float[Array, "6 ..."]) -> WrenchClosure:
    """Wrench-closure membership and margin μ_c of ``pose`` (``(6,)`` or ``(6, B)``, m / rad).

    **Arguments:** ``robot`` with 7 or 8 cables; ``pose`` poses trailing.

    **Returns:** :class:`WrenchClosure` (tension limits play no part; see
    :func:`cstiffjax.workspace.wrench_feasible.wrench_feasible` for bounded tensions).
    """
    check_cables(robot)
    pose = jnp.asarray(pose, dtype=jnp.float64)
    nb = pose.ndim - 1
    _, r, u, _ = css_kernel.geometry(robot, pose, nb)
    zero = jnp.zeros((6, *pose.shape[1:]))
    _, N, singular = css_kernel.null_space(css_kernel.structure_rows(r, u), zero)
    mu = jnp.where(singular, -jnp.inf, closure_margin(N))
    return WrenchClosure(~singular & (mu > 0), mu, singular)
