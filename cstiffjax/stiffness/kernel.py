"""CSS membership written once for one pose *or* a pose-minor batch (Cui et al. 2019, exact).

Every function here takes arrays whose small axes (cables, wrench components, slabs)
come first and whose *trailing* axes ``...`` are a batch of poses: a pose is ``(6,)``
(batch ``()``) or ``(6, B)``. For one pose this is the ordinary per-pose physics of
:func:`cstiffjax.stiffness.css.css_point` (which calls it with batch ``()``, and which
``jax.vmap`` batches as usual). For ``B`` poses the same code keeps the poses on the
minor, contiguous axis, so every operation -- the 6 Householder reflections, the
stiffness's forward-mode tangents, the 406 Fourier-Motzkin slab pairs -- is one elementwise loop
over the poses that XLA vectorizes with SIMD; ``vmap`` of the per-pose function puts the
poses on the major axis instead, where the small axes (2, 3, 6, 8) defeat vectorization.
Sums over those small axes are written out term by term (:func:`_sum`) for the same
reason. Measured with ``benchmarks/bench_css.py`` on the 2-core CPU (see README for the
numbers and the load they were taken under).

The cable path is that of the rest of the toolkit (:func:`frame_paths`: straight, or over
swivel pulleys with the one-cable code :func:`cstiffjax.cable.path.pulley_span`, formats.md §1
v2), and every stiffness here -- :func:`cstiffjax.stiffness.matrix.stiffness` and the CSS's ``K0``,
``K_lin`` -- is autodiff of the wrench along it (:func:`stiffness_sets`); the hand-derived
:func:`contractions` are only the test reference (:func:`membership`). Which path is taken
(straight, pulleys, mixed) is static (:func:`pulley_layout`), so a robot without pulleys runs the
straight-cable code it ran before pulleys.

The maths (null space, closed-form affine stiffness, slabs, Fourier-Motzkin) is
documented in :mod:`cstiffjax.stiffness.css`. :func:`null_space` also serves
:func:`cstiffjax.stiffness.tensions.tension_space`; ``tests/test_css.py`` and
``tests/test_pulley_stiffness.py`` check the kernel against numpy's pinv/SVD,
:func:`cstiffjax.core.lie.exp`, the per-cable :func:`cstiffjax.stiffness.css.affine_stiffness`, the
statics' wrench (finite differences, pulleys) and an LP.
"""

import jax
import jax.numpy as jnp
import numpy as np

from cstiffjax.cable.path import pulley_span

RANK_TOL = 1e-9  # a pivot below this fraction of the largest one: the 6 wrench rows are dependent
_IU = np.triu_indices(6)  # the 21 upper-triangle entries of a 6x6 matrix


def trailing_axes(x, nb):
    """``x`` with ``nb`` trailing singleton axes (to broadcast robot data over a batch)."""
    return jnp.reshape(x, x.shape + (1,) * nb)


def axis_sum(x, axis=0):
    """Sum over a small axis written out term by term: XLA's CPU reduction over a major
    axis of a broadcast product does not vectorize over the trailing poses (measured 7x
    slower); an explicit sum is one elementwise loop."""
    x = jnp.moveaxis(x, axis, 0)
    out = x[0]
    for k in range(1, x.shape[0]):
        out = out + x[k]
    return out


def _cross(a, b):
    """Cross product on axis 1 of ``(m, 3, ...)`` arrays."""
    return jnp.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                      a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def rotation(rv):
    """Rodrigues ``exp(hat(rv))`` for ``rv`` ``(3, ...)`` -> ``(3, 3, ...)`` (as :func:`cstiffjax.core.lie.exp`)."""
    sq = rv[0] ** 2 + rv[1] ** 2 + rv[2] ** 2
    small = sq < 1e-6
    th = jnp.sqrt(jnp.where(small, 1.0, sq))
    a = jnp.where(small, 1.0 - sq / 6.0 + sq * sq / 120.0, jnp.sin(th) / th)
    b = jnp.where(small, 0.5 - sq / 24.0 + sq * sq / 720.0, (1.0 - jnp.cos(th)) / (th * th))
    x, y, z = rv[0], rv[1], rv[2]
    c = 1.0 - b * sq
    return jnp.stack([jnp.stack([c + b * x * x, b * x * y - a * z, b * x * z + a * y]),
                      jnp.stack([b * x * y + a * z, c + b * y * y, b * y * z - a * x]),
                      jnp.stack([b * x * z - a * y, b * y * z + a * x, c + b * z * z])])


