"""Wrench-feasible workspace: exact membership and capacity margin, one pose or a pose-minor batch.

A pose is *wrench-feasible* for a required set ``W_req`` of external wrenches (N, N·m,
about the platform reference point, base frame, weight excluded) when every ``w`` in the
set can be held with tensions inside the limits: ``S t = -(w + W_g)`` for some ``t`` in
``[t_min, t_max]^m`` (Cui et al. 2019 eq. 3 with bounds). The available wrenches form the
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
``N``, ``S⁺ᵀ`` and the minimum-norm tensions come from the Cholesky factor of the Gram
matrix ``S Sᵀ`` (:func:`gram_null_space`: no QR, whose Householder passes cost more
than the whole facet loop; margins agree with the QR route to 3e-13 relative on 131072
poses of ``bench_wrench_workspace.py``, same members).

**Capacity margin** (Guay, Cardou, Cruz-Ruiz & Caro 2014): ``s = min_J min_w`` of the
signed distance from the extreme points of ``-(W_req + W_g)`` to the facet hyperplanes of
``Z``, in the wrench metric ``|f|² + |m/L|²`` (``L = length_scale``, m; moments are divided
by ``L``). ``s >= 0`` iff the pose is wrench-feasible; then the required set can grow by
a ball of radius ``s`` (N) and still be held; ``s < 0`` is (minus) the largest distance
by which some extreme wrench lies beyond a facet hyperplane: the set must shrink.

Everything is written for pose-minor arrays (small axes first, poses trailing, as in
:mod:`cstiffjax.stiffness.kernel`), so one pose ``(6,)`` and a batch ``(6, B)`` share the code
and XLA vectorizes over the poses on CPU. The structure matrix and the load wrench come
from :mod:`cstiffjax.css_kernel` (the batched form of
:func:`cstiffjax.statics.geometry.structure_matrix_closed_form`).
"""

import itertools

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from cstiffjax.core.status import Status, select
from cstiffjax.stiffness import kernel as css_kernel
from cstiffjax.stiffness.kernel import RANK_TOL, axis_sum, trailing_axes

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
    ``singular`` (``S`` rank deficient: reported as not a member); :attr:`result` says the
    same as a :class:`~cstiffjax.core.status.Status`."""

    member: Bool[Array, "*batch"]
    margin: Float[Array, "*batch"]
    singular: Bool[Array, "*batch"]

    @property
    def result(self) -> Status:
        """``singular``, ``infeasible`` (not a member) or ``successful``, of the batch's shape."""
        return select(self.singular, Status.singular, select(self.member, Status.successful, Status.infeasible))


def facet_cables(m: int) -> np.ndarray:
    """Static ``(F, r + 1)`` cable indices ``K`` of the facets (complements of the 5-column sets)."""
    r = m - 6
    if r < 0 or r > 2:
        raise ValueError(f"wrench workspace: needs 6, 7 or 8 cables (r = m - 6 <= 2), got m = {m}")
    return np.array(list(itertools.combinations(range(m), r + 1)), dtype=np.int64)


def pseudo_inverse_rows(s, R):
    """``S⁺ᵀ`` rows: ``P`` ``(m, 6, ...)`` with ``P[i] = (S Sᵀ)⁻¹ s_i``, for all cables at once
    by two triangular solves with an upper triangular ``R`` (nested lists of ``(...)``
    arrays) such that ``S Sᵀ = Rᵀ R``: the QR factor of ``Sᵀ`` (from
    :func:`cstiffjax.stiffness.kernel.qr_null_space`) or the transposed Cholesky factor of
    ``S Sᵀ`` (as :func:`gram_null_space` uses it); the identity where singular."""
    z = []
    for i in range(6):  # Rᵀ z = s_i
        z.append((s[:, i] - sum(R[k][i] * z[k] for k in range(i))) / R[i][i])
    x = [None] * 6
    for i in reversed(range(6)):  # R x = z
        x[i] = (z[i] - sum(R[i][k] * x[k] for k in range(i + 1, 6))) / R[i][i]
    return jnp.stack(x, axis=1)


def _argmax_column(diag, cols):
    """The column ``cols[k]`` (each ``(m, ...)``) and ``diag[k]`` at ``k = argmax diag``
    (first on ties), per pose, by a running select (elementwise over the poses)."""
    best, col = diag[0], cols[0]
    for k in range(1, len(cols)):
        take = diag[k] > best
        best, col = jnp.where(take, diag[k], best), jnp.where(take, cols[k], col)
    return best, col


