"""Checks on the samples of a recordings set before a fit or a diagnosis trusts them.

- :func:`time_order`: the samples must be in the order they were taken (formats.md §2);
  the direction of the last length change of each cable (``dir_i``, the covariate of
  exit friction) and the lag-1 whiteness are computed from that order. A ``time`` column
  that goes backwards is an error naming the first offending row, unless the caller asks
  to sort by time.
- :func:`no_equilibrium_cause`: when the nominal model has no equilibrium for most
  samples, the likeliest reason, from the commanded lengths against the
  anchor-attachment distances at the measured poses.
"""

import numpy as np

from cstiffjax.core.errors import DiagnosisError
from cstiffjax.io import schema
from cstiffjax.io.plausibility import length_ratios, straight_distances, unit_mismatch

MAX_FAILED_FRACTION = 0.5  # more samples than this without an equilibrium: no verdict


def _where(i: int, rows) -> str:
    return f"sample {i + 1}" if rows is None else f"row {rows[i]}"


def time_order(recordings, *, sort_by_time: bool = False, rows=None):
    """Check (or restore, ``sort_by_time``) the time order of the samples.

    **Arguments:**

    - ``recordings``: a :class:`~cstiffjax.io.recordings.Recordings`.
    - ``sort_by_time``: sort the samples by ``time`` (stable) instead of failing.
    - ``rows``: file line number of each sample (used in messages), or ``None`` (samples
      are then named by their 1-based position).

    **Returns:** ``(recordings, rows, sorted)``: unchanged with ``sorted`` false when the
    times never decrease (or there is no ``time`` column); sorted with ``sorted`` true.

    **Raises:** :class:`~cstiffjax.core.errors.DiagnosisError` naming the first row whose time
    is earlier than the row before it (or, when sorting, a row with no time).
    """
    t = np.asarray(recordings.time)
    finite = np.flatnonzero(np.isfinite(t))
    back = np.flatnonzero(np.diff(t[finite]) < 0)
    if back.size == 0:
        return recordings, rows, False
    if not sort_by_time:
        i, prev = int(finite[back[0] + 1]), int(finite[back[0]])
        raise DiagnosisError(
            f"{recordings.source}: {_where(i, rows)}: time {t[i]:g} s is earlier than {t[prev]:g} s at "
            f"{_where(prev, rows)}; samples must be in the order they were taken (formats.md §2), the direction "
            f"of each cable's last length change is computed from that order. Put the rows in time order, or "
            f"pass sort_by_time=True (--sort-by-time) to sort them by time")
    if finite.size != t.size:
        i = int(np.flatnonzero(~np.isfinite(t))[0])
        raise DiagnosisError(f"{recordings.source}: {_where(i, rows)}: empty time cell; cannot sort by time")
    order = np.argsort(t, kind="stable")
    return recordings.select(order), None if rows is None else [rows[i] for i in order], True


def no_equilibrium_cause(robot, recordings, failed) -> str:
    """The likeliest reason why the samples ``failed`` (0-based) have no equilibrium:
    a sentence comparing ``l0`` with the anchor-attachment distances at the measured poses
    (:mod:`cstiffjax.io.plausibility`, the checks of ``cstiffjax check``), naming the cables
    whose lengths are a factor ~1000 off."""
    idx = np.asarray(failed, dtype=int)
    l0 = np.asarray(recordings.l0)[idx]
    dist = straight_distances(robot, np.asarray(recordings.pose)[idx])
    if np.any(l0 <= 0):
        k, j = np.argwhere(l0 <= 0)[0]
        column = schema.cable_column("l0", j + 1)
        return (f"{int(np.sum(l0 <= 0))} commanded lengths are zero or negative (e.g. sample {idx[k] + 1}, "
                f"{column} = {l0[k, j]:g} m): cable lengths must be positive; wrong sign or a wrong offset?")
    ratio = float(np.median(l0 / dist))
    per_cable = length_ratios(robot, l0, np.asarray(recordings.pose)[idx])
    off = [j for j, r in enumerate(per_cable) if unit_mismatch(r)]
    if unit_mismatch(ratio):
        return (f"l0 is {ratio:.4g} times the anchor-attachment distance at the measured poses (median): "
                f"wrong units (mm against m?)")
    if off:
        cables = ", ".join(f"{schema.cable_column('l0', j + 1)} is {per_cable[j]:.4g} times" for j in off)
        return f"{cables} the anchor-attachment distance at the measured poses (median): wrong units (mm against m?)"
    if ratio < 0.9:
        return (f"l0 is shorter than the anchor-attachment distances at the measured poses (median ratio "
                f"{ratio:.3g}): the cables would have to stretch by {100 * (1 / ratio - 1):.0f}%; wrong units, "
                f"a missing length offset, or l0 measured to another point than the exit point?")
    if ratio > 1.1:
        return (f"l0 is longer than the anchor-attachment distances at the measured poses (median ratio "
                f"{ratio:.3g}): every cable would be slack; wrong units or a length offset?")
    return ("l0 matches the anchor-attachment distances (median ratio "
            f"{ratio:.3g}), so the robot description itself (anchors, attachments, EA, platform mass, "
            f"noise) or the pose columns probably do not match these recordings")
