"""Static-equilibrium workspace of a suspended robot (fewer than 6 cables), one pose at a time.

With ``m < 6`` cables the structure matrix ``S`` (6 x m) spans at most ``m`` wrench
directions: a pose is held only where the weight and the load happen to lie in that span.
A pose belongs to the *static-equilibrium workspace* for a set of external wrenches
(N, N·m about the platform reference point, base frame, weight excluded) when, for every
wrench ``w`` of the set, tensions ``t`` in ``[tension_min, tension_max]^m`` balance it:
``S t + W_g + w = 0``. ``tension_max`` may be ``+inf`` (a description with no upper limit,
the default): then every cable need only be taut, ``t >= tension_min``.
For a fixed pose this is a linear feasibility problem in ``t``
whose solution set for ``b = -(W_g + w)`` is convex in ``b``, so the set's extreme points
(:meth:`~cstiffjax.workspace.wrench_feasible.WrenchSet.extreme_points`; a box's vertices)
decide it.

Two meanings of the pose's rotation (``orientation``):

- ``"given"``: the rotation is imposed; only the force and moment balance at that pose is
  tested. A platform whose cables do not meet at one point has few such poses at a fixed
  rotation (for 3 cables isolated positions, for 4 curves, for 5 surfaces): the volume of a
  grid at one rotation is then zero but for a point-mass platform (every attachment and
  the centre of mass at one point, where the moment balance holds by itself).
- ``"free"`` (the cables decide the rotation, as they do with ``m < 6``): for each wrench,
  the rotation at which the platform hangs in equilibrium at the given position, reached
  by :func:`equilibrium_rotation` from the pose's rotation (the start; default 0, upright).
  With 3 cables that equilibrium is isolated; with 4 or 5 the equilibrium rotations at a
  position form a family (1- or 2-dimensional; the lengths select one) and the
  minimum-norm steps end on it close to the start. A member must also be *stable* there:
  the stiffness of spring cables at those tensions, the weight's term included, positive
  definite (:func:`cstiffjax.statics.suspended.is_stable`), as where the platform settles
  (forward statics with the unstrained lengths of those tensions returns the same pose).
  For a wrench set each extreme wrench gets its own rotation, sought from the centre's
  (the rotation follows the load), and the check is exact at those wrenches.

**Tensions of one equilibrium** (:func:`tension_margin`): ``S t = b`` has the solutions
``t = t_p + N φ`` (``t_p`` the least-squares tensions, ``N`` the null space, empty when
``S`` has rank ``m``). The *tension margin* ``s* = max {s : tmin + s <= t <= tmax - s}``
over those solutions (N) is a linear program in ``(φ, s)``; its optimum is a vertex where
some cables sit at a limit, so every assignment of each cable to {lower limit, upper limit,
free} (``3^m - 1`` of them, 242 for 5 cables) is solved as a small least-squares system
and the best feasible one kept (plus ``t = (tmin + tmax)/2``, the one vertex with a cable at
both limits). With no upper limit the margin is ``max min_i (t_i - tmin)``, the distance to
the lower limit alone; it is bounded unless the null space holds an *internal force* ``d > 0``
pulling every cable (then every tension rises without bound along ``d``: the margin is
``+inf``). That case is itself a small LP (``max min_i d_i`` over null vectors with
``sum d = 1``), solved by the same enumeration; it needs a rank-deficient ``S``, as a
point-mass platform's, and cables that can pull against each other (never for a platform
hanging below all its anchors, where every cable pulls up).
The pose is held iff ``b`` lies in the span (``|S t_p - b| <= 1e-6 (|W| + 1)``,
:data:`cstiffjax.statics.geometry.BALANCE_TOL`, the tolerance of
:func:`~cstiffjax.statics.geometry.inverse_statics`) and ``s* >= 0``.

Written for one pose and batched with ``jax.vmap`` (``sweep(..., vectorized=False)``).
"""

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
from jaxtyping import Array, Bool, Float

from cstiffjax.core.arrays import batched_like
from cstiffjax.core.status import Status, select
from cstiffjax.statics.forward import wrench_scale
from cstiffjax.statics.geometry import apply_twist, balanced, gravity_wrench, structure_matrix
from cstiffjax.statics.suspended import FULL, is_stable, platform_size
from cstiffjax.stiffness.matrix import stiffness_from_lengths, unstrained_lengths
from cstiffjax.workspace.wrench_feasible import WrenchSet