def pulley_layout(robot) -> str:
    """Which cable path :func:`frame_paths` takes, decided at trace time: ``"none"`` when
    every swivel axis is known to be zero (the straight-cable formulas, bit for bit those
    before pulleys), ``"all"`` when every cable is known to run over a pulley, ``"some"``
    otherwise -- a mix, or a robot whose arrays are traced (then each cable picks its
    branch with ``jnp.where``, as :func:`cstiffjax.cable.path.cable_path` does). Entry points
    that ``jit`` the robot (:func:`cstiffjax.stiffness.matrix.stiffness`,
    :func:`cstiffjax.stiffness.css.css_point`) call this before tracing and pass the answer down."""
    try:
        has = np.any(np.asarray(robot.pulley_axis) != 0, axis=1)
    except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
        return "some"
    return "all" if has.all() else "some" if has.any() else "none"


def frame_paths(robot, p, R, nb, layout=None):
    """``(r (m,3,...), u (m,3,...), l (m,...), free (m,...))`` at the frame ``p (3, ...)``,
    ``R (3, 3, ...)``: lever arms ``R b``, unit vectors from the attachment P towards the
    anchor (over a swivel pulley: towards the tangent point T), path lengths (``r·β + |P - T|``
    over a pulley) and free spans ``|P - T|`` (formats.md §1 v2; the geometry of
    :func:`cstiffjax.cable.path.pulley_span`, the one-cable path's own code). ``layout`` as
    :func:`pulley_layout` (None: decide from ``robot`` now)."""
    r = lever_arms(robot, R, nb)
    return (r, *lever_paths(robot, p, r, nb, layout))


def lever_arms(robot, R, nb):
    """Lever arms ``r_i = R b_i`` (m) ``(m, 3, ...)`` of the attachments for ``R (3, 3, ...)``."""
    att = trailing_axes(robot.attachments, nb)  # (m, 3, 1...)
    return jnp.stack([sum(R[a, k][None] * att[:, k] for k in range(3)) for a in range(3)], axis=1)


def lever_paths(robot, p, r, nb, layout=None):
    """``(u, l, free)`` of :func:`frame_paths` from the position ``p (3, ...)`` (m) and the
    lever arms ``r (m, 3, ...)`` (m) directly (the autodiff stiffness perturbs ``r``)."""
    layout = pulley_layout(robot) if layout is None else layout
    anchors = trailing_axes(robot.anchors, nb)
    d = anchors - p[None] - r
    if layout != "all":
        l_s = jnp.sqrt(axis_sum(d * d, axis=1))
        u_s = d / l_s[:, None]
        if layout == "none":
            return u_s, l_s, l_s
    P = p[None] + r
    axis = trailing_axes(robot.pulley_axis, nb)
    l_p, free, _, dirn, *_ = pulley_span([anchors[:, k] for k in range(3)], [P[:, k] for k in range(3)],
                                          trailing_axes(robot.pulley_radius, nb), [axis[:, k] for k in range(3)])
    u_p = jnp.stack(dirn, axis=1)
    if layout == "all":
        return u_p, l_p, free
    has = axis_sum(axis * axis, axis=1) > 0  # (m, 1...)
    return jnp.where(has[:, None], u_p, u_s), jnp.where(has, l_p, l_s), jnp.where(has, free, l_s)


def frame_geometry(robot, p, R, nb, layout=None):
    """``(r, u, l)`` of :func:`frame_paths`."""
    return frame_paths(robot, p, R, nb, layout)[:3]


def geometry(robot, pose, nb, layout=None):
    """``(R (3,3,...), r (m,3,...), u (m,3,...), l (m,...))`` at ``pose`` (see :func:`frame_paths`)."""
    R = rotation(pose[3:])
    return (R, *frame_geometry(robot, pose[:3], R, nb, layout))


