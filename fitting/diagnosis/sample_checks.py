"""Checks on the samples of a recordings set before a fit or a diagnosis trusts them.

- :func:`time_order`: the samples must be in the order they were taken (formats.md §2);
  the direction of the last length change of each cable (``dir_i``, the covariate of
  exit friction) and the lag-1 whiteness are computed from that order. A ``time`` column
  that goes backwards is an error naming the first offending row, unless the caller asks
  to sort by time.
- :func:`no_equilibrium_cause`: when the nominal model has no equilibrium for most
  samples, the likeliest reason, from the commanded lengths against the
  anchor-attachment distances at the measured poses.
- :func:`enough_distinct`: copies of one measurement (:func:`cstiffjax.io.screening.duplicate_groups`)
  count once; fewer than :data:`MIN_DISTINCT_PER_FOLD` distinct samples per held-out fold
  is an error, not a verdict (:func:`cstiffjax.io.screening.distinct` then keeps one of
  each); :func:`held_out_folds` keeps the copies of a sample in one held-out fold.
- :func:`elasticity_unknown`: whether the recordings determine any cable's ``EA`` at its
  nominal value (when they do not, tensions and elongations are below the noise, and an
  effect seen only through the cables' strain cannot be claimed).
"""

import numpy as np

from cstiffjax.core.errors import DiagnosisError
from cstiffjax.io import schema
from cstiffjax.io.plausibility import length_ratios, straight_distances, unit_mismatch

MAX_FAILED_FRACTION = 0.5  # more samples than this without an equilibrium: no verdict
MIN_DISTINCT_PER_FOLD = 2  # distinct samples per held-out fold a verdict needs at least


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
    t, session = np.asarray(recordings.time), np.asarray(recordings.session)
    finite = np.flatnonzero(np.isfinite(t))
    # a new session has its own clock (formats.md §2 version 3): time may restart there
    back = np.flatnonzero((np.diff(t[finite]) < 0) & (np.diff(session[finite]) == 0))
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
    order = np.lexsort((t, session))  # by session, then by time within it (stable)
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


def enough_distinct(recordings, groups, folds: int) -> None:
    """Raise unless ``recordings`` hold at least ``MIN_DISTINCT_PER_FOLD · folds`` distinct
    samples (``groups`` from :func:`cstiffjax.io.screening.duplicate_groups`: copies count once).

    **Raises:** :class:`~cstiffjax.core.errors.DiagnosisError` naming the number of samples,
    of distinct ones and of copies, and the number needed.
    """
    n = int(np.size(groups))
    distinct = int(np.max(groups)) + 1 if n else 0
    need = MIN_DISTINCT_PER_FOLD * folds
    if distinct >= need:
        return
    copies = f" ({n - distinct} of the {n} samples are copies of another)" if distinct < n else ""
    raise DiagnosisError(
        f"{recordings.source}: only {distinct} distinct samples{copies}; a diagnosis needs at least {need} "
        f"({MIN_DISTINCT_PER_FOLD} per held-out fold, {folds} folds) to tell an effect from noise: no verdict. "
        f"Record more poses")


def held_out_folds(groups, folds: int) -> np.ndarray:
    """``(n,)`` held-out fold (``0 .. folds-1``) of each sample: groups (``groups`` from
    :func:`cstiffjax.io.screening.duplicate_groups`) are dealt to the folds in a fixed random
    order, so all copies of a sample fall in one fold; without copies (``groups = arange(n)``)
    sample ``i`` gets ``permutation(n)[i] % folds`` (seed 0)."""
    groups = np.asarray(groups, dtype=int)
    count = int(groups.max()) + 1 if groups.size else 0
    return (np.random.default_rng(0).permutation(count) % folds)[groups]


def elasticity_unknown(fitter, model, weight, max_std: float) -> str | None:
    """Why the recordings carry no information about the cables' elasticity, or ``None``.

    At the nominal robot (every ``EA`` nominal, no effect; ``θ = 0`` of ``model``, the
    baseline model of ``fitter``, a :class:`~fitting.diagnosis.fitter.Fitter`) the standard
    deviation of ``ln EA_j`` with everything else held is ``1 / |J_j|`` (``J_j`` the
    whitened residuals' derivative, samples of ``weight`` that have an equilibrium). When
    it exceeds ``max_std`` for every cable, no cable's stretch shows above the noise: the
    tensions are below the load cells' noise and the elongations below the pose noise.

    **Returns:** ``None`` when some cable's ``EA`` is determined, else a sentence with the
    smallest such standard deviation and the largest predicted tension against the noise.
    """
    m = fitter.m
    r, J, ok = fitter.evaluator(model, weight, columns=np.arange(m))(np.zeros(model.size))
    use = (np.asarray(weight) > 0) & np.asarray(ok, dtype=bool)
    if not use.any():
        return None
    J = np.asarray(J).reshape(len(use), -1, np.shape(J)[-1])[use][..., :m]
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        std = 1.0 / np.sqrt(np.sum(J.reshape(-1, m) ** 2, axis=0))
    if np.any(std <= max_std):
        return None
    sigma = float(fitter.robot.noise.tension)
    mask = np.asarray(fitter.rec.tension_mask, dtype=bool)[use]
    m = fitter.m
    predicted = np.asarray(fitter.rec.tensions)[use] - sigma * np.asarray(r).reshape(len(use), -1)[use][:, 6:6 + m]
    largest = float(np.max(np.abs(predicted[mask]))) if mask.any() else float("nan")
    return (f"the recordings carry no information about the cables' elasticity: at the nominal EA no cable's EA "
            f"is determined (standard deviation of ln EA at least {float(np.min(std)):.3g}, more than "
            f"{max_std:g}); the tensions the nominal model predicts reach only {largest:.3g} N against the load "
            f"cells' noise sigma {sigma:.3g} N, and the cables' stretch is below the pose noise. EA is reported "
            f"at its nominal value and no effect seen only through the cables' strain (nonlinear_elasticity) is tried")