ORIENTATIONS = ("free", "given")
RANK_TOL = 1e-9  # singular values of S below this times the largest: a null direction
ROTATION_STEPS = 60  # most Gauss-Newton steps of equilibrium_rotation
MAX_TURN = 0.3  # rad: the longest rotation step
_REG = 1e-12  # ridge of the vertex systems' normal equations (entries O(1)), removed by refinement
_TENSION_TOL = 1e-9  # relative to |tmin| + |tmax| + 1: a vertex's equations and limits hold


class StaticEquilibrium(eqx.Module):
    """Result for one pose (a batch under ``vmap``).

    - ``member``: every wrench of the set is held in equilibrium with tensions within the
      limits (with ``orientation="free"``: at a stable equilibrium rotation).
    - ``margin``: the smallest tension margin over the set's extreme wrenches, N: the most
      every tension can stay away from both limits (``>= 0`` within the limits, ``< 0``
      by how much the limits must widen); with no upper limit (``tension_max = inf``) the
      distance above ``tension_min`` alone, ``+inf`` where an internal force can raise
      every tension without bound; ``-inf`` where some wrench has no equilibrium.
    - ``residual``: the largest unbalanced wrench ``|S t + W|`` of the least-squares tensions
      (Euclidean norm of N and N·m, limits ignored); zero at an equilibrium.
    - ``stable``: each equilibrium is stable (spring cables; false where none is found).
    - ``solved``: with ``"free"``, an equilibrium rotation was found for every wrench
      (with ``"given"``: the pose is an equilibrium for every wrench).
    - ``rotation``: the rotation vector (rad) of the equilibrium under the set's centre
      (``"free"``) or the given one.
    """

    member: Bool[Array, "*batch"]
    margin: Float[Array, "*batch"]
    residual: Float[Array, "*batch"]
    stable: Bool[Array, "*batch"]
    solved: Bool[Array, "*batch"]
    rotation: Float[Array, "*batch 3"]

    @property
    def result(self) -> Status:
        """``not_converged`` (no equilibrium), ``unstable``, ``infeasible`` or ``successful``."""
        return select(~self.solved, Status.not_converged,
                      select(self.member, Status.successful,
                             select(self.stable | (self.margin < 0), Status.infeasible, Status.unstable)))


def limit_assignments(m: int) -> np.ndarray:
    """Static ``(3^m - 1, m)`` signs: each cable at its lower limit (-1), upper limit (+1) or
    free (0), at least one at a limit."""
    return np.array([s for s in itertools.product((-1.0, 0.0, 1.0), repeat=m) if any(s)])


def _inv_kept(sv, keep):
    """``1 / sv`` where ``keep``, else 0 (a pseudo-inverse's singular values; no division by a dropped one)."""
    return jnp.where(keep, 1.0 / jnp.where(keep, sv, 1.0), 0.0)