def stiffness_sets(robot, pose, tension_sets, gravity, nb, layout=None):
    """``-∂W_c/∂δ`` ``(k, 6, 6, ...)`` by forward-mode autodiff (one ``jax.jvp`` per twist
    direction, at the pose's own geometry).

    ``W_c(δ) = Σ_i t_ci(l(δ)) [u_i; r_i × u_i] (+ the weight's wrench where ``gravity[c]``)``
    at the base-frame twist ``δ = [δp, δθ]`` from ``pose`` ``(6, ...)`` (Cui et al. 2019 eqs 3-5:
    ``K = -∂W/∂x``), ``l`` and ``u`` along the cable path of :func:`lever_paths` (straight or
    over swivel pulleys; the pulley's geometric stiffness comes from the same autodiff);
    ``tension_sets(l, l_ref) -> (k, m, ...)`` gives the cable tensions of every set as a
    function of the cable lengths ``l`` (``l_ref`` the lengths at ``pose``).

    The twist moves the platform point ``p`` to ``p + δp`` and every body-fixed arm ``a``
    (the lever arms ``r_i = R b_i`` and ``R c``) to ``a + δθ × a``: the same first-order
    motion as ``exp(hat(δθ)) R`` (equal derivative at ``δ = 0``, so the same ``K``), without
    differentiating the rotation matrix (measured 1.5x faster, ``bench_stiffness.py``).
    """
    layout = pulley_layout(robot) if layout is None else layout
    p0, R0 = pose[:3], rotation(pose[3:])
    r0 = lever_arms(robot, R0, nb)
    c = trailing_axes(robot.com, nb)
    rc0 = jnp.stack([sum(R0[a, k] * c[k] for k in range(3)) for a in range(3)])  # (3, ...)
    l_ref = lever_paths(robot, p0, r0, nb, layout)[1]
    grav = trailing_axes(jnp.asarray(gravity, dtype=jnp.float64), nb + 1)
    weight = trailing_axes(robot.weight, nb)

    def wrench(p, r, rc):
        u, l, _ = lever_paths(robot, p, r, nb, layout)
        # Σ_i t_ci s_i with the structure rows s_i = [u_i; r_i × u_i] formed once for every
        # set: their tangents are shared by the sets (t (r × u), not r × (t u), per set)
        s = structure_rows(r, u)  # (m, 6, ...), for all sets
        t = tension_sets(l, l_ref)  # (k, m, ...)
        w = axis_sum(t[:, :, None] * s[None], axis=1)  # (k, 6, ...)
        mg = _cross(rc[None], weight[None])[0]
        return w + grav * jnp.concatenate([jnp.broadcast_to(weight, mg.shape), mg])[None]

    # one jvp per direction at the pose's own p, r_i, R c: the primal is the caller's
    # geometry, which XLA computes once for the caller and the 6 jvps (differentiating at a
    # zero twist recomputed it: the CSS membership 1.3x slower); δp moves p
    # (the arms' tangents are symbolic zeros), δθ moves every body-fixed arm a by δθ × a.
    # Measured against one jax.linearize applied to the 6 directions: as fast or faster
    # (bench_pulley_stiffness.py, bench_css.py); a vmap over the directions: the CSS
    # membership 1.5x slower
    cols = [jax.jvp(lambda p: wrench(p, r0, rc0), (p0,), (jnp.zeros_like(p0).at[j].set(1.0),))[1] for j in range(3)]
    for j in range(3):
        e = trailing_axes(jnp.eye(3)[j], nb)  # (3, 1...)
        cols.append(jax.jvp(lambda r, rc: wrench(p0, r, rc), (r0, rc0),
                            (_cross(jnp.broadcast_to(e[None], r0.shape), r0), _cross(e[None], rc0[None])[0]))[1])
    return -jnp.moveaxis(jnp.stack(cols), 0, 2)  # (k, 6, 6 dir, ...)


