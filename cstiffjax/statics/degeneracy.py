"""Whether a robot's cables can hold a pose at all: the rank of its structure matrix and the
degeneracies that make it short (duplicate cables, cables along one line, all anchors or all
attachments at one point), named for the user.

The matrices are unit-free (``cstiffjax check`` scales the moment rows by the platform size),
so one relative tolerance, :data:`RANK_RTOL`, fits forces and moments alike. The rank is
tested at a reference pose and at the six poses around it (:func:`poses_around`), because one
pose can be singular by accident: :func:`check_rank` fails only when the rank is short at all
seven.
"""

import numpy as np

from cstiffjax.core.errors import RobotFileError

RANK_RTOL = 1e-9
"""A singular value below this fraction of the largest counts as zero (moment rows scaled by
the platform size, so forces and moments weigh alike)."""


def poses_around(robot, pose) -> list[np.ndarray]:
    """Six poses around ``pose``.

    **Arguments:**

    - `robot`: the robot (its anchors give the step of a CDPR).
    - `pose`: `(6,)` CDPR pose (m, rad) or `(3,)` CSJM rotation vector (rad).

    **Returns:** six poses of ``pose``'s shape: CDPR, a step of 10 % of the anchors' spread
    along x, y and z and of 0.1 rad about each axis; CSJM, ±0.1 rad about each axis.
    """
    e = np.eye(3)
    if pose.shape[0] == 3:
        steps = [s * d for d in e for s in (0.1, -0.1)]
    else:
        spread = float(np.ptp(np.asarray(robot.anchors), axis=0).max()) or 1.0
        steps = [np.r_[0.1 * spread * d, 0, 0, 0] for d in e] + [np.r_[0, 0, 0, 0.1 * d] for d in e]
    return [pose + s for s in steps]


def unit_free(robot, S) -> np.ndarray:
    """Structure matrices with unit-free entries: one relative tolerance fits both rows.

    **Arguments:**

    - `robot`: the robot (its attachments give the platform size, m).
    - `S`: structure matrices, `(n, 6, m)` (CDPR: N per N, N·m per N) or the moment Jacobians
      transposed, `(n, 3, m)` (CSJM: N·m per N).

    **Returns:** ``S`` with its moment rows (CDPR) or all of it (CSJM) divided by the platform
    size, the largest distance of an attachment from the reference point (1 when that is 0).
    """
    size = float(np.linalg.norm(np.asarray(robot.attachments), axis=1).max()) or 1.0
    if robot.kind == "csjm":
        return S / size
    S = np.array(S)
    S[:, 3:] /= size
    return S


def matrix_rank(S) -> int:
    """The rank of the unit-free matrix ``S`` (r x m): its singular values above
    :data:`RANK_RTOL` times the largest; 0 when ``S`` has a non-finite entry or is zero."""
    if not np.all(np.isfinite(S)):
        return 0
    s = np.linalg.svd(S, compute_uv=False)
    return int(np.sum(s > RANK_RTOL * s.max())) if s.max() > 0 else 0


def _coincide(points, tol) -> bool:
    p = np.asarray(points)
    return bool(np.all(np.linalg.norm(p - p.mean(0), axis=1) <= tol))


def degeneracies(robot, S) -> list[str]:
    """Why the cables of ``robot`` are dependent, naming them.

    **Arguments:**

    - `robot`: the robot (its anchors and attachments, m).
    - `S`: its unit-free structure matrix at one pose, r x m (columns: cables).

    **Returns:** one sentence per degeneracy found (all anchors or all attachments at one
    point, two cables with the same anchor and attachment, two cables whose columns are
    equal or opposite within 1e-9); empty when none is.
    """
    a, b = np.asarray(robot.anchors), np.asarray(robot.attachments)
    tol = 1e-9 * max(np.abs(a).max(), np.abs(b).max(), 1.0)
    out = []
    if _coincide(a, tol):
        out.append(f"all anchors are at one point {np.round(a[0], 6).tolist()}")
    if _coincide(b, tol):
        out.append(f"all attachments are at one point {np.round(b[0], 6).tolist()}")
    m = S.shape[1]
    for i in range(m):
        for j in range(i + 1, m):
            if np.allclose(a[i], a[j], atol=tol) and np.allclose(b[i], b[j], atol=tol):
                out.append(f"cables {i + 1} and {j + 1} are duplicates (same anchor and attachment)")
            elif min(np.abs(S[:, i] - S[:, j]).max(), np.abs(S[:, i] + S[:, j]).max()) < 1e-9:
                out.append(f"cables {i + 1} and {j + 1} act along the same line")
    return out


def check_rank(robot, pose, matrices, path) -> tuple[int, int, list[str]]:
    """Whether ``robot`` can hold a pose: the rank at ``pose`` and around it.

    **Arguments:**

    - `robot`: the robot (``kind`` ``"cdpr"`` or ``"csjm"``).
    - `pose`: the reference pose, `(6,)` (m, rad) or `(3,)` (rad), as the message names it.
    - `matrices`: the unit-free structure matrices at ``pose`` (first) and at
      ``poses_around(robot, pose)``, `(7, r, m)`.
    - `path`: the robot's file, as the message names it.

    **Returns:** ``(rank at pose, highest rank at pose and around it, warnings)`` (the
    degeneracies found at ``pose``).

    **Raises:** :class:`RobotFileError` when the robot cannot hold any pose: the rank short
    (CSJM: of 3; CDPR: of 6, or of m with fewer than 6 cables) at ``pose`` and at the six
    poses around it, naming the degeneracies (else the wrench direction no tensions produce).
    """
    full = 3 if robot.kind == "csjm" else min(6, robot.num_cables)  # fewer than 6 cables: independent ones
    S = matrices[0]
    rank, found = matrix_rank(S), degeneracies(robot, S)
    best = max(matrix_rank(q) for q in matrices)
    if best == full:
        return rank, best, found
    if not found:
        u = np.linalg.svd(S)[0][:, -1] if np.all(np.isfinite(S)) else np.full(full, np.nan)
        found = [f"no tensions of cables 1..{S.shape[1]} produce the {'wrench' if full == 6 else 'moment'} "
                 f"direction {np.round(u, 4).tolist()} (structure-matrix rows scaled by the platform size)"]
    what = "cannot hold any pose" if full == 6 or robot.kind == "csjm" else "has dependent cables"
    raise RobotFileError(
        f"{path}: the robot {what}: its structure matrix has rank {rank} < {full} at "
        f"the reference pose {np.round(pose, 6).tolist()} and at six poses around it: "
        + "; ".join(found) + ". (Rule: `cstiffjax check` tests the rank at the mean recorded pose, or without "
        "recordings at the centre of the anchors' bounding box, unrotated, and at six poses around it.)"
    )
