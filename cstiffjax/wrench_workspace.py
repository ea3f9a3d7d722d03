"""Wrench-feasible workspace: exact membership and capacity margin, one pose or a pose-minor batch.

A pose is *wrench-feasible* for a required set ``W_req`` of external wrenches (N, N·m,
about the platform reference point, base frame, weight excluded) when every ``w`` in the
set can be held with tensions inside the limits: ``S t = -(w + W_g)`` for some ``t`` in
``[t_min, t_max]^m`` (seed 004 eq. 3 with bounds). The available wrenches form the
zonotope ``Z = {S t : t ∈ [t_min, t_max]^m}`` and the test is ``-(W_req + W_g) ⊂ Z``.

Hyperplane shifting (Bouchard, Gosselin & Moore 2010; Gouttefarde & Krut 2010): every
facet of ``Z`` in R^6 is parallel to ``n - 1 = 5`` linearly independent columns of ``S``;
its normal ``n_J`` is orthogonal to those 5 columns and ``Z`` lies between the two
hyperplanes ``n_J · (z - c) = ±d_J`` with ``c = S t_mid`` and ``d_J = Σ_i h |n_J · s_i|``
(``h = (t_max - t_min)/2``). So ``Z = {z : |n_J·(z - c)| <= d_J for all J}`` exactly, and
``-(W_req + W_g) ⊂ Z`` iff each hyperplane pair holds the extreme points of the set.

The normals are computed by Gale duality instead of 5x5 cofactors: with ``N`` the
orthonormal null basis of ``S`` (m x r, ``r = m - 6``) the vector ``y = Sᵀ n_J`` vanishes
on ``J`` and is therefore supported on the complement ``K`` (``r + 1`` cables, ``C(8, 3) =
C(8, 5) = 56`` facets for 8 cables) with ``N_Kᵀ y_K = 0``: ``y_K`` is the cross product of
the two columns of ``N_K`` (``r = 2``), ``(N_k2, -N_k1)`` (``r = 1``) or ``1`` (``r = 0``).
Then ``d_J = h Σ_K |y_k|``, ``n_J·(q - c) = y·(t_q - t_mid)`` for any tensions ``t_q`` with
``S t_q = q``, and ``n_J = S⁺ᵀ y`` (needed for the box term and the margin). ``y_K = 0``
exactly when the 5 columns are dependent; such combinations carry no facet and are
dropped (``|y| <= 1e-12``; every facet of ``Z`` is spanned by some independent 5 columns).

**Capacity margin** (Guay, Cardou, Cruz-Ruiz & Caro 2014): ``s = min_J min_w`` of the
signed distance from the extreme points of ``-(W_req + W_g)`` to the facet hyperplanes of
``Z``, in the wrench metric ``|f|² + |m/L|²`` (``L = length_scale``, m; moments are divided
by ``L``). ``s >= 0`` iff the pose is wrench-feasible; then the required set can grow by
a ball of radius ``s`` (N) and still be held; ``s < 0`` is (minus) the largest distance
by which some extreme wrench lies beyond a facet hyperplane: the set must shrink.

Everything is written for pose-minor arrays (small axes first, poses trailing, as in
:mod:`cstiffjax.css_kernel`), so one pose ``(6,)`` and a batch ``(6, B)`` share the code
and XLA vectorizes over the poses on CPU. The structure matrix, the load wrench and the
null space come from :mod:`cstiffjax.css_kernel` (the batched form of
:func:`cstiffjax.statics.structure_matrix_closed_form`).
"""

import itertools

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from . import css_kernel
from .css_kernel import _sum, _tail

_Y_TOL = 1e-12  # |y| below this: the 5 columns are dependent, no facet