def spring_stiffness(robot, pose, tensions, nb, layout=None):
    """``K`` ``(6, 6, ...)`` of spring cables holding ``tensions`` ``(m, ...)`` at ``pose``
    ``(6, ...)``: the spring law at the unstrained lengths ``l0 = l EA/(EA + t)``, i.e.
    ``t(l) = (EA + t) l / l_ref - EA`` (Cui et al. 2019 eq. 17, ``∂t/∂l = EA/l0``; ``l`` the whole
    path, formats.md §1 v2), by autodiff. ``layout`` as :func:`pulley_layout`."""
    ea = trailing_axes(robot.EA, nb)
    return stiffness_sets(robot, pose, lambda l, lr: ((ea + tensions) * l / lr - ea)[None], (1.0,), nb,
                          layout)[0]


def _affine_tensions(robot, V, inherent, l, lr, nb):
    """The tension sets of the affine stiffness as functions of the lengths ``l`` (``lr`` at
    the pose): ``EA (l - lr)/lr`` ``(m, ...)`` (``K0``'s, zero at the pose) and the columns
    of ``V`` ``(k, m, ...)``, scaled by ``l / lr`` (``inherent="spring"``) or fixed
    (``"paper"``)."""
    cols = V * (l / lr)[:, None] if inherent == "spring" else V + 0.0 * l[:, None]
    return trailing_axes(robot.EA, nb) * (l - lr) / lr, jnp.moveaxis(cols, 1, 0)


def affine_stiffness_sets(robot, pose, V, inherent, nb, layout=None):
    """``K0 (6, 6, ...)`` and ``Σ_i V[i, c] M_i`` ``(k, 6, 6, ...)`` of the affine stiffness
    ``K(T) = K0 + Σ_i T_i M_i`` (:func:`cstiffjax.stiffness.css.affine_stiffness`) by autodiff:
    ``K0`` from the tensions ``EA (l - l_ref)/l_ref`` plus the weight, column ``c`` from
    ``V_c l / l_ref`` (``inherent="spring"``: ``∂t/∂l = (EA + t)/l``) or the fixed ``V_c``
    (``"paper"``: ``EA/l``, Cui et al. 2019), along the path of :func:`frame_paths` (pulleys
    included). :func:`contractions` is the hand-derived straight-cable form, the test
    reference."""
    def sets(l, lr):
        t0, cols = _affine_tensions(robot, V, inherent, l, lr, nb)
        return jnp.concatenate([t0[None], cols])

    K = stiffness_sets(robot, pose, sets, (1.0,) + (0.0,) * V.shape[1], nb, layout)
    return K[0], K[1:]


def membership_stiffness(robot, pose, V, inherent, nb, layout=None):
    """:func:`affine_stiffness_sets` as the CSS slabs use it: ``(K0 + K_lin[0], K_lin)``
    with ``K_lin[0]`` zero (:func:`slabs` adds the two), one tension set fewer to push
    through the autodiff: ``K`` is linear in the tensions, so the particular solution's
    set and ``K0``'s are one set, ``EA (l - l_ref)/l_ref`` plus ``V_0``'s column."""
    def sets(l, lr):
        t0, cols = _affine_tensions(robot, V, inherent, l, lr, nb)
        return jnp.concatenate([(t0 + cols[0])[None], cols[1:]])

    K = stiffness_sets(robot, pose, sets, (1.0,) + (0.0,) * (V.shape[1] - 1), nb, layout)
    return K[0], jnp.concatenate([jnp.zeros_like(K[:1]), K[1:]])


def structure_rows(r, u):
    """``Sᵀ`` as ``(m, 6, ...)``: rows ``[u_i, r_i × u_i]`` (Cui et al. 2019 below eq. 2)."""
    return jnp.concatenate([u, _cross(r, u)], axis=1)


def load_wrench(robot, R, external, nb):
    """Weight about the reference point plus ``external`` -> ``(6, ...)``."""
    f = trailing_axes(robot.weight, nb)
    c = trailing_axes(robot.com, nb)
    rc = jnp.stack([sum(R[a, k] * c[k] for k in range(3)) for a in range(3)])
    m = _cross(rc[None], f[None])[0]
    w = jnp.concatenate([jnp.broadcast_to(f, m.shape), m])
    return w if external is None else w + trailing_axes(jnp.asarray(external, dtype=jnp.float64), nb)


