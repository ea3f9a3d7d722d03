"""Constant stiffness space (CSS) of 2-DOR CDPRs, exactly (Cui et al. 2019 section III).

Seed 004 (``004_b946b1caf1c3d79b.txt``) eq. (24) and the Fig. 7 algorithm: a pose ``x``
belongs to the CSS of a target stiffness ``k_c`` when some tensions in the CTFR give
``K(T) ≈ k_c`` within a relative accuracy ``ε`` (5% in the paper).

Stiffness is affine in the tensions
-----------------------------------
In the twist coordinates of :mod:`cstiffjax.statics.geometry`, one straight cable ``i`` (unit vector
``u`` from attachment to anchor, length ``l``, lever ``r = R b``, ``P = I - u uᵀ``,
``G = [I, -hat(r)]``, ``s = [u; r × u]``) contributes (Cui et al. 2019 eqs 5-19, closed form):

    K1_i = t_i (Gᵀ P G / l - [[0, 0], [0, hat(u) hat(r)]])        (controllable, eq. 6)
    K2_i = (EA_i / l0_i) s sᵀ                                       (inherent, eq. 19)

and gravity adds ``-[[0, 0], [0, hat(f) hat(R c)]]``. For ``K2`` there are two readings
(``inherent=``):

- ``"spring"`` (default): the spring law's unstrained length ``l0 = l EA/(EA + t)``, so
  ``EA/l0 = (EA + t)/l`` -- the exact tangent stiffness, equal to
  :func:`cstiffjax.stiffness.matrix.stiffness`.
- ``"paper"``: ``l0 = l``, the cable length at the pose, i.e. ``EA/l``. This is what seed
  004 used: with it our reconstructed TCPR-8 reproduces eq. (26) to < 0.5%, while
  ``"spring"`` is ~8% stiffer in translation (the 0.47 mm cables stretch ~9% at 200 N).

Either way ``K(T) = K0 + Σ t_i M_i`` is exactly affine in ``T``, hence in the null-space
coordinate ``φ`` (``T = t_p + N φ``); the tests check this by autodiff (zero Hessian).
The ``φ``-dependent part ``Σ (Nφ)_i M_i`` is symmetric (a self-stress has zero net moment,
and ``K - Kᵀ = hat(m)``), so entries ``(i, j)`` and ``(j, i)`` share one direction in φ.

The accuracy criterion
----------------------
Step 5 of Fig. 7 writes ``|k(T(φ)) - k_c| / k_c <= ε`` elementwise. Literally, every zero
entry of ``k_c`` (eq. 26 has 28) becomes an equality constraint, so off the symmetry
planes no pose qualifies and the CSS has zero volume; and the entries mix N/m, N and
N·m/rad. We use (``norm="scaled"``, default) the unit-consistent elementwise bound

    |K_ij(φ) - k_c,ij| <= ε sqrt(|k_c,ii k_c,jj|)   for all i, j,

which is the paper's relative error on the diagonal and bounds the off-diagonal
couplings on the scale of the diagonal (it is ``ε`` in the max-norm of
``D^-½ (K - k_c) D^-½``, ``D = diag(k_c)``). ``norm="paper"`` uses ``ε |k_c,ij|`` (the
literal reading), ``norm="max"`` the matrix max-norm ``max|K - k_c| <= ε max|k_c|`` (a
norm-ratio reading; in SI units it is dominated by the translational entries, so the
rotational stiffness is hardly constrained -- the reproduction in the README shows it).

Exact membership
----------------
Every constraint is a slab ``lo <= a·φ <= hi`` in the plane: 8 from the tension limits
(eq. 21) and 21 from the stiffness entries. Feasibility of a 2-D linear system is decided
exactly by Fourier-Motzkin elimination of ``φ2``: each pair (upper bound of one slab,
lower bound of another) gives one bound ``c φ1 <= d``; the system is feasible iff the
largest lower bound on ``φ1`` is at most the smallest upper bound (and exactly parallel
pairs overlap). Both pairings of two slabs come from one division, so the 29 slabs need
``29·28/2 = 406`` pairs per pose, branch-free (details in
:func:`cstiffjax.stiffness.kernel.feasible_point`); a cheap exact certificate
(:func:`cstiffjax.stiffness.kernel.disc_reject`) settles most poses far from the CSS first.
The chosen tensions are at ``φ1`` = the middle of the feasible ``φ1`` interval and
``φ2`` = the middle of the feasible segment there (an interior point, deterministic).
Robots with ``r < 2`` are padded with a dummy coordinate (``|φ_dummy| <= 1``).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from cstiffjax.core import lie
from cstiffjax.core.status import Status, raise_if_failed, select, solver_errors
from cstiffjax.statics.geometry import frame
from cstiffjax.stiffness import kernel as css_kernel
from cstiffjax.stiffness.tensions import ctfr_from_space, tension_space

INHERENT = ("spring", "paper")  # the allowed values of ``inherent``
NORMS = ("scaled", "max", "paper")  # the allowed values of ``norm``


def check_cables(robot) -> None:
    """Raise ``ValueError`` with the reason when ``robot`` has fewer than 6 cables: the CSS is
    a set of poses where *some* feasible tensions give the target stiffness, and such a robot
    has no tensions to choose (at an equilibrium they are fixed, most poses of a grid are no
    equilibrium at all: the platform hangs where gravity puts it)."""
    m = robot.num_cables
    if m < 6:
        raise ValueError(
            f"the constant stiffness space needs at least 6 cables; robot '{robot.name}' has {m}: with fewer "
            f"cables no tensions are left to choose (they are fixed where the pose is an equilibrium) and most poses "
            f"are no equilibrium at all (the platform hangs where gravity puts it). Its stiffness is that of its "
            f"equilibrium: `cstiffjax stiffness` at an equilibrium pose, or forward statics for given lengths")


def _check(name, value, allowed):
    if value not in allowed:
        raise ValueError(f"{name}={value!r} is not allowed; allowed: {', '.join(map(repr, allowed))}")


class AffineStiffness(eqx.Module):
    """``K(T) = K0 + Σ_i T_i M[i]`` (6x6, twist coordinates); ``K1 = Σ T_i M1[i]`` is the
    controllable part alone (Cui et al. 2019 eq. 6)."""

    K0: Float[Array, "6 6"]
    M: Float[Array, "m 6 6"]
    M1: Float[Array, "m 6 6"]

    def __call__(self, tensions: Float[Array, " m"]) -> Float[Array, "6 6"]:
        return self.K0 + jnp.einsum("i,ijk->jk", tensions, self.M)

    def controllable(self, tensions: Float[Array, " m"]) -> Float[Array, "6 6"]:
        return jnp.einsum("i,ijk->jk", tensions, self.M1)


@eqx.filter_jit
def affine_stiffness(robot, pose, *, inherent: str = "spring") -> AffineStiffness:
    """Closed-form stiffness of straight cables as an affine function of the tensions
    (hand-derived, no pulley term: a reference; the CSS itself takes its stiffness from
    autodiff of the cable path, :func:`cstiffjax.stiffness.kernel.membership_stiffness`).

    **Arguments:** ``robot``, ``pose`` ``[x, y, z, rx, ry, rz]`` (m, rad), ``inherent``:
    ``"spring"`` (``EA/l0 = (EA + t)/l``, exact) or ``"paper"`` (``EA/l``, Cui et al. 2019).

    **Returns:** an :class:`AffineStiffness`; ``K(T)`` in N/m, N, N·m/rad.
    """
    _check("inherent", inherent, INHERENT)
    p, R = frame(pose)
    r = robot.attachments @ R.T
    d = robot.anchors - p - r
    l = jnp.linalg.norm(d, axis=-1)
    u = d / l[:, None]
    hr = jax.vmap(lie.hat)(r)
    hu = jax.vmap(lie.hat)(u)
    G = jnp.concatenate([jnp.broadcast_to(jnp.eye(3), hr.shape), -hr], axis=-1)  # (m, 3, 6)
    P = jnp.eye(3) - u[:, :, None] * u[:, None, :]
    M1 = jnp.einsum("mai,mab,mbj->mij", G, P, G) / l[:, None, None]
    M1 = M1.at[:, 3:, 3:].add(-hu @ hr)
    s = jnp.concatenate([u, jnp.cross(r, u)], axis=-1)
    ss = s[:, :, None] * s[:, None, :] / l[:, None, None]
    M = M1 + ss if inherent == "spring" else M1
    f = robot.weight
    Kg = jnp.zeros((6, 6)).at[3:, 3:].set(-lie.hat(f) @ lie.hat(R @ robot.com))
    K0 = jnp.einsum("m,mij->ij", robot.EA, ss) + Kg
    return AffineStiffness(K0, M, M1)


def stiffness_contractions(robot, pose, V: Float[Array, "m k"], *, inherent: str = "spring"):
    """``K0`` and ``Σ_i V[i, c] M_i`` for each column ``c`` of ``V`` (same as
    :class:`AffineStiffness`, without forming the ``m`` per-cable 6x6 matrices).

    Uses ``Gᵀ P G = Gᵀ G - s sᵀ`` (``Gᵀ u = s``) and ``-hat(r)² = |r|² I - r rᵀ``, so that every
    term is a weighted sum of outer products over the cables
    (:func:`cstiffjax.stiffness.kernel.contractions`, which also takes pose-minor batches).
    Hand-derived, a test reference: the CSS takes the same quantities from autodiff.

    **Returns:** ``(K0 (6, 6), K_lin (k, 6, 6))``.
    """
    _check("inherent", inherent, INHERENT)
    pose = jnp.asarray(pose, dtype=jnp.float64)
    R, r, u, l = css_kernel.geometry(robot, pose, 0)
    return css_kernel.contractions(robot, R, r, u, l, jnp.asarray(V, dtype=jnp.float64), inherent)


def srcc(K1: Float[Array, "6 6"], K: Float[Array, "6 6"]) -> Float[Array, ""]:
    """Stiffness relative contribution coefficient ``ψ = ||K1||_2 / ||K||_2`` (Cui et al. 2019 eq. 22),
    spectral norms (largest singular values)."""
    return jnp.linalg.norm(K1, ord=2) / jnp.linalg.norm(K, ord=2)


class PoseChange(eqx.Module):
    """``delta`` (6,) m / rad with ``K delta = W``; ``result`` ``singular`` when K is."""

    delta: Float[Array, "6"]
    result: Status


@solver_errors
@eqx.filter_jit
def pose_change(K: Float[Array, "6 6"], load: Float[Array, "6"], *, throw: bool = True) -> PoseChange:
    """Small pose change under a load increment ``load`` (N, N·m): ``Δx = K⁻¹ W`` (Cui et al. 2019 eq. 23).

    The paper's ``K⁻ = (KᵀK)⁻¹Kᵀ`` equals ``K⁻¹`` for the square invertible ``K``; we solve
    directly. ``Δx`` is in the twist coordinates (m, rad).
    """
    sv = jnp.linalg.svd(K, compute_uv=False)
    singular = ~(sv[-1] > 1e-12 * sv[0])
    Ks = jnp.where(singular, jnp.eye(6), K)
    delta = jnp.where(singular, 0.0, jnp.linalg.solve(Ks, jnp.asarray(load, dtype=jnp.float64)))
    result = Status.where(singular, Status.singular, Status.successful)
    return raise_if_failed(result, PoseChange(delta, result), throw)


# ------------------------------------------------------------------- target stiffness
class Target(eqx.Module):
    """Target stiffness ``k_c`` (6x6) from the CTFR centroid at a reference pose, with the
    centroid tensions (m,) N, ``ψ`` and the status of the CTFR."""

    K: Float[Array, "6 6"]
    tensions: Float[Array, " m"]
    srcc: Float[Array, ""]
    result: Status


@solver_errors
def target_stiffness(robot, pose, external=None, *, inherent: str = "spring", throw: bool = True) -> Target:
    """``k_c`` = stiffness at ``pose`` with the tensions at the CTFR centroid (Cui et al. 2019 eq. 26).

    The stiffness (and its controllable part ``K1`` for ``ψ``) comes from autodiff along the
    cable path, swivel pulleys included (:func:`cstiffjax.stiffness.kernel.affine_stiffness_sets`).

    **Arguments:** ``robot`` (m = 8), ``pose`` (m, rad), ``external`` (N, N·m) or None,
    ``inherent`` as in :func:`affine_stiffness`.
    """
    _check("inherent", inherent, INHERENT)
    check_cables(robot)
    return _target_stiffness(robot, pose, external, inherent=inherent, throw=throw,
                             layout=css_kernel.pulley_layout(robot))


@eqx.filter_jit
def _target_stiffness(robot, pose, external, *, inherent, throw, layout) -> Target:
    pose = jnp.asarray(pose, dtype=jnp.float64)
    space = tension_space(robot, pose, external)
    region = ctfr_from_space(space, robot.tension_min, robot.tension_max)
    t = region.tensions[:, None]
    K0, K_lin = css_kernel.affine_stiffness_sets(robot, pose, t, inherent, 0, layout)
    K1 = css_kernel.affine_stiffness_sets(robot, pose, t, "paper", 0, layout)[1][0]  # tensions held fixed
    K = K0 + K_lin[0]
    out = Target(K, region.tensions, srcc(K1, K), region.result)
    return raise_if_failed(out.result, out, throw)


# ------------------------------------------------------------------------ membership
class CSSPoint(eqx.Module):
    """CSS membership at one pose: ``member``; ``tensions`` (m,) N chosen inside the CTFR
    with ``K(T) ≈ k_c``; ``phi`` (2,) their null-space coordinates; ``stability`` μ
    (eq. 25a) of those tensions; ``result``: ``successful`` (member), ``infeasible`` (no
    such tensions) or ``singular``."""

    member: Bool[Array, ""]
    tensions: Float[Array, " m"]
    phi: Float[Array, "2"]
    stability: Float[Array, ""]
    result: Status


def tolerance(kc: Float[Array, "6 6"], eps, norm: str = "scaled") -> Float[Array, "6 6"]:
    """Allowed ``|K_ij - k_c,ij|``: ``ε sqrt(|k_ii k_jj|)`` (``"scaled"``), ``ε max|k_c|``
    (``"max"``) or ``ε |k_ij|`` (``"paper"``); see the module docstring."""
    _check("norm", norm, NORMS)
    if norm == "paper":
        return eps * jnp.abs(kc)
    if norm == "max":
        return jnp.full((6, 6), eps * jnp.max(jnp.abs(kc)))
    dg = jnp.sqrt(jnp.abs(jnp.diag(kc)))
    return eps * dg[:, None] * dg[None, :]


def slab_feasible_point(a: Float[Array, "k 2"], lo: Float[Array, " k"], hi: Float[Array, " k"]):
    """Exact feasibility of ``lo <= a φ <= hi`` in the plane (Fourier-Motzkin) and a point.

    **Returns:** ``(feasible, φ)``; ``φ`` is an interior point chosen as described in the
    module docstring (zeros when infeasible). See :func:`cstiffjax.stiffness.kernel.feasible_point`.
    """
    return css_kernel.feasible_point(jnp.asarray(a, dtype=jnp.float64), jnp.asarray(lo, dtype=jnp.float64),
                                     jnp.asarray(hi, dtype=jnp.float64))


def css_point(robot, pose, kc, eps, external=None, *, norm: str = "scaled", inherent: str = "spring") -> CSSPoint:
    """CSS membership of one pose, or of a pose-minor batch (Cui et al. 2019 eq. 24 / Fig. 7 step 5, exact).

    **Arguments:** ``robot`` (6 <= m <= 8), ``pose`` ``(6,)`` ``[x, y, z, rx, ry, rz]``
    (m, rad) *or* ``(6, B)`` (poses as columns: the fast layout, see
    :mod:`cstiffjax.stiffness.kernel`), ``kc`` target stiffness (6x6, e.g.
    :func:`target_stiffness`), ``eps`` relative accuracy (0.05 in the paper), ``external``
    wrench (N, N·m) or None, ``norm`` and ``inherent`` as documented above.

    **Returns:** a :class:`CSSPoint`; for a ``(6, B)`` batch every field gets a trailing
    ``B`` axis (``tensions`` ``(m, B)``). ``jax.vmap`` of the one-pose form works too, and
    :func:`cstiffjax.workspace.sweep.sweep` takes either (``vectorized=True`` for the batch form).
    The cable path (swivel pulleys included) gives both the structure matrix and the
    stiffness, by autodiff (:func:`cstiffjax.stiffness.kernel.membership`).
    """
    _check("norm", norm, NORMS)
    _check("inherent", inherent, INHERENT)
    return _css_point(robot, pose, kc, eps, external, norm=norm, inherent=inherent,
                      layout=css_kernel.pulley_layout(robot))


@eqx.filter_jit
def _css_point(robot, pose, kc, eps, external, *, norm, inherent, layout) -> CSSPoint:
    check_cables(robot)
    r = robot.num_cables - 6
    if not 0 <= r <= 2:
        raise ValueError(f"css_point: exact CSS membership handles 0 to 2 degrees of redundancy; "
                         f"robot has m = {robot.num_cables} cables (r = {r})")
    pose = jnp.asarray(pose, dtype=jnp.float64)
    if pose.ndim not in (1, 2) or pose.shape[0] != 6:
        raise ValueError(f"css_point: pose must have shape (6,) or (6, B), got {pose.shape}")
    kc = jnp.asarray(kc, dtype=jnp.float64)
    ok, t, phi, mu, singular = css_kernel.membership(robot, pose, kc, tolerance(kc, eps, norm), external, inherent,
                                                      layout)
    result = select(singular, Status.singular, select(ok, Status.successful, Status.infeasible))
    return CSSPoint(ok, t, phi, mu, result)


class CSSSummary(eqx.Module):
    """CSS over a grid: ``count`` members, ``volume`` m³ (the members' point volumes added)
    and the global stability ``U`` (eq. 25b: the volume-weighted mean of μ over the CSS;
    NaN-free, 0 if empty)."""

    count: Array
    volume: Float[Array, ""]
    stability: Float[Array, ""]


def summarize(member, stability, point_volume) -> CSSSummary:
    """Volume ``∫dv`` and ``U = ∫μ dv / ∫dv`` (Cui et al. 2019 eq. 25b) as sums over the members.

    **Arguments:** ``member`` (bool) and ``stability`` μ per grid point; ``point_volume``:
    the volume each point stands for, m³, broadcast against ``member``: a grid's
    :meth:`~cstiffjax.workspace.sweep.Grid.point_volumes` (trapezoid weights: half cells on
    the faces of the grid box), or one number for equal weights.

    **Returns:** :class:`CSSSummary`.
    """
    member = jnp.asarray(member)
    w = jnp.where(member, jnp.broadcast_to(jnp.asarray(point_volume, dtype=jnp.float64), member.shape), 0.0)
    v = jnp.sum(w)
    s = jnp.sum(jnp.where(member, w * stability, 0.0))
    return CSSSummary(jnp.sum(member), v, jnp.where(v > 0, s / jnp.where(v > 0, v, 1.0), 0.0))