def tension_margin(S: Float[Array, "6 m"], b: Float[Array, "6"], t_min, t_max):
    """The tension margin of ``S t = b`` within ``[t_min, t_max]`` (exact LP by enumeration).

    **Arguments:** ``S`` (6 x m, m <= 5 for speed: ``3^m`` small systems), ``b`` (6,) N and
    N·m; ``t_min``: a finite lower limit, N; ``t_max``: the upper limit, N, finite or ``+inf``
    (no upper limit: the margin is the distance to the lower limit alone).

    **Returns:** ``(margin, residual, t)``: ``margin = max_t min_i min(t_i - t_min, t_max - t_i)``
    over the exact solutions of ``S t = b`` projected on the span (N; ``-inf`` if no vertex is
    found; ``+inf`` when ``t_max`` is infinite and the null space of ``S`` holds an internal
    force pulling every cable, so that every tension can be raised without bound),
    ``residual = |S t_p - b|`` of the least-squares tensions ``t_p`` (N, N·m), ``t`` (m,) the
    tensions of the margin (``t_p`` where ``S`` has rank m; for a ``+inf`` margin ``t_p`` plus
    the least multiple of that internal force that lifts every tension to ``t_min``).
    """
    m = S.shape[1]
    U, sv, Vt = jnp.linalg.svd(S, full_matrices=False)
    keep = sv > RANK_TOL * sv[0]
    tp = Vt.T @ (_inv_kept(sv, keep) * (U.T @ b))
    residual = jnp.linalg.norm(S @ tp - b)
    V = Vt.T
    bounded = jnp.isfinite(t_max)  # an upper limit; without it the upper rows (t_i + s = t_min) are
    hi = jnp.where(bounded, t_max, t_min)  # feasible points of the lower-only LP, never above its optimum
    mid, h = 0.5 * (hi + t_min), 0.5 * (hi - t_min)
    tol = _TENSION_TOL * (jnp.abs(t_min) + jnp.abs(hi) + 1.0)
    ray = not _finite(t_max)  # also the internal-force LP (in the same batch of systems)
    sig, K = _assignments(m, ray), 3 ** m - 1
    tight = jnp.abs(sig)
    rhs = tight * ((mid - tp)[None] + sig * h)
    normal = jnp.where(jnp.arange(len(sig))[:, None] >= K, jnp.sum(V, axis=0) * (~keep), 0.0)
    dt, z_s, ok = _vertices(keep, V, sig, rhs.at[K:].set(0.0), normal, tol)
    t, s, holds = tp[None] + dt[:K], z_s[:K], ok[:K]
    within = jnp.all(t - s[:, None] >= t_min - tol, axis=1) & jnp.all(t + s[:, None] <= t_max + tol, axis=1)
    s = jnp.where(holds & within, s, -jnp.inf)
    centred = bounded & (jnp.max(jnp.abs(jnp.where(keep, V.T @ (mid - tp), 0.0))) <= tol)  # t = mid solves it
    k = jnp.argmax(s)
    best_s = jnp.where(centred, h, s[k])
    best_t = jnp.where(centred, jnp.full(m, mid), jnp.where(jnp.isfinite(s[k]), t[k], tp))
    if not ray:  # a concrete finite upper limit: the margin is bounded
        return best_s, residual, best_t
    # the internal force: max δ = min_i d_i over null vectors d with sum d = 1 (δ > 0: every cable pulled)
    d, lift = dt[K:], z_s[K:]
    lift = jnp.where(ok[K:] & jnp.all(d - lift[:, None] >= -_TENSION_TOL, axis=1), lift, -jnp.inf)
    j = jnp.argmax(lift)
    unbounded = ~bounded & (lift[j] > RANK_TOL)
    d = jnp.where(unbounded, d[j], 1.0)
    raise_by = jnp.maximum(0.0, jnp.max((t_min - tp) / d))
    return (jnp.where(unbounded, jnp.inf, best_s), residual,
            jnp.where(unbounded, tp + raise_by * d, best_t))


def _assignments(m: int, ray: bool):
    """The limit assignments (:func:`limit_assignments`), followed with ``ray`` by those of the
    internal-force LP (each cable at ``d_i = δ`` (-1) or above it (0))."""
    sig = limit_assignments(m)
    return jnp.asarray(np.concatenate([sig, sig[np.all(sig <= 0, axis=1)]]) if ray else sig)


def _finite(x) -> bool:
    """``x`` is concrete and finite (False for a traced value: decided at run time)."""
    try:
        return bool(np.isfinite(float(x)))
    except Exception:  # traced
        return False


def _vertices(keep, V, sig, rhs, normal, tol):
    """The vertex of each assignment in ``z = (φ, s)``: rows ``φ_j = 0`` along the span's
    directions (``keep``), ``V_i φ + sig_i s = rhs_i`` for each tight cable, and
    ``normal_k · φ = 1`` where ``normal_k`` is not zero (the internal-force LP's ``sum d = 1``).

    **Returns:** ``(V φ, s, holds)``: (K, m), (K,) and whether the equations hold within
    ``tol`` with finite values (K,)."""
    K, m = sig.shape
    tight = jnp.abs(sig)
    top = jnp.concatenate([jnp.diag(keep.astype(V.dtype)), jnp.zeros((m, 1))], axis=1)
    bottom = tight[:, :, None] * jnp.concatenate([jnp.broadcast_to(V, (K, m, m)), sig[:, :, None]], axis=2)
    last = jnp.concatenate([normal, jnp.zeros((K, 1))], axis=1)[:, None]
    A = jnp.concatenate([jnp.broadcast_to(top, (K, m, m + 1)), bottom, last], axis=1)
    y = jnp.concatenate([jnp.zeros((K, m)), rhs, jnp.any(normal != 0, axis=1, keepdims=True).astype(V.dtype)], axis=1)
    z = jax.vmap(_least_squares)(A, y)
    holds = (jnp.max(jnp.abs(jnp.einsum("kij,kj->ki", A, z) - y), axis=1) <= tol) & jnp.all(jnp.isfinite(z), axis=1)
    return z[:, :m] @ V.T, z[:, m], holds