def null_space(s, w):
    """Householder QR of ``Sᵀ`` (``s`` ``(m, 6, ...)``): ``t_p`` ``(m, ...)`` with
    ``S t_p = -w`` (minimum norm), ``N`` ``(m, r, ...)`` orthonormal, ``singular`` ``(...)``."""
    return qr_null_space(s, w)[:3]


def qr_null_space(s, w):
    """As :func:`null_space`, plus the triangular factor: ``(t_p, N, singular, R)`` with
    ``Sᵀ = Q [R; 0]`` and ``R`` a 6x6 nested list of ``(...)`` arrays (upper triangular;
    the identity where ``singular``).

    Reflection ``k`` acts on rows and columns ``k..`` only (the rows above are untouched
    by it, the columns before are zero below the diagonal; it updated every row and
    column before): the geometry plus null space of a 64-pose batch 760 -> 355
    ns/pose on one device; the 1e7-pose CSS frame sweep with the hand contractions
    1.22-1.24e6 -> 1.78-1.81e6 poses/s (two alternating runs each)."""
    m = s.shape[0]
    A, vs = s, []
    for k in range(6):  # reflection k acts on rows k.. and columns k.. only (the rest is 0 or done)
        x = A[k:, k]
        alpha = -jnp.where(x[0] >= 0, 1.0, -1.0) * jnp.sqrt(axis_sum(x * x, axis=0))
        v = x.at[0].add(-alpha)
        nv = jnp.sqrt(axis_sum(v * v, axis=0))
        v = v / jnp.where(nv > 0, nv, 1.0)
        B = A[k:, k:]
        A = A.at[k:, k:].set(B - 2.0 * v[:, None] * axis_sum(v[:, None] * B, axis=0)[None])
        vs.append(v)
    diag = jnp.stack([jnp.abs(A[k, k]) for k in range(6)])
    singular = ~(jnp.min(diag, axis=0) > RANK_TOL * jnp.max(diag, axis=0))
    Rd = [[jnp.where(singular, float(i == j), A[i, j]) for j in range(6)] for i in range(6)]
    z = []
    for k in range(6):  # Rᵀ z = -w
        z.append((-w[k] - sum(Rd[j][k] * z[j] for j in range(k))) / Rd[k][k])
    z = jnp.where(singular, 0.0, jnp.stack(z))

    def apply_q(y):
        for k in reversed(range(6)):
            v = vs[k]
            y = y.at[k:].add(-2.0 * v * axis_sum(v * y[k:], axis=0))
        return y

    tp = apply_q(jnp.concatenate([z, jnp.zeros((m - 6, *z.shape[1:]))]))
    e = jnp.eye(m)
    cols = [apply_q(jnp.broadcast_to(trailing_axes(e[j], z.ndim - 1), tp.shape)) for j in range(6, m)]
    N = jnp.stack(cols, axis=1) if cols else jnp.zeros((m, 0, *tp.shape[1:]))
    return tp, _canonical(N), singular, Rd


def _canonical(N):
    """Canonical null basis (see :func:`cstiffjax.stiffness.tensions.tension_space`), batched."""
    m, r = N.shape[:2]
    if r == 0 or r > 2:
        return N
    c = axis_sum(N, axis=0)  # Nᵀ 1, (r, ...)
    nc = jnp.sqrt(axis_sum(c * c, axis=0))
    good = nc > 1e-9 * jnp.sqrt(m)
    c = jnp.where(good, c / jnp.where(nc > 0, nc, 1.0), trailing_axes(jnp.eye(r)[0], c.ndim - 1))
    if r == 1:
        return N * jnp.where(c[0] < 0, -1.0, 1.0)
    n1 = N[:, 0] * c[0] + N[:, 1] * c[1]
    n2 = -N[:, 0] * c[1] + N[:, 1] * c[0]
    n2 = n2 * jnp.where(axis_sum(n2**3, axis=0) < 0, -1.0, 1.0)
    return jnp.stack([n1, n2], axis=1)