def gram_null_space(s, w):
    """``(t_p, N, singular, P)`` for ``Sᵀ`` rows ``s`` ``(m, 6, ...)`` and the load ``w``
    ``(6, ...)``, by the Cholesky factor ``L`` of the Gram matrix ``G = S Sᵀ`` (no QR):

    - ``P`` ``(m, 6, ...)``: the rows of ``S⁺ᵀ``, ``P[i] = G⁻¹ s_i`` (two triangular solves);
    - ``t_p`` ``(m, ...)``: the minimum-norm tensions with ``S t_p = -w``, ``t_p,i = -P[i]·w``;
    - ``N`` ``(m, m - 6, ...)``: an orthonormal null basis of ``S`` by a pivoted rank-2
      (or 1) Cholesky of the projector ``Π = I - Sᵀ G⁻¹ S = N Nᵀ`` (largest diagonal
      first; ``Π_ij = δ_ij - s_i·P[j]``);
    - ``singular`` ``(...)``: ``min L_kk <= 1e-9 max L_kk`` (``L_kk = |R_kk|`` of the QR of
      ``Sᵀ``, the test of :func:`cstiffjax.stiffness.kernel.qr_null_space`); ``L`` is the identity
      there, so everything stays finite.

    ``G`` squares the condition number of ``S``: fine for the wrench-feasible facets
    (tested against an LP and an SVD brute force to 1e-9), the QR stays in
    :mod:`cstiffjax.stiffness.kernel` for the CSS."""
    m = s.shape[0]
    G = [[axis_sum(s[:, i] * s[:, j]) if j <= i else None for j in range(6)] for i in range(6)]
    L = [[None] * 6 for _ in range(6)]
    for j in range(6):
        dj = G[j][j] - sum(L[j][k] * L[j][k] for k in range(j))
        L[j][j] = jnp.sqrt(jnp.maximum(dj, 0.0))
        inv = 1.0 / jnp.where(L[j][j] > 0, L[j][j], 1.0)
        for i in range(j + 1, 6):
            L[i][j] = (G[i][j] - sum(L[i][k] * L[j][k] for k in range(j))) * inv
    diag = jnp.stack([L[k][k] for k in range(6)])
    singular = ~(jnp.min(diag, axis=0) > RANK_TOL * jnp.max(diag, axis=0))
    R = [[jnp.where(singular, float(i == j), L[j][i]) if j >= i else None for j in range(6)] for i in range(6)]
    P = pseudo_inverse_rows(s, R)  # (m, 6, ...)
    tp = jnp.where(singular, 0.0, -axis_sum(P * w[None], axis=1))
    r = m - 6
    if r == 0:
        return tp, jnp.zeros((m, 0, *tp.shape[1:])), singular, P
    pi = [[None] * m for _ in range(m)]  # Π, symmetric
    for i in range(m):
        for j in range(i, m):
            pi[i][j] = pi[j][i] = float(i == j) - axis_sum(s[i] * P[j])
    cols = [jnp.stack([pi[i][j] for i in range(m)]) for j in range(m)]
    d1, a = _argmax_column([pi[i][i] for i in range(m)], cols)
    n1 = a / jnp.sqrt(jnp.where(d1 > 0, d1, 1.0))
    if r == 1:
        return tp, n1[:, None], singular, P
    d2, b = _argmax_column([pi[i][i] - n1[i] * n1[i] for i in range(m)],
                           [cols[j] - n1 * n1[j] for j in range(m)])
    n2 = b / jnp.sqrt(jnp.where(d2 > 0, d2, 1.0))
    return tp, jnp.stack([n1, n2], axis=1), singular, P


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
    tp, N, singular, P = gram_null_space(s, css_kernel.load_wrench(robot, R, wrench_set.center, nb))
    tmid = 0.5 * (robot.tension_max + robot.tension_min)
    h = 0.5 * (robot.tension_max - robot.tension_min)
    return _facets(N, K, tp - tmid, P, h, wrench_set, length_scale, nb), singular


