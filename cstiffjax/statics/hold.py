"""Whether the cables can hold a pose at all, by pulling: the verdict ``cstiffjax sag`` gives
before it solves anything.

A pose is held when cable tensions ``t >= tension_min`` balance the load, ``|S t + W|``
within ``BALANCE_TOL (|W| + 1)`` (:mod:`cstiffjax.statics.geometry`). With 6 cables the
balancing tensions are unique; with more, whether such tensions exist is a linear
feasibility problem, answered by non-negative least squares (:func:`nearest_pulling`).
"""

import jax.numpy as jnp
import numpy as np

from cstiffjax.core.errors import NoAnswerError
from cstiffjax.statics.geometry import balanced, external_wrench, gravity_wrench, structure_matrix_closed_form


def check_holdable(robot, pose, ext, tensions, where: str) -> None:
    """Raise :class:`NoAnswerError` when the cables cannot hold ``pose`` at all.

    **Arguments:**

    - `robot`: a CDPR.
    - `pose`: `(6,)` platform pose (m, rad).
    - `ext`: external wrench `(6,)` (N, N·m) or ``None``.
    - `tensions`: the minimum-norm balancing tensions at ``pose`` (``inverse_statics``), `(m,)` N.
    - `where`: the pose as the message names it (e.g. ``"--pose 0 0 1.5 0 0 0"``).

    **Raises:** :class:`NoAnswerError` when the pose's position is outside the anchors'
    horizontal bounding box, (6 cables) one of the unique balancing ``tensions`` is not
    positive, or (more cables) no tensions >= ``tension_min`` balance the load
    (:func:`nearest_pulling`).
    """
    a = np.asarray(robot.anchors)
    p = np.asarray(pose)[:3]
    lo, hi = a[:, :2].min(0), a[:, :2].max(0)
    if np.any(p[:2] < lo) or np.any(p[:2] > hi):
        raise NoAnswerError(f"{where}: the pose is outside the anchors' frame (x {lo[0]:g} .. {hi[0]:g} m, "
                            f"y {lo[1]:g} .. {hi[1]:g} m): no positive cable tensions hold it")
    t = np.asarray(tensions)
    if robot.num_cables == 6 and not np.all(t > 0):
        raise NoAnswerError(f"{where}: no positive cable tensions hold this pose (the unique balancing tensions "
                            f"are {' '.join(f'{v:.4g}' for v in t)} N): outside what the cables can hold")
    if robot.num_cables > 6:
        t, unbalanced, load = nearest_pulling(robot, pose, ext)
        if not balanced(unbalanced, load):
            raise NoAnswerError(
                f"{where}: no cable tensions >= {float(robot.tension_min):g} N hold this pose: the closest "
                f"balance such tensions reach leaves |S t + W| = {unbalanced:.4g} N of the {load:.4g} N load "
                f"unbalanced (tensions {' '.join(f'{v:.4g}' for v in t)} N, non-negative least squares): outside "
                f"what the cables can hold")


def nearest_pulling(robot, pose, ext) -> tuple[np.ndarray, float, float]:
    """The tensions ``t >= tension_min`` (no upper limit) that come closest to balancing the
    load at ``pose``.

    Non-negative least squares (Lawson-Hanson, exact in finitely many steps) on
    ``u = t - tension_min``: the pose can be held by pulling cables iff the residual is zero,
    which for a redundant robot is a linear feasibility problem no pseudo-inverse answers
    (its minimum-norm tensions may push).

    **Arguments:**

    - `robot`: a CDPR.
    - `pose`: `(6,)` platform pose (m, rad).
    - `ext`: external wrench `(6,)` (N, N·m) or ``None``.

    **Returns:** ``(t, |S t + W|, |W|)``: the tensions `(m,)` and the two norms, N; the pose
    is held when ``|S t + W|`` is within ``BALANCE_TOL (|W| + 1)``.
    """
    from scipy.optimize import nnls  # lazy: scipy is a dependency of jax; one pose, on the host

    S = np.asarray(structure_matrix_closed_form(robot, jnp.asarray(pose)))
    w = np.asarray(gravity_wrench(robot, jnp.asarray(pose)) + external_wrench(ext))
    tmin = float(robot.tension_min)
    scale = np.maximum(np.linalg.norm(S, axis=0), 1e-300)  # unit columns (moments and forces mixed)
    u, _ = nnls(S / scale, -(w + tmin * S.sum(axis=1)), maxiter=50 * S.shape[1])
    t = tmin + u / scale
    return t, float(np.linalg.norm(S @ t + w)), float(np.linalg.norm(w))