def _least_squares(A, y):
    """A least-squares solution of ``A z = y`` (small, entries O(1)): ridge normal equations
    and two refinement steps (exact where ``A`` has full column rank)."""
    M = A.T @ A + _REG * jnp.eye(A.shape[1])
    c = jsl.cho_factor(M)
    z = jsl.cho_solve(c, A.T @ y)
    for _ in range(2):
        z = z + jsl.cho_solve(c, A.T @ (y - A @ z))
    return z


def _unbalanced(robot, pose, t, external):
    return structure_matrix(robot, pose) @ t + gravity_wrench(robot, pose) + external


def _rotated(pose, d):
    return apply_twist(pose, jnp.concatenate([jnp.zeros(3), d]))


def _pinv_apply(A, y, ref):
    """``A⁺ y`` with singular values below ``RANK_TOL ref`` dropped (``ref`` an absolute scale)."""
    U, sv, Vt = jnp.linalg.svd(A, full_matrices=False)
    keep = sv > RANK_TOL * ref
    return Vt.T @ (_inv_kept(sv, keep) * (U.T @ y))


def equilibrium_rotation(robot, pose: Float[Array, "6"], external: Float[Array, "6"]):
    """The equilibrium rotation at ``pose``'s position under ``external`` (N, N·m), reached
    from ``pose``'s rotation by minimum-norm Gauss-Newton steps: each step the smallest
    base-frame rotation (at most :data:`MAX_TURN` rad) that cancels, to first order, the part
    of the unbalanced wrench the cables cannot take (its component in the left null space of
    ``S``, the tensions their least squares). With 3 cables the equilibrium is isolated;
    with 4 or 5 the steps end on the family of equilibrium rotations near the start
    (quadratic convergence, typically 4 to 8 steps). Stops when a step is below 1e-12 rad
    or after :data:`ROTATION_STEPS`.

    **Returns:** ``(pose, residual, steps)``: the pose (6,) with the rotation reached,
    ``|S t + W|`` of its least-squares tensions (N, N·m) and the steps taken."""
    m = robot.num_cables
    scale = wrench_scale(robot, external)

    def step(pose):
        S = structure_matrix(robot, pose)
        U, sv, Vt = jnp.linalg.svd(S, full_matrices=True)
        keep = sv > RANK_TOL * sv[0]
        w = gravity_wrench(robot, pose) + external
        t = -Vt.T @ (_inv_kept(sv, keep) * (U[:, :m].T @ w))
        Q = U * jnp.concatenate([~keep, jnp.ones(6 - m, bool)])[None]  # the left null space
        J = jax.jacfwd(lambda d: _unbalanced(robot, _rotated(pose, d), t, external))(jnp.zeros(3))
        d = -_pinv_apply(Q.T @ J, Q.T @ (S @ t + w), jnp.linalg.norm(J) + scale)
        d = d * jnp.minimum(1.0, MAX_TURN / (jnp.linalg.norm(d) + 1e-300))
        return d, jnp.linalg.norm(S @ t + w)

    def body(c):
        i, pose, _, _ = c
        d, res = step(pose)
        ok = jnp.all(jnp.isfinite(d))
        return i + 1, jnp.where(ok, _rotated(pose, d), pose), res, ~ok | (jnp.max(jnp.abs(d)) <= 1e-12)

    init = (batched_like(jnp.zeros((), jnp.int32), pose), pose, batched_like(jnp.inf, pose),
            batched_like(False, pose))
    i, pose, _, _ = jax.lax.while_loop(lambda c: (c[0] < ROTATION_STEPS) & ~c[3], body, init)
    return pose, step(pose)[1], i


def _one_wrench(robot, pose, w, free):
    """``(margin, residual, stable, solved, pose)`` for one external wrench ``w`` (6,)."""
    if free:
        pose, _, _ = equilibrium_rotation(robot, pose, w)
    S = structure_matrix(robot, pose)
    W = gravity_wrench(robot, pose) + w
    margin, residual, t = tension_margin(S, -W, robot.tension_min, robot.tension_max)
    solved = balanced(residual, jnp.linalg.norm(W))
    K = stiffness_from_lengths(robot, pose, unstrained_lengths(robot, pose, t))
    stable = solved & is_stable(K, platform_size(robot), wrench_scale(robot, w))
    return jnp.where(solved, margin, -jnp.inf), residual, stable, solved, pose