class WrenchSet(eqx.Module):
    """Required external wrenches ``center + box(radii) ⊕ conv(offsets)`` (N, N·m).

    Wrenches ``[fx, fy, fz, mx, my, mz]`` about the platform reference point in the base
    frame, weight excluded. A box has ``offsets`` of shape ``(0, 6)``; a vertex list has
    ``radii = 0`` and ``offsets`` the vertices relative to ``center``. Build with
    :meth:`box` or :meth:`vertices`.
    """

    center: Float[Array, "6"]
    radii: Float[Array, "6"]
    offsets: Float[Array, "V 6"]

    @classmethod
    def box(cls, lower, upper) -> "WrenchSet":
        """Axis-aligned box ``lower <= w <= upper`` (each ``(6,)``, N and N·m)."""
        lo, hi = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
        if lo.shape != (6,) or hi.shape != (6,):
            raise ValueError(f"WrenchSet.box: lower and upper must have shape (6,), got {lo.shape}, {hi.shape}")
        bad = ~(np.isfinite(lo) & np.isfinite(hi) & (lo <= hi))
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(f"WrenchSet.box: component {k}: need finite lower <= upper, got "
                             f"lower = {lo[k]!r}, upper = {hi[k]!r}")
        return cls(jnp.asarray(0.5 * (lo + hi)), jnp.asarray(0.5 * (hi - lo)), jnp.zeros((0, 6)))

    @classmethod
    def vertices(cls, points) -> "WrenchSet":
        """Convex hull of ``points`` ``(V, 6)`` (V >= 1), N and N·m."""
        v = np.asarray(points, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 6 or len(v) < 1:
            raise ValueError(f"WrenchSet.vertices: points must have shape (V >= 1, 6), got {v.shape}")
        if not np.all(np.isfinite(v)):
            row = int(np.argmax(~np.all(np.isfinite(v), axis=1)))
            raise ValueError(f"WrenchSet.vertices: row {row} is not finite: {v[row].tolist()}")
        c = v.mean(axis=0)
        return cls(jnp.asarray(c), jnp.zeros(6), jnp.asarray(v - c))

    def extreme_points(self) -> np.ndarray:
        """All extreme-point candidates (numpy, ``(2^6 · max(V, 1), 6)``), for references and plots."""
        signs = np.array(list(itertools.product((-1.0, 1.0), repeat=6)))
        corners = np.asarray(self.center) + signs * np.asarray(self.radii)
        off = np.asarray(self.offsets)
        if len(off) == 0:
            return np.unique(corners, axis=0)
        return np.unique((corners[:, None] + off[None]).reshape(-1, 6), axis=0)


class WrenchFeasible(eqx.Module):
    """Result for a pose or a batch ``(...)``: ``member`` (wrench-feasible), ``margin``
    (capacity margin, N in the metric ``|f|² + |m/L|²``; ``-inf`` when singular) and
    ``singular`` (``S`` rank deficient: reported as not a member)."""

    member: Bool[Array, "*batch"]
    margin: Float[Array, "*batch"]
    singular: Bool[Array, "*batch"]


def facet_cables(m: int) -> np.ndarray:
    """Static ``(F, r + 1)`` cable indices ``K`` of the facets (complements of the 5-column sets)."""
    r = m - 6
    if r < 0 or r > 2:
        raise ValueError(f"wrench workspace: needs 6, 7 or 8 cables (r = m - 6 <= 2), got m = {m}")
    return np.array(list(itertools.combinations(range(m), r + 1)), dtype=np.int64)


def _gale(N, K):
    """``y_K`` ``(r + 1, F, ...)``: the null vector of ``N_Kᵀ`` for every facet (see module doc)."""
    r = N.shape[1]
    if r == 0:
        return jnp.ones((1, K.shape[0], *N.shape[2:]))
    rows = [N[K[:, c]] for c in range(r + 1)]  # each (F, r, ...)
    if r == 1:
        return jnp.stack([rows[1][:, 0], -rows[0][:, 0]])
    a, b, c = rows
    return jnp.stack([b[:, 0] * c[:, 1] - c[:, 0] * b[:, 1], c[:, 0] * a[:, 1] - a[:, 0] * c[:, 1],
                      a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]])


def pseudo_inverse_rows(s, R):
    """``S⁺ᵀ`` rows: ``P`` ``(m, 6, ...)`` with ``P[i] = (S Sᵀ)⁻¹ s_i``, for all cables at once
    by two triangular solves with the QR factor of ``Sᵀ`` (``S Sᵀ = Rᵀ R``; ``R`` from
    :func:`cstiffjax.css_kernel.qr_null_space`, the identity where singular). Reusing the
    null space's QR replaces a Gram matrix and its Cholesky factorization (and is the
    better-conditioned route)."""
    z = []
    for i in range(6):  # Rᵀ z = s_i
        z.append((s[:, i] - sum(R[k][i] * z[k] for k in range(i))) / R[i][i])
    x = [None] * 6
    for i in reversed(range(6)):  # R x = z
        x[i] = (z[i] - sum(R[i][k] * x[k] for k in range(i + 1, 6))) / R[i][i]
    return jnp.stack(x, axis=1)


def _tree_min(x):
    """Minimum over the leading axis as pairwise ``jnp.minimum`` (vectorizes over the poses)."""
    while x.shape[0] > 1:
        k = x.shape[0] // 2
        head = jnp.minimum(x[:k], x[k:2 * k])
        x = jnp.concatenate([head, x[2 * k:]]) if x.shape[0] % 2 else head
    return x[0]