def _hat(v):
    """``hat`` of ``v`` ``(k, 3, ...)`` -> ``(k, 3, 3, ...)``."""
    z = jnp.zeros_like(v[:, 0])
    return jnp.stack([jnp.stack([z, -v[:, 2], v[:, 1]], 1), jnp.stack([v[:, 2], z, -v[:, 0]], 1),
                      jnp.stack([-v[:, 1], v[:, 0], z], 1)], 1)


def contractions(robot, R, r, u, l, V, inherent):
    """``K0 (6, 6, ...)`` and ``Σ_i V[i, c] M_i`` ``(k, 6, 6, ...)`` (see
    :func:`cstiffjax.stiffness.css.stiffness_contractions`; same formulas, batch-minor), straight
    cables only. Hand-derived: the test reference of :func:`affine_stiffness_sets` and of
    the CSS membership (tested equal to 1e-9 relative without pulleys); no production
    path uses it."""
    nb = l.ndim - 1
    s = structure_rows(r, u)  # (m, 6, ...)
    tau = V / l[:, None]  # (m, k, ...)

    def wsum(w, x, y):
        return axis_sum(w[:, :, None, None] * x[:, None, :, None] * y[:, None, None, :], axis=0)

    eye = trailing_axes(jnp.eye(3), nb)
    tr = axis_sum(tau[:, :, None] * r[:, None], axis=0)  # (k, 3, ...)
    hat_tr = _hat(tr)
    diag = (axis_sum(tau * axis_sum(r * r, 1)[:, None], 0) + axis_sum(V * axis_sum(u * r, 1)[:, None], 0))
    rot = diag[:, None, None] * eye - wsum(tau, r, r) - wsum(V, r, u)
    st = axis_sum(tau, axis=0)[:, None, None] * eye
    K_lin = jnp.concatenate([jnp.concatenate([st, -hat_tr], 2), jnp.concatenate([hat_tr, rot], 2)], 1)
    if inherent == "paper":
        K_lin = K_lin - wsum(tau, s, s)
    f = trailing_axes(robot.weight, nb)[None]
    c = trailing_axes(robot.com, nb)
    rc = jnp.stack([sum(R[a, k] * c[k] for k in range(3)) for a in range(3)])[None]
    Kg = -axis_sum(_hat(f)[0][:, :, None] * _hat(rc)[0][None], axis=1)  # hat(f) hat(Rc), (3, 3, ...)
    K0 = wsum(trailing_axes(robot.EA, nb)[:, None] / l[:, None], s, s)[0]
    K0 = K0.at[3:, 3:].add(Kg)
    return K0, K_lin


def slabs(robot, tp, N, K0, K_lin, kc, tol):
    """All slabs ``lo <= a·φ <= hi`` (tension limits, then the 21 stiffness entries):
    ``a (k, r, ...)``, ``lo``, ``hi`` ``(k, ...)``."""
    nb = tp.ndim - 1
    kc, tol = trailing_axes(kc, nb), trailing_axes(tol, nb)
    C = K0 + K_lin[0] - kc
    A = K_lin[1:]
    i, j = _IU
    a = 0.5 * (A[:, i, j] + A[:, j, i])  # (r, 21, ...)
    a = jnp.moveaxis(a, 0, 1)
    lo = jnp.maximum(-tol[i, j] - C[i, j], -tol[j, i] - C[j, i])
    hi = jnp.minimum(tol[i, j] - C[i, j], tol[j, i] - C[j, i])
    return (jnp.concatenate([N, a]), jnp.concatenate([trailing_axes(robot.tension_min, nb) - tp, lo]),
            jnp.concatenate([trailing_axes(robot.tension_max, nb) - tp, hi]))


def pad2(a, lo, hi):
    """Pad ``r < 2`` coordinates to 2 with ``|φ_dummy| <= 1`` slabs."""
    r = a.shape[1]
    if r == 2:
        return a, lo, hi
    bshape = lo.shape[1:]
    a = jnp.concatenate([a, jnp.zeros((a.shape[0], 2 - r, *bshape))], axis=1)
    dummy = jnp.broadcast_to(trailing_axes(jnp.eye(2)[r:], len(bshape)), (2 - r, 2, *bshape))
    one = jnp.ones((2 - r, *bshape))
    return jnp.concatenate([a, dummy]), jnp.concatenate([lo, -one]), jnp.concatenate([hi, one])