def static_equilibrium(robot, pose: Float[Array, "6"], wrench_set: WrenchSet | None = None, *,
                       orientation: str = "free") -> StaticEquilibrium:
    """Static-equilibrium membership and tension margin of one ``pose`` of a robot with
    fewer than 6 cables (module docstring).

    **Arguments:**

    - ``robot``: a :class:`~cstiffjax.io.robot.CableRobot` with 1 to 5 cables (3 to 5 for
      ``"free"``), a finite ``tension_min`` and ``tension_max >= tension_min`` (``+inf``:
      no upper limit).
    - ``pose``: ``[x, y, z, rx, ry, rz]`` (m, rad): the position, and the rotation
      (``"given"``) or the reference the equilibrium rotation is sought from (``"free"``).
    - ``wrench_set``: a concrete :class:`~cstiffjax.workspace.wrench_feasible.WrenchSet`
      (N, N·m, weight excluded); default: no external wrench (the weight alone).
    - ``orientation``: ``"free"`` or ``"given"``.

    **Returns:** :class:`StaticEquilibrium`. ``jax.vmap`` it for a batch (or
    :func:`~cstiffjax.workspace.sweep.sweep` with ``vectorized=False``).
    """
    check_robot(robot, orientation)
    pose = jnp.asarray(pose, dtype=jnp.float64)
    if wrench_set is None:
        centre, extremes = np.zeros(6), np.zeros((1, 6))
    else:
        centre, extremes = np.asarray(wrench_set.center), wrench_set.extreme_points()
    free = orientation == "free"
    m0, r0, st0, ok0, pose0 = _one_wrench(robot, pose, jnp.asarray(centre), free)
    if len(extremes) == 1 and np.array_equal(extremes[0], centre):
        margin, residual, stable, solved = m0, r0, st0, ok0
    else:  # every extreme wrench, its rotation sought from the centre's equilibrium
        ms, rs, sts, oks, _ = jax.vmap(lambda w: _one_wrench(robot, pose0, w, free))(jnp.asarray(extremes))
        margin, residual, stable, solved = jnp.min(ms), jnp.max(rs), jnp.all(sts), jnp.all(oks)
    member = solved & (margin >= 0) & (stable | (not free))
    return StaticEquilibrium(member, margin, residual, stable, solved, pose0[3:])


def check_robot(robot, orientation: str = "free") -> None:
    """Raise ``ValueError`` with the reason unless ``robot`` can have a static-equilibrium
    workspace here: fewer than 6 cables (with 6 or more the wrench-feasible workspace with a
    one-point wrench set is the same thing, exactly), at least 3 for ``"free"``, a finite
    ``tension_min`` and ``tension_max >= tension_min`` (``+inf`` allowed: no upper limit),
    and ``orientation`` one of :data:`ORIENTATIONS`."""
    if orientation not in ORIENTATIONS:
        raise ValueError(f"orientation {orientation!r}: expected one of {', '.join(ORIENTATIONS)}")
    m = robot.num_cables
    if m >= FULL:
        raise ValueError(f"the static-equilibrium workspace is for robots with fewer than {FULL} cables; robot "
                         f"'{robot.name}' has {m}: use the wrench-feasible workspace (its default one-point wrench "
                         f"set is the static equilibrium under the weight)")
    if orientation == "free" and m < 3:
        raise ValueError(f"orientation 'free' needs at least 3 cables; robot '{robot.name}' has {m}: with fewer the "
                         f"equilibrium positions form a surface or a curve (no volume); use orientation 'given'")
    try:
        lo, hi = float(robot.tension_min), float(robot.tension_max)
    except Exception:  # traced: nothing to check here
        return
    if not (np.isfinite(lo) and lo <= hi):  # hi = inf: no upper limit
        raise ValueError(f"robot '{robot.name}': the static-equilibrium workspace needs a finite tension_min <= "
                         f"tension_max (tension_max may be inf: no upper limit; [limits] in the TOML), got "
                         f"[{lo!r}, {hi!r}] N")