def _facets(N, K, tau, P, h, wrench_set, length_scale, nb):
    """The quotients ``(F, ...)`` of :func:`facet_quotients`, one facet at a time (static
    indices, no gathers: every facet is a few elementwise loops over the poses, and XLA
    schedules the independent facets freely; measured faster than ``(F, 6, ...)`` arrays
    built by gathers). ``tau = t_p - t_mid`` ``(m, ...)``, N; ``h`` the half range, N."""
    r = N.shape[1]
    radii = trailing_axes(wrench_set.radii, nb)
    off = wrench_set.offsets
    L2 = jnp.asarray(length_scale, dtype=jnp.float64) ** 2
    out = []
    for ks in K:
        rows = [N[k] for k in ks]
        if r == 0:
            y = [1.0]
        elif r == 1:
            y = [rows[1][0], -rows[0][0]]
        else:
            a_, b_, c_ = rows
            y = [b_[0] * c_[1] - c_[0] * b_[1], c_[0] * a_[1] - a_[0] * c_[1], a_[0] * b_[1] - b_[0] * a_[1]]
        d = h * sum(jnp.abs(yc) for yc in y)
        a = sum(yc * tau[k] for yc, k in zip(y, ks))
        n = sum(yc * P[k] for yc, k in zip(y, ks))  # (6, ...)
        box = axis_sum(jnp.abs(n) * radii)
        hi, lo = a + box, a - box
        if off.shape[0]:
            e = axis_sum(n[None] * trailing_axes(off, nb), axis=1)  # (V, ...)
            hi, lo = hi - jnp.min(e, axis=0), lo - jnp.max(e, axis=0)
        norm2 = axis_sum(n[:3] ** 2) + L2 * axis_sum(n[3:] ** 2)
        live = sum(yc * yc for yc in y) > _Y_TOL**2
        raw = jnp.minimum(d - hi, d + lo)
        out.append(jnp.where(live, raw * jnp.abs(raw) / jnp.where(live, norm2, 1.0), jnp.inf))
    return jnp.stack(out)


def wrench_feasible(robot, pose: Float[Array, "6 ..."], wrench_set: WrenchSet, *,
                    length_scale: float = 1.0) -> WrenchFeasible:
    """Wrench-feasible membership and capacity margin of ``pose`` (``(6,)`` or ``(6, B)``).

    **Arguments:**

    - ``robot``: a :class:`~cstiffjax.io.robot.CableRobot` with 6 to 8 cables and finite
      ``tension_max``.
    - ``pose``: ``[x, y, z, rx, ry, rz]`` (m, rad) on the leading axis, poses trailing.
    - ``wrench_set``: a :class:`WrenchSet` (N, N·m, about the reference point; the
      platform weight is added here).
    - ``length_scale``: ``L`` (m) of the margin metric ``|f|² + |m/L|²`` (default 1 m).

    **Returns:** :class:`WrenchFeasible` with batch shape ``pose.shape[1:]``. Exact up to
    rounding (tested against a linear program per extreme wrench). Jit it (or call it
    inside :func:`cstiffjax.workspace.sweep.sweep` with ``vectorized=True``).
    """
    check_cables(robot)
    check_limits(robot)
    pose = jnp.asarray(pose, dtype=jnp.float64)
    quotients, singular = facet_quotients(robot, pose, wrench_set, length_scale)
    q = _tree_min(quotients)  # sign(g) g²/|n|² is monotone in g/|n|: one square root per pose
    margin = jnp.where(singular, -jnp.inf, jnp.sign(q) * jnp.sqrt(jnp.abs(q)))
    return WrenchFeasible(~singular & (margin >= 0), margin, singular)


def check_cables(robot) -> None:
    """Raise ``ValueError`` with the reason unless ``robot`` has 6 to 8 cables: with fewer the
    cables span fewer than 6 wrench directions (the platform holds a pose only where its
    weight and the load happen to lie in their span: no box of wrenches is ever held); the
    exact facet enumeration stops at 2 degrees of redundancy."""
    m = robot.num_cables
    if m < 6:
        raise ValueError(f"the wrench-feasible workspace needs at least 6 cables; robot '{robot.name}' has {m}: "
                         f"{m} cables span at most {m} of the 6 wrench directions, so no set of wrenches around the "
                         f"weight is held at any pose (a suspended robot holds only its gravity equilibrium): use the "
                         f"static-equilibrium workspace (cstiffjax workspace --kind static-equilibrium, "
                         f"cstiffjax.workspace.static_equilibrium)")
    facet_cables(m)


def check_limits(robot) -> None:
    """Raise ``ValueError`` when the tension limits are concrete and not finite / ordered."""
    try:
        lo, hi = float(robot.tension_min), float(robot.tension_max)
    except Exception:  # traced: nothing to check here
        return
    if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
        raise ValueError(f"robot '{robot.name}': the wrench-feasible workspace needs finite tension limits "
                         f"tension_min <= tension_max ([limits] in the TOML), got [{lo!r}, {hi!r}] N")