def feasible_point(a, lo, hi):
    """Exact feasibility of the slabs ``lo <= a φ <= hi`` in the plane and an interior point.

    ``a`` ``(k, 2, ...)``, ``lo``/``hi`` ``(k, ...)``. Each slab with ``a2 != 0`` (signs
    flipped so that ``a2 > 0``) bounds ``φ2`` between the lines ``bl - α φ1`` and
    ``bh - α φ1`` (``α = a1/a2``, ``bl = lo/a2``, ``bh = hi/a2``); "vertical" slabs
    (``|a2| <= 1e-12 |a1|``) bound ``φ1`` directly. Fourier-Motzkin elimination of ``φ2``
    pairs every upper line with every lower one; for an unordered pair ``i < j`` with
    ``c = α_i - α_j`` the two pairings give ``φ1`` between ``(bl_i - bh_j)/c`` and
    ``(bh_i - bl_j)/c`` (in either order, by the sign of ``c``), so ``k(k-1)/2`` pairs
    suffice. Exactly parallel pairs (``c = 0``) give ``±inf`` (no bound) when the two
    strips overlap and an empty interval when they do not; strips that merely touch
    (``bh_i = bl_j`` and ``c = 0``, a degenerate boundary case) come out infeasible.
    The system is feasible iff every slab is non-empty and the largest lower bound on
    ``φ1`` is at most the smallest upper bound.

    **Returns:** ``(feasible (...), φ (2, ...))``; ``φ1`` the middle of the feasible
    interval, ``φ2`` the middle of the feasible segment there (for an unbounded region:
    1 inside the finite end of a half-line, 0 on a whole line); zeros when infeasible.
    """
    k = a.shape[0]
    a1, a2 = a[:, 0], a[:, 1]
    flip = a2 < 0
    a1, a2 = jnp.where(flip, -a1, a1), jnp.abs(a2)
    lo, hi = jnp.where(flip, -hi, lo), jnp.where(flip, -lo, hi)
    vert = a2 <= 1e-12 * jnp.abs(a1)
    zero = vert & (a1 == 0)
    s1 = jnp.where(a1 == 0, 1.0, a1)
    on = vert & ~zero
    L = jnp.max(jnp.where(on, jnp.where(a1 > 0, lo, hi) / s1, -jnp.inf), axis=0)
    U = jnp.min(jnp.where(on, jnp.where(a1 > 0, hi, lo) / s1, jnp.inf), axis=0)
    nonempty = jnp.all((lo <= hi) & (~zero | ((lo <= 0) & (hi >= 0))), axis=0)
    s2 = jnp.where(vert, 1.0, a2)
    al = jnp.where(vert, 0.0, a1 / s2)
    bl = jnp.where(vert, -jnp.inf, lo / s2)
    bh = jnp.where(vert, jnp.inf, hi / s2)
    i, j = np.triu_indices(k, 1)  # static: every unordered slab pair once
    r = 1.0 / (al[i] - al[j])
    q1 = (bh[i] - bl[j]) * r
    q2 = (bl[i] - bh[j]) * r
    U = jnp.minimum(U, jnp.min(jnp.maximum(q1, q2), axis=0))
    L = jnp.maximum(L, jnp.max(jnp.minimum(q1, q2), axis=0))
    ok = nonempty & (L <= U)  # False for NaN
    x = _inside(L, U)
    y = _inside(jnp.max(bl - al * x, axis=0), jnp.min(bh - al * x, axis=0))
    phi = jnp.where(ok, jnp.stack([x, y]), 0.0)
    return ok, phi


def _inside(lo, hi):
    """A finite point of ``[lo, hi]``: the middle, or 1 inside the finite end of a
    half-line, or 0 for the whole line."""
    flo, fhi = jnp.isfinite(lo), jnp.isfinite(hi)
    mid = 0.5 * (jnp.where(flo, lo, 0.0) + jnp.where(fhi, hi, 0.0))
    return jnp.where(flo & fhi, mid, jnp.where(flo, lo + 1.0, jnp.where(fhi, hi - 1.0, 0.0)))