def facet_quotients(robot, pose, wrench_set: WrenchSet, length_scale=1.0):
    """``sign(g) g² / |n|²`` of every facet ``(F, ...)`` (N²; ``+inf`` for dropped
    combinations) and ``singular`` ``(...)`` for ``pose`` ``(6, ...)``: ``g / |n|`` is the
    facet's signed margin (N), ``g`` the gap of the worst extreme wrench to the facet's
    hyperplane pair and ``|n|`` the normal's length in the margin metric. The signed square
    is monotone in the margin, so the minimum over the facets needs one square root per
    pose, not one per facet. See the module docstring."""
    nb = pose.ndim - 1
    m = robot.num_cables
    K = facet_cables(m)
    R, r, u, _ = css_kernel.geometry(robot, pose, nb)
    s = css_kernel.structure_rows(r, u)  # (m, 6, ...)
    tp, N, singular, Rq = css_kernel.qr_null_space(s, css_kernel.load_wrench(robot, R, wrench_set.center, nb))
    P = pseudo_inverse_rows(s, Rq)
    tmid = 0.5 * (robot.tension_max + robot.tension_min)
    h = 0.5 * (robot.tension_max - robot.tension_min)
    y = _gale(N, K)  # (r+1, F, ...)
    tau = tp - tmid  # (m, ...)
    d = h * _sum(jnp.abs(y))
    a = _sum(jnp.stack([y[c] * tau[K[:, c]] for c in range(K.shape[1])]))
    # n_J = S⁺ᵀ y: -n·w is the change of y·τ under the extra wrench w
    n = _sum(jnp.stack([y[c][:, None] * P[K[:, c]] for c in range(K.shape[1])]))  # (F, 6, ...)
    radii = _tail(wrench_set.radii, nb)
    box = _sum(jnp.abs(n) * radii[None], axis=1)
    hi, lo = a + box, a - box  # range of y·τ over the box, before the offsets
    off = wrench_set.offsets
    if off.shape[0]:
        e = _sum(n[:, None] * _tail(off, nb)[None], axis=2)  # (F, V, ...) = n·o_v
        hi, lo = hi - jnp.min(e, axis=1), lo - jnp.max(e, axis=1)
    L = jnp.asarray(length_scale, dtype=jnp.float64)
    norm2 = _sum(n[:, :3] ** 2, axis=1) + L**2 * _sum(n[:, 3:] ** 2, axis=1)
    live = _sum(y * y) > _Y_TOL**2
    raw = jnp.minimum(d - hi, d + lo)
    quotients = jnp.where(live, raw * jnp.abs(raw) / jnp.where(live, norm2, 1.0), jnp.inf)
    return quotients, singular


def wrench_feasible(robot, pose: Float[Array, "6 ..."], wrench_set: WrenchSet, *,
                    length_scale: float = 1.0) -> WrenchFeasible:
    """Wrench-feasible membership and capacity margin of ``pose`` (``(6,)`` or ``(6, B)``).

    **Arguments:**

    - ``robot``: a :class:`~cstiffjax.robot.CableRobot` with 6 to 8 cables and finite
      ``tension_max``.
    - ``pose``: ``[x, y, z, rx, ry, rz]`` (m, rad) on the leading axis, poses trailing.
    - ``wrench_set``: a :class:`WrenchSet` (N, N·m, about the reference point; the
      platform weight is added here).
    - ``length_scale``: ``L`` (m) of the margin metric ``|f|² + |m/L|²`` (default 1 m).

    **Returns:** :class:`WrenchFeasible` with batch shape ``pose.shape[1:]``. Exact up to
    rounding (tested against a linear program per extreme wrench). Jit it (or call it
    inside :func:`cstiffjax.workspace.sweep` with ``vectorized=True``).
    """
    check_limits(robot)
    pose = jnp.asarray(pose, dtype=jnp.float64)
    quotients, singular = facet_quotients(robot, pose, wrench_set, length_scale)
    q = _tree_min(quotients)  # sign(g) g²/|n|² is monotone in g/|n|: one square root per pose
    margin = jnp.where(singular, -jnp.inf, jnp.sign(q) * jnp.sqrt(jnp.abs(q)))
    return WrenchFeasible(~singular & (margin >= 0), margin, singular)


def check_limits(robot) -> None:
    """Raise ``ValueError`` when the tension limits are concrete and not finite / ordered."""
    try:
        lo, hi = float(robot.tension_min), float(robot.tension_max)
    except Exception:  # traced: nothing to check here
        return
    if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
        raise ValueError(f"robot '{robot.name}': the wrench-feasible workspace needs finite tension limits "
                         f"tension_min <= tension_max ([limits] in the TOML), got [{lo!r}, {hi!r}] N")
