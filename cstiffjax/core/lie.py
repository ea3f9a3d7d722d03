"""SO(3) helpers: hat, vee, exp, log, distances and validation.

Conventions
-----------
A rotation vector ``v`` (axis times angle, rad) maps to ``R = exp(hat(v))``.
Perturbations of a rotation are taken on the *left*, in the base (spatial) frame:
``R(δθ) = exp(hat(δθ)) @ R``. This is the convention of every derivative in the
package (see :mod:`cstiffjax.statics.geometry`).

``exp`` and ``log`` are exact (Rodrigues), use Taylor series near angle 0 so that
values *and* gradients are finite there, and ``log`` is accurate near angle pi
(it extracts the axis from the symmetric part instead of dividing by sin θ).
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from cstiffjax.core import config as _config  # noqa: F401  (enables float64)

_SMALL = 1e-4  # below this angle the Taylor branches are used (errors ~ θ^6 < 1e-24)


def hat(v: Float[ArrayLike, "3"]) -> Float[Array, "3 3"]:
    """Skew-symmetric matrix with ``hat(v) @ w == cross(v, w)``."""
    v = jnp.asarray(v)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack(
        [jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2
    )


def vee(M: Float[ArrayLike, "3 3"]) -> Float[Array, "3"]:
    """Inverse of :func:`hat` applied to the skew part of ``M``: ``vee(hat(v)) == v``."""
    M = jnp.asarray(M)
    return 0.5 * jnp.stack(
        [M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]],
        -1,
    )


def _safe_norm(v):
    """Norm with a finite (zero) gradient at v = 0."""
    sq = jnp.sum(v * v, axis=-1)
    small = sq < _SMALL**2
    return jnp.where(small, 0.0, jnp.sqrt(jnp.where(small, 1.0, sq))), sq, small


def exp(v: Float[ArrayLike, "3"]) -> Float[Array, "3 3"]:
    """Rotation matrix ``exp(hat(v))`` (Rodrigues), exact, smooth at ``v = 0``.

    **Arguments:** ``v``: rotation vector, rad.

    **Returns:** the 3x3 rotation matrix.
    """
    v = jnp.asarray(v)
    th, sq, small = _safe_norm(v)
    th_s = jnp.where(small, 1.0, th)
    a = jnp.where(small, 1.0 - sq / 6.0 + sq * sq / 120.0, jnp.sin(th_s) / th_s)
    b = jnp.where(small, 0.5 - sq / 24.0 + sq * sq / 720.0, (1.0 - jnp.cos(th_s)) / th_s**2)
    K = hat(v)
    eye = jnp.eye(3, dtype=K.dtype)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def log(R: Float[ArrayLike, "3 3"]) -> Float[Array, "3"]:
    """Rotation vector ``v`` with ``exp(v) == R`` and ``|v| <= pi``.

    Accurate over the whole group: near angle 0 a Taylor series keeps the gradient
    finite; near pi the axis comes from the symmetric part ``(R + Rᵀ)/2 - cos θ I``,
    whose sign is fixed by the (small but exact) skew part.

    **Arguments:** ``R``: a rotation matrix.

    **Returns:** the rotation vector, rad.
    """
    R = jnp.asarray(R)
    tr = jnp.trace(R, axis1=-2, axis2=-1)
    cos = jnp.clip(0.5 * (tr - 1.0), -1.0, 1.0)
    w = vee(R)  # = sin(θ) * axis
    sq_w = jnp.sum(w * w, axis=-1)
    sin = jnp.where(sq_w > 0, jnp.sqrt(jnp.where(sq_w > 0, sq_w, 1.0)), 0.0)
    th = jnp.arctan2(sin, cos)
    # generic and small-angle branch: v = θ / sin θ * w
    small = th < _SMALL
    sq = th * th
    th_s = jnp.where(small, 1.0, th)
    sin_s = jnp.where(small, 1.0, jnp.sin(th_s))
    f = jnp.where(small, 1.0 + sq / 6.0 + 7.0 * sq * sq / 360.0, th_s / sin_s)
    v_generic = f[..., None] * w
    # near pi: axis from B = (R + Rᵀ)/2 - cos θ I = (1 - cos θ) a aᵀ
    near_pi = cos < -0.9
    B = 0.5 * (R + jnp.swapaxes(R, -1, -2)) - cos[..., None, None] * jnp.eye(3, dtype=R.dtype)
    # outside the branch, feed it a harmless matrix so that its gradient stays finite
    B = jnp.where(near_pi[..., None, None], B, jnp.diag(jnp.array([2.0, 0.0, 0.0])))
    one_m_cos = jnp.where(near_pi, 1.0 - cos, 1.0)
    diag = jnp.diagonal(B, axis1=-2, axis2=-1)
    onehot = jnp.eye(3, dtype=R.dtype)[jnp.argmax(diag, axis=-1)]
    col = jnp.einsum("...ij,...j->...i", B, onehot)
    colk = jnp.sum(col * onehot, axis=-1)
    axis = col / jnp.sqrt(jnp.clip(colk * one_m_cos, 1e-300))[..., None]
    sign = jnp.where(jnp.sum(axis * w, axis=-1) < 0, -1.0, 1.0)
    v_pi = (sign * th)[..., None] * axis
    return jnp.where(near_pi[..., None], v_pi, v_generic)


def rotation_distance(R1: Float[ArrayLike, "3 3"], R2: Float[ArrayLike, "3 3"]) -> Float[Array, ""]:
    """Geodesic distance ``‖log(R1ᵀ R2)‖`` in rad (Yang et al. 2019 eq. 63)."""
    R1 = jnp.asarray(R1)
    return jnp.linalg.norm(log(jnp.swapaxes(R1, -1, -2) @ R2), axis=-1)


def as_rotation(M: ArrayLike, atol: float = 1e-6) -> np.ndarray:
    """Return ``M`` as a float64 array if it is a rotation matrix, else raise.

    **Raises:** ``ValueError`` naming the orthogonality error ``max|MᵀM - I|`` and the
    determinant when ``M`` is not 3x3, not orthogonal to ``atol`` or has det != +1.
    """
    M = np.asarray(M, dtype=np.float64)
    if M.shape != (3, 3):
        raise ValueError(f"a rotation matrix must have shape (3, 3), got {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"rotation matrix contains NaN or inf:\n{M}")
    orth = float(np.max(np.abs(M.T @ M - np.eye(3))))
    det = float(np.linalg.det(M))
    if orth > atol or abs(det - 1.0) > atol:
        raise ValueError(
            f"not a rotation matrix: orthogonality error max|MᵀM - I| = {orth:.3e}, "
            f"det = {det:.9f}; allowed: error <= {atol:g} and det = +1 within {atol:g}"
        )
    return M


def left_jacobian_inverse(v: Float[ArrayLike, "3"]) -> Float[Array, "3 3"]:
    """Inverse left Jacobian of SO(3): maps a spatial twist ``δθ`` (``exp(δθ)R``)
    to the change of the rotation vector ``v`` of ``R``: ``δv = J_l⁻¹(v) δθ``."""
    v = jnp.asarray(v)
    th, sq, small = _safe_norm(v)
    th_s = jnp.where(small, 1.0, th)
    c = jnp.where(
        small,
        1.0 / 12.0 + sq / 720.0,
        (1.0 - th_s * jnp.sin(th_s) / (2.0 * (1.0 - jnp.cos(th_s)))) / th_s**2,
    )
    K = hat(v)
    return jnp.eye(3, dtype=K.dtype) - 0.5 * K + c[..., None, None] * (K @ K)


def left_jacobian(v: Float[ArrayLike, "3"]) -> Float[Array, "3 3"]:
    """Left Jacobian of SO(3): ``exp(v + δv) ≈ exp(J_l(v) δv) exp(v)``."""
    v = jnp.asarray(v)
    th, sq, small = _safe_norm(v)
    th_s = jnp.where(small, 1.0, th)
    b = jnp.where(small, 0.5 - sq / 24.0, (1.0 - jnp.cos(th_s)) / th_s**2)
    c = jnp.where(small, 1.0 / 6.0 - sq / 120.0, (th_s - jnp.sin(th_s)) / th_s**3)
    K = hat(v)
    return jnp.eye(3, dtype=K.dtype) + b[..., None, None] * K + c[..., None, None] * (K @ K)