def disc_reject(a, lo, hi, tp, robot):
    """Exact, cheap infeasibility certificate: every CTFR point has ``|φ| <= ρ`` with
    ``ρ² = Σ_i max((t_max - t_p,i)², (t_min - t_p,i)²)`` (``N`` is orthonormal, so
    ``|φ| = |T - t_p|``); a slab that misses that disc, or is empty, proves the pose is
    not in the CSS. ``a`` ``(k, r, ...)`` before padding. Returns ``(...)`` bool."""
    nb = tp.ndim - 1
    tmin, tmax = trailing_axes(robot.tension_min, nb), trailing_axes(robot.tension_max, nb)
    rho = jnp.sqrt(axis_sum(jnp.maximum((tmax - tp) ** 2, (tmin - tp) ** 2)))
    na = jnp.sqrt(axis_sum(a * a, axis=1)) if a.shape[1] else jnp.zeros_like(lo)
    return jnp.any((lo > na * rho) | (hi < -na * rho) | (lo > hi), axis=0)


def membership(robot, pose, kc, tol, external, inherent, layout=None):
    """CSS membership of ``pose`` ``(6, ...)``: ``(member, tensions (m, ...), φ (2, ...),
    μ (...), singular (...))``; ``tol`` the 6x6 allowed ``|K - k_c|``. The cable path (pulleys
    included, ``layout`` as :func:`pulley_layout`) gives the structure matrix, and the
    affine stiffness comes from autodiff of the same path (:func:`membership_stiffness`),
    straight cables included. Measured with ``benchmarks/bench_css.py --frame-contractions``
    (2 cores, benchmarks/RESULTS.md): the 1e8-pose frame sweep at 1.80e6 poses/s (the hand
    contractions 2.46e6 in the same run; the earlier kernel, contractions, 1.55e6 side by
    side), the near-CSS sample at 9.5e5 (contractions 1.04e6; the earlier 7.7e5); tests
    check the autodiff and the hand contractions agree to 1e-9."""
    nb = pose.ndim - 1
    layout = pulley_layout(robot) if layout is None else layout
    R, rr, u, _ = geometry(robot, pose, nb, layout)
    tp, N, singular = null_space(structure_rows(rr, u), load_wrench(robot, R, external, nb))
    V = jnp.concatenate([tp[:, None], N], axis=1)
    K0, K_lin = membership_stiffness(robot, pose, V, inherent, nb, layout)
    return membership_from_stiffness(robot, tp, N, singular, K0, K_lin, kc, tol)


def membership_from_stiffness(robot, tp, N, singular, K0, K_lin, kc, tol):
    """:func:`membership` from the null space ``(tp, N, singular)`` of :func:`null_space` and
    the affine stiffness ``(K0, K_lin)`` for the tension sets ``[tp, N]``.

    The Fourier-Motzkin step (most of the work) is skipped, under ``lax.cond``, for a
    batch in which :func:`disc_reject` already settles every pose (most of a workspace
    sweep far from the CSS); the answer is the same either way."""
    nb = tp.ndim - 1
    r = robot.num_cables - 6
    a, lo, hi = slabs(robot, tp, N, K0, K_lin, kc, tol)
    rejected = disc_reject(a, lo, hi, tp, robot) | singular
    padded = pad2(a, lo, hi)
    ok, phi = jax.lax.cond(jnp.all(rejected), lambda x: (jnp.zeros_like(lo[0], bool), jnp.zeros_like(x[0][0])),
                           lambda x: feasible_point(*x), padded)
    ok = ok & ~rejected
    t = tp + axis_sum(N * phi[None, :r], axis=1) if r else tp
    tbar = 0.5 * (trailing_axes(robot.tension_max, nb) + trailing_axes(robot.tension_min, nb))
    mu = axis_sum(jnp.abs(t - tbar)) / (robot.num_cables * tbar)
    return ok, t, phi, mu, singular
