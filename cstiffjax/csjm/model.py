"""Cable-driven spherical joint module (CSJM) of Yang et al. (IEEE Access 2019).

Kinetostatics and stiffness on SO(3) for one pose at a time (``jax.vmap`` for many);
identification, pose prediction and the symmetry audit are in :mod:`cstiffjax.csjm.identify`.

Geometry and frames
-------------------
``robot`` is a :class:`~cstiffjax.io.robot.SphericalJointModule`: ``anchors`` are the base
holes ``B_i`` (base frame) and ``attachments`` the platform holes ``A_i`` (platform frame),
both relative to the joint centre O (formats.md §1). A pose is a rotation only, given as a
rotation vector ``(3,)`` or a matrix ``(3, 3)``. In the base frame ``a_i = R A_i``, the cable
vector is ``c_i = b_i - a_i = c_i u_i`` and the Jacobian has rows ``a_i × u_i`` (Yang et al. 2019
eq. 38), so the moment of the cables about O is ``m_c = Jᵀ T`` and ``∂c/∂θ = -J`` (eq. 40).

Derivatives are taken, as everywhere in the package, in **base-frame twist coordinates**
``R -> exp(hat(δθ)) R`` (right-invariant fields ``X_a``, ``[X_a, X_b] = -X_{a×b}``). The
raw stiffness is ``K = -∂m/∂θ`` (positive for a stable module), where ``m`` is the
moment of the conservative elements (cables, optionally the platform weight) on the
platform. Seed 000 instead uses the platform frame {A}: ``R -> R exp(hat(δζ))``
(left-invariant basis ``L_i = R σ̂_i``, eq. 5, ``[L_i, L_j] = L_{σ_i×σ_j}``) and, from §III
on, the *applied* load ``τ_A = -Rᵀ m`` that the cables balance (external + gravity, eq. 56),
with ``K_D = ∂τ_A/∂ζ`` (eq. 48a). Differentiating ``τ_A(R e^{δζ})`` gives exactly

    K_D = Rᵀ (K - hat(m)) R    (always),    K_D - K_Dᵀ = hat(τ_A)    (conservative m),

so for a conservative module the paper's raw ``K_D`` is ``Rᵀ Kᵀ R`` of ours. (Its eq. 45
writes ``K = D - JᵀK_diag J`` for the derivative of the *cable* moment ``τ = JᵀT``, i.e.
with the opposite sign; §III then switches to the applied load.)

The connection coefficient (the printed one is wrong)
-----------------------------------------------------
The Levi-Civita connection of the bi-invariant metric has ``∇_X Y = ½[X, Y]`` (eq. 28),
so the covariant stiffness is the raw one minus **one half** of the bracket term. For the
basis of eq. (2), ``[σ̂_i, σ̂_j] = hat(σ_i × σ_j) = ε_ijk σ̂_k``: the structure constants of
eq. (30) are ``γ_12^3 = γ_31^2 = γ_23^1 = +1`` (and -1 for odd permutations), not ±2 as
printed in eq. (31). With γ = ±1, eq. (33) gives ``K_L = -½ hat(τ_A)``; the printed γ = ±2
produce eq. (48b) ``K_L = -hat(τ_A)``, which Table 3 uses (``K_L = -hat(τ_0)`` to print
precision). Structure constants ±2 belong to the doubled basis ``2σ̂_i`` (e.g. unit
quaternion units, ``[i, j] = 2k``), not to eq. (2). The printed coefficient contradicts the
paper's own proof (37): with ``K_D - K_Dᵀ = hat(τ_A)`` (eq. 36) it leaves
``K - Kᵀ = -hat(τ_A) ≠ 0``. In our twist coordinates: ``K - Kᵀ = hat(m)`` and the covariant
stiffness is ``K - ½ hat(m)`` (:func:`cstiffjax.stiffness.matrix.covariant_stiffness`, reused
here); in the paper's frame it is ``K_D - ½ hat(τ_A) = Rᵀ (K - ½ hat(m)) R``. Both are
symmetric for a conservative module under any load; the printed coefficient leaves
``K - Kᵀ = -hat(τ_A)`` (``tests/test_csjm.py`` checks both to 1e-10 relative). With γ = ±1
the paper's proof (35)-(37) goes through unchanged.

Stiffness model (eq. 45)
------------------------
Cable ``s`` has tension ``t_s`` and cable-plus-drive stiffness ``k_s = ∂t_s/∂c_s`` (eq. 43);
with a spring law ``k_s = EA_s/l0_s = (EA_s + t_s)/c_s``. :func:`stiffness` differentiates
``m(θ) = J(θ)ᵀ (T + k ⊙ (c(θ) - c))`` (+ weight) by autodiff and splits
``K = K_geometric + K_elastic + K_gravity`` with ``K_geometric = -∂(JᵀT)/∂θ|_T`` (``-D`` of
eq. 45), ``K_elastic = Jᵀ diag(k) J`` and ``K_gravity = -∂m_g/∂θ``.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from cstiffjax.cable.laws import CABLE_FORCE_LAWS, CableLaw, cable_force, check_law
from cstiffjax.core import lie
from cstiffjax.stiffness.matrix import covariant_stiffness

FRAMES = ("body", "base")


def check_frame(frame: str) -> str:
    """Return ``frame`` if it is ``"body"`` (platform frame {A}, Yang et al. 2019) or ``"base"``."""
    if frame not in FRAMES:
        raise ValueError(f"frame={frame!r} is not allowed; allowed: 'body' (platform frame {{A}}, "
                         f"R -> R exp(δζ), Yang et al. 2019) or 'base' (R -> exp(δθ) R, package convention)")
    return frame


def rotation_matrix(rotation: Float[ArrayLike, "3"] | Float[ArrayLike, "3 3"]) -> Float[Array, "3 3"]:
    """Rotation matrix of a rotation vector ``(3,)`` (rad) or a matrix ``(3, 3)`` (returned as is)."""
    rotation = jnp.asarray(rotation, dtype=jnp.float64)
    if rotation.shape == (3,):
        return lie.exp(rotation)
    if rotation.shape == (3, 3):
        return rotation
    raise ValueError(f"rotation must be a rotation vector of shape (3,) or a rotation matrix of shape (3, 3), "
                     f"got shape {rotation.shape}")


class CableGeometry(eqx.Module):
    """Cable geometry at one pose, base frame: ``attachments`` ``a_i = R A_i`` (m, 3) m,
    ``vectors`` ``c_i = b_i - a_i`` (m, 3) m, ``lengths`` (m,) m, ``directions`` ``u_i`` (m, 3)."""

    attachments: Float[Array, "m 3"]
    vectors: Float[Array, "m 3"]
    lengths: Float[Array, " m"]
    directions: Float[Array, "m 3"]


def _geometry(robot, R) -> CableGeometry:
    a = robot.attachments @ R.T
    c = robot.anchors - a
    length = jnp.linalg.norm(c, axis=-1)
    return CableGeometry(a, c, length, c / length[:, None])


def cable_geometry(robot, rotation) -> CableGeometry:
    """Attachment points, cable vectors, lengths and unit vectors at ``rotation`` (Yang et al. 2019 §II.E)."""
    return _geometry(robot, rotation_matrix(rotation))


def _jacobian(robot, R):
    g = _geometry(robot, R)
    return jnp.cross(g.attachments, g.directions)


def jacobian(robot, rotation) -> Float[Array, "m 3"]:
    """Jacobian ``J`` (m x 3) with rows ``a_i × u_i``, base frame, m (Yang et al. 2019 eq. 38).

    ``m_c = Jᵀ T`` is the cable moment about O and ``∂c/∂θ = -J`` (eq. 40) for the base
    twist ``δθ``; in the paper's platform-frame coordinates ``δζ`` the Jacobian is ``J R``.
    """
    return _jacobian(robot, rotation_matrix(rotation))


def jacobian_autodiff(robot, rotation) -> Float[Array, "m 3"]:
    """``J = -∂c/∂θ`` by autodiff of the cable lengths (check of :func:`jacobian`)."""
    R = rotation_matrix(rotation)
    return -jax.jacfwd(lambda d: _geometry(robot, lie.exp(d) @ R).lengths)(jnp.zeros(3))


def cable_moment(robot, rotation, tensions: Float[ArrayLike, " m"]) -> Float[Array, "3"]:
    """Moment of the cables on the platform about O, ``Jᵀ T``, base frame, N·m (eq. 38)."""
    return _jacobian(robot, rotation_matrix(rotation)).T @ jnp.asarray(tensions, dtype=jnp.float64)


def _gravity_moment(robot, R):
    return jnp.cross(R @ robot.com, robot.platform_mass * robot.gravity)


def gravity_moment(robot, rotation) -> Float[Array, "3"]:
    """Moment of the platform weight about O, ``(R com) × (mass g)``, base frame, N·m."""
    return _gravity_moment(robot, rotation_matrix(rotation))


def elastic_moment(robot, rotation, l0: Float[ArrayLike, " m"], law: CableLaw = CableLaw.spring) -> Float[Array, "3"]:
    """Moment about O of cables of unstrained lengths ``l0`` (m) under ``law``, base frame, N·m.

    Each cable is the one-cable law of :mod:`cstiffjax.cable.laws` between ``B_i`` and ``a_i``
    (:data:`~cstiffjax.cable.laws.CABLE_FORCE_LAWS`; ``spring``: slack cables carry
    nothing). The weight is not included.
    """
    check_law(law, CABLE_FORCE_LAWS, "elastic_moment")
    R = rotation_matrix(rotation)
    a = robot.attachments @ R.T
    f = jax.vmap(lambda b, p, l, ea, w: cable_force(law, b, p, l, ea, w, robot.gravity).on_platform)(
        robot.anchors, a, jnp.asarray(l0, dtype=jnp.float64), robot.EA, robot.mass_per_length)
    return jnp.sum(jnp.cross(a, f), axis=0)


def drive_stiffness(robot, rotation, tensions) -> Float[Array, " m"]:
    """Spring-law cable stiffness ``k = EA/l0 = (EA + t)/c``, N/m (Yang et al. 2019 eq. 43, Cui et al. 2019 eq. 17)."""
    lengths = _geometry(robot, rotation_matrix(rotation)).lengths
    return (robot.EA + jnp.asarray(tensions, dtype=jnp.float64)) / lengths


def conservative_antisymmetry(load: Float[ArrayLike, "3"], frame: str = "body") -> Float[Array, "3"]:
    """``vee(K - Kᵀ)`` that a conservative module must show under the applied ``load``, N·m.

    ``load`` is the moment the elastic elements balance (Yang et al.'s pre-load ``τ_A``:
    external + gravity), in the coordinates of ``frame``. Platform frame (``"body"``,
    eq. 36): ``+load``; base frame (``"base"``): ``m = -load`` (:mod:`cstiffjax.stiffness.matrix`).
    """
    load = jnp.asarray(load, dtype=jnp.float64)
    return load if check_frame(frame) == "body" else -load


def connection_term(load, frame: str = "body", coefficient: float = 0.5) -> Float[Array, "3 3"]:
    """``K_L`` of Yang et al. 2019 eq. (47): ``-coefficient · hat(s)``, ``s`` from :func:`conservative_antisymmetry`.

    ``coefficient = 0.5`` is the Levi-Civita value (structure constants ±1 of eq. 2's basis);
    ``coefficient = 1.0`` reproduces the printed eq. (48b) ``K_L = -hat(τ)`` (γ = ±2), which is
    wrong (see module docstring).
    """
    return -coefficient * lie.hat(conservative_antisymmetry(load, frame))


def covariant(K: Float[ArrayLike, "3 3"], load, frame: str = "body") -> Float[Array, "3 3"]:
    """Covariant (Levi-Civita) stiffness ``K - ½ hat(s)`` of a raw 3x3 stiffness ``K``.

    ``s = conservative_antisymmetry(load, frame)``; computed with
    :func:`cstiffjax.stiffness.matrix.covariant_stiffness` on the rotation block. Symmetric when
    ``K`` comes from a conservative module loaded by ``load``.
    """
    K = jnp.asarray(K, dtype=jnp.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K must have shape (3, 3), got {K.shape}")
    s = conservative_antisymmetry(load, frame)
    return covariant_stiffness(jnp.zeros((6, 6)).at[3:, 3:].set(K), s)[3:, 3:]


class CSJMStiffness(eqx.Module):
    """Stiffness of a CSJM at one pose, base-frame twist coordinates, N·m/rad.

    ``K = K_geometric + K_elastic + K_gravity = -∂m/∂θ``; ``moment`` is ``m`` (cables, plus
    weight when included), base frame, N·m; ``rotation`` the pose matrix.
    """

    K: Float[Array, "3 3"]
    K_geometric: Float[Array, "3 3"]
    K_elastic: Float[Array, "3 3"]
    K_gravity: Float[Array, "3 3"]
    moment: Float[Array, "3"]
    rotation: Float[Array, "3 3"]

    @property
    def load(self) -> Float[Array, "3"]:
        """Applied load balancing ``moment`` (``-m``), base frame, N·m."""
        return -self.moment

    @property
    def covariant(self) -> Float[Array, "3 3"]:
        """Levi-Civita stiffness ``K - ½ hat(m)`` (symmetric: conservative model)."""
        return covariant(self.K, self.load, "base")

    @property
    def body_load(self) -> Float[Array, "3"]:
        """Applied load in the platform frame, ``τ_A = -Rᵀ m`` (Yang et al.'s ``ᴬτ``), N·m."""
        return -self.rotation.T @ self.moment

    @property
    def K_D(self) -> Float[Array, "3 3"]:
        """Seed 000's raw ``K_D = ∂τ_A/∂ζ`` (eq. 48a) = ``Rᵀ (K - hat(m)) R``, platform frame."""
        R = self.rotation
        return R.T @ (self.K - lie.hat(self.moment)) @ R

    @property
    def K_L(self) -> Float[Array, "3 3"]:
        """Correct connection term ``-½ hat(τ_A)`` (printed eq. 48b has ``-hat(τ_A)``)."""
        return connection_term(self.body_load, "body")

    @property
    def covariant_body(self) -> Float[Array, "3 3"]:
        """``K_D + K_L = Rᵀ (K - ½ hat(m)) R``: Yang et al.'s ``K`` (eq. 47) with the right coefficient."""
        return self.K_D + self.K_L


@eqx.filter_jit
def stiffness(robot, rotation, tensions, k=None, *, include_gravity: bool = False) -> CSJMStiffness:
    """Stiffness model of Yang et al. 2019 eq. (45) by autodiff, base-frame twist coordinates.

    **Arguments:**

    - ``robot``: a :class:`~cstiffjax.io.robot.SphericalJointModule`.
    - ``rotation``: pose, rotation vector ``(3,)`` rad or matrix ``(3, 3)``.
    - ``tensions``: ``(m,)`` cable tensions ``T``, N (need not balance anything: the
      result is the stiffness of the elements alone, loaded by ``-moment``).
    - ``k``: ``(m,)`` cable-plus-drive stiffnesses ``k_s = ∂t_s/∂c_s``, N/m; default the
      spring law ``(EA + t)/c`` (:func:`drive_stiffness`).
    - ``include_gravity``: add the platform weight (``K_gravity``, its moment in ``moment``).
      Off by default, as in eq. (45) and in what §III identifies (the weight is part of
      the measured load there).

    **Returns:** a :class:`CSJMStiffness` (``.covariant``, ``.K_D``, ``.K_L``, ``.covariant_body``).
    """
    R = rotation_matrix(rotation)
    T = jnp.asarray(tensions, dtype=jnp.float64)
    k = drive_stiffness(robot, R, T) if k is None else jnp.asarray(k, dtype=jnp.float64)
    zero = jnp.zeros(3)
    c_ref = _geometry(robot, R).lengths

    def geometric(d):  # Jᵀ T with the tensions held fixed
        return _jacobian(robot, lie.exp(d) @ R).T @ T

    def tension_change(d):  # k ⊙ (c(θ) - c), eq. (43)
        return k * (_geometry(robot, lie.exp(d) @ R).lengths - c_ref)

    J = _jacobian(robot, R)
    K_geometric = -jax.jacfwd(geometric)(zero)
    K_elastic = -J.T @ jax.jacfwd(tension_change)(zero)
    if include_gravity:
        K_gravity = -jax.jacfwd(lambda d: _gravity_moment(robot, lie.exp(d) @ R))(zero)
        m = J.T @ T + _gravity_moment(robot, R)
    else:
        K_gravity, m = jnp.zeros((3, 3)), J.T @ T
    return CSJMStiffness(K_geometric + K_elastic + K_gravity, K_geometric, K_elastic, K_gravity, m, R)


def moment_function(robot, rotation, tensions, k=None, *, include_gravity: bool = False):
    """``m(δθ)``: moment of the elements of :func:`stiffness` at ``exp(δθ) R``, base frame, N·m.

    The model behind :func:`stiffness` (``K = -∂m/∂θ`` at 0), for checks and finite steps;
    returned jitted.
    """
    R = rotation_matrix(rotation)
    T = jnp.asarray(tensions, dtype=jnp.float64)
    k = drive_stiffness(robot, R, T) if k is None else jnp.asarray(k, dtype=jnp.float64)
    c_ref = _geometry(robot, R).lengths

    def m(d):
        Rd = lie.exp(d) @ R
        out = _jacobian(robot, Rd).T @ (T + k * (_geometry(robot, Rd).lengths - c_ref))
        return out + _gravity_moment(robot, Rd) if include_gravity else out

    return jax.jit(m)


@eqx.filter_jit
def stiffness_from_lengths(robot, rotation, l0, *, law: CableLaw = CableLaw.spring,
                           include_gravity: bool = False) -> Float[Array, "3 3"]:
    """``K = -∂m/∂θ`` for cables of unstrained lengths ``l0`` (m) under ``law``
    (:data:`~cstiffjax.cable.laws.CABLE_FORCE_LAWS`), base frame, N·m/rad."""
    check_law(law, CABLE_FORCE_LAWS, "stiffness_from_lengths")
    R = rotation_matrix(rotation)

    def m(d):
        Rd = lie.exp(d) @ R
        out = elastic_moment(robot, Rd, l0, law)
        return out + _gravity_moment(robot, Rd) if include_gravity else out

    return -jax.jacfwd(m)(jnp.zeros(3))


def unstrained_lengths(robot, rotation, tensions) -> Float[Array, " m"]:
    """Spring-law ``l0 = c EA/(EA + t)`` that give ``tensions`` (N) at ``rotation``, m."""
    lengths = _geometry(robot, rotation_matrix(rotation)).lengths
    return lengths * robot.EA / (robot.EA + jnp.asarray(tensions, dtype=jnp.float64))
