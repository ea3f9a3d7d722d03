"""Screening of loaded recordings for readings no cable robot produces and for copied samples.

- :func:`negative_tensions`: a cable pulls and never pushes, so a load cell that reads
  below zero by more than :data:`NEGATIVE_SIGMAS` noise sigmas (the robot's ``[noise]
  tension``) has an offset, a sign error or a fault. Readings within that band of zero are
  noise around a slack or lightly loaded cable and pass.
- :func:`duplicate_groups`: samples whose commanded lengths, external wrench, session and
  readings (pose, tensions, CSJM moment, swivel angles, AHRS) agree to within
  :data:`NEAR_COPY_SIGMAS` (a millionth) of each channel's noise sigma are copies of one
  measurement (real repeats differ by the sensors' noise; a copy rewritten with a rounding
  error is still a copy). They are one sample's worth of
  information: a held-out check that puts one copy in the training folds and another in
  the test fold scores the fit on its own training data, and a statistic that counts
  each copy turns noise into "significant" structure: :func:`distinct` keeps the first
  of each set of copies, which ``fit`` and ``diagnose`` use.
- :func:`recordings_warnings`: both, as the sentences ``check`` and ``diagnose`` report.

Samples are named by file line when the recordings know them (``rows``, header = line 1)
and by 1-based position otherwise.
"""

import numpy as np

from cstiffjax.io import schema

NEGATIVE_SIGMAS = 5.0
"""A tension reading below ``-NEGATIVE_SIGMAS`` noise sigmas is reported (a one-sided 5 σ
false-alarm rate of 3e-7 per reading of a slack cable)."""

SHOWN = 8  # rows named in one warning; the rest are counted


def _name(i: int, rows) -> str:
    return f"line {rows[i]}" if rows else f"sample {i + 1}"


def _rows_of(recordings, rows):
    return list(recordings.rows if rows is None else rows)


def negative_tensions(recordings, sigma: float, rows=None) -> list[str]:
    """One sentence naming the tension readings below ``-NEGATIVE_SIGMAS · sigma`` (``[]``
    when there is none).

    **Arguments:** ``recordings``: a :class:`~cstiffjax.io.recordings.Recordings`;
    ``sigma``: the load cells' noise standard deviation, N (the robot's ``noise.tension``);
    ``rows``: the file line of each sample (default ``recordings.rows``; empty: samples are
    named by position).

    **Returns:** ``[]`` or ``[sentence]``: the count, the first :data:`SHOWN` readings as
    ``line L, column 't_j': value N`` (most negative first), sigma and the likely causes.
    """
    rows = _rows_of(recordings, rows)
    t = np.asarray(recordings.tensions, dtype=float)
    bad = np.asarray(recordings.tension_mask, dtype=bool) & (t < -NEGATIVE_SIGMAS * float(sigma))
    if not bad.any():
        return []
    where = np.argwhere(bad)
    where = where[np.argsort(t[bad], kind="stable")]
    shown = "; ".join(f"{_name(int(i), rows)}, column '{schema.cable_column('t', int(j) + 1)}': {t[i, j]:.6g} N"
                      for i, j in where[:SHOWN])
    more = f"; and {len(where) - SHOWN} more" if len(where) > SHOWN else ""
    return [f"{recordings.source}: {len(where)} measured tension(s) below zero by more than {NEGATIVE_SIGMAS:g} "
            f"noise sigmas (sigma = {float(sigma):.6g} N, the robot's [noise] tension): {shown}{more}. A cable "
            f"cannot push: a load-cell zero offset (the diagnosis's tension_sensor_bias), a sign error or a "
            f"faulty channel?"]


NEAR_COPY_SIGMAS = 1e-6
"""Two samples are copies when every compared value agrees to within ``NEAR_COPY_SIGMAS``
of its channel's noise sigma (the robot's ``[noise]``): a millionth of the noise, far below
any real repeat and far above the rounding of a rewritten file (``t_1 × (1 + 1e-12)``)."""


def _columns(recordings, noise):
    """``(values (n, k), scale (k,))``: the compared values, each with its noise sigma
    (``0``: compared exactly: masks, session, channels without a stated sigma)."""
    def masked(values, mask):
        values, mask = np.asarray(values, dtype=float), np.asarray(mask, dtype=bool)
        return np.where(mask, values, 0.0), mask.astype(float)

    if noise is None:
        pos = rot = ten = mom = swi = np.nan
        ahrs = np.full(3, np.nan)
    else:
        pos, rot, ten, mom, swi = (float(getattr(noise, k)) for k in ("position", "rotation", "tension", "moment",
                                                                       "swivel"))
        ahrs = np.asarray(noise.ahrs, dtype=float)
    l0 = np.asarray(recordings.l0, dtype=float)
    pose, pose_m = masked(recordings.pose, recordings.pose_mask)
    t, t_m = masked(recordings.tensions, recordings.tension_mask)
    moment = np.asarray(recordings.moment, dtype=float)
    sw, sw_m = masked(recordings.swivel, recordings.swivel_mask)
    ah, ah_m = masked(recordings.ahrs, recordings.ahrs_mask)
    session = np.asarray(recordings.session, dtype=float)[:, None]
    parts = [(l0, pos), (np.asarray(recordings.wrench, dtype=float), [ten] * 3 + [ten] * 3),  # moments: σ_t × 1 m
             (pose, [pos] * 3 + [rot] * 3), (pose_m, 0.0), (t, ten), (t_m, 0.0), (moment, mom), (sw, swi),
             (sw_m, 0.0), (ah, ahrs), (ah_m, 0.0), (session, 0.0)]
    values = np.hstack([v for v, _ in parts]) + 0.0  # -0.0 -> 0.0
    scale = np.concatenate([np.broadcast_to(np.asarray(sc, dtype=float), (v.shape[1],)) for v, sc in parts])
    return values, np.where(np.isfinite(scale) & (scale > 0), scale, 0.0)


def _components(n: int, pairs) -> np.ndarray:
    """Connected components of the graph on ``n`` samples with edges ``pairs``: each sample's
    smallest member index (union-find)."""
    parent = np.arange(n)

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in pairs:
        a, b = root(i), root(j)
        if a != b:
            parent[max(a, b)] = min(a, b)
    return np.array([root(i) for i in range(n)], dtype=int)


def duplicate_groups(recordings, noise=None) -> np.ndarray:
    """``(n,)`` group of each sample: samples whose commanded lengths, wrench, session and
    readings (pose, recorded tensions, CSJM moment, swivel angles, AHRS; each where measured;
    ``time`` and covariates are not compared) agree share a group. "Agree": every value to
    within :data:`NEAR_COPY_SIGMAS` of its channel's sigma in ``noise`` (the robot's
    :class:`~cstiffjax.io.robot.Noise`; lengths by the position sigma, forces by the tension
    sigma, moments by the tension sigma × 1 m), the session and which values were measured
    exactly; a channel without a sigma (``noise=None``: every channel) is compared exactly.
    Chains of agreeing samples form one group. Groups are numbered ``0, 1, ...`` in the order
    of their first sample, so recordings without copies get ``arange(n)``."""
    values, scale = _columns(recordings, noise)
    n = values.shape[0]
    if n == 0:
        return np.zeros(0, dtype=int)
    # exact copies collapse first (tiled recordings: thousands of copies of each sample), so the
    # search for near copies runs over distinct rows only
    rows, inverse = np.unique(values, axis=0, return_inverse=True)
    tol = scale > 0
    exact = np.unique(rows[:, ~tol], axis=0, return_inverse=True)[1].reshape(-1)
    near = rows[:, tol] / (NEAR_COPY_SIGMAS * scale[tol])  # agreeing values differ by at most 1 here
    comp = _components(len(rows), _near_pairs(near, exact))[inverse.reshape(-1)]
    first = np.full(len(rows), n)
    np.minimum.at(first, comp, np.arange(n))  # each group's first sample
    _, rank = np.unique(first[comp], return_inverse=True)  # ascending first samples: the order of the file
    return rank.reshape(-1)


def _near_pairs(near: np.ndarray, exact: np.ndarray) -> list[tuple[int, int]]:
    """Pairs of rows whose exactly compared values are equal (same ``exact`` label) and whose
    scaled values ``near`` differ by at most 1 each; candidates from a sort on the row sums
    (agreeing rows' sums differ by at most ``near.shape[1]``), each row against its window at once."""
    proj = near.sum(axis=1)
    order = np.argsort(proj, kind="stable")
    stops = np.searchsorted(proj[order], proj[order] + near.shape[1], side="right")
    pairs = []
    for a, i in enumerate(order):
        cand = order[a + 1:stops[a]]
        if cand.size:
            ok = (exact[cand] == exact[i]) & np.all(np.abs(near[cand] - near[i]) <= 1.0, axis=1)
            pairs.extend((int(i), int(j)) for j in cand[ok])
    return pairs


def distinct(recordings, rows=None, groups=None, noise=None):
    """The first sample of each set of copies (:func:`duplicate_groups` with ``noise``, or the
    given ``groups``), in file order: the
    samples a fit or a diagnosis counts, each distinct measurement once (``n`` copies of one
    reading are one reading's worth of evidence, and counted ``n`` times they would turn
    noise into "significant" structure).

    **Returns:** ``(recordings, rows)``, unchanged (the same objects) when there are no copies;
    ``rows`` (file line of each sample, or ``None``) subset with the samples.
    """
    groups = duplicate_groups(recordings, noise) if groups is None else np.asarray(groups)
    if groups.size == 0 or int(groups.max()) + 1 == groups.size:
        return recordings, rows
    keep = np.sort(np.unique(groups, return_index=True)[1])
    return recordings.select(keep), None if rows is None else [rows[i] for i in keep]


def duplicate_samples(recordings, groups=None, rows=None, noise=None) -> list[str]:
    """One sentence naming the samples that are copies of an earlier one (``[]`` when
    there is none; ``groups`` from :func:`duplicate_groups` (default: of ``noise``), ``rows``
    as in :func:`negative_tensions`); it says how close a copy is (``noise``: within
    :data:`NEAR_COPY_SIGMAS` of each channel's sigma; ``None``: identical)."""
    rows = _rows_of(recordings, rows)
    groups = duplicate_groups(recordings, noise) if groups is None else np.asarray(groups)
    n, distinct = groups.size, int(groups.max()) + 1 if groups.size else 0
    if distinct == n:
        return []
    parts = []
    for g in range(distinct):
        members = np.flatnonzero(groups == g)
        if members.size > 1:
            copies = [_name(int(i), rows) for i in members[1:]]
            shown = ", ".join(copies[:SHOWN]) + (f" and {len(copies) - SHOWN} more" if len(copies) > SHOWN else "")
            parts.append(f"{_name(int(members[0]), rows)} is repeated at {shown}")
    listed = "; ".join(parts[:SHOWN]) + (f"; and {len(parts) - SHOWN} more groups" if len(parts) > SHOWN else "")
    how = ("identical commanded lengths, wrench and readings" if noise is None else
           f"commanded lengths, wrench and readings equal to within {NEAR_COPY_SIGMAS:g} of each channel's noise "
           f"sigma")
    return [f"{recordings.source}: {n - distinct} of {n} samples are copies of another ({how}; {distinct} "
            f"distinct): {listed}. Copies add no information: a fit or a diagnosis counts each distinct sample once "
            f"(the first of its copies)"]


def recordings_warnings(recordings, robot, rows=None) -> list[str]:
    """The sentences of :func:`negative_tensions` (with ``robot.noise.tension``) and
    :func:`duplicate_samples` for ``recordings`` recorded on ``robot``."""
    return negative_tensions(recordings, float(robot.noise.tension), rows) + duplicate_samples(
        recordings, rows=rows, noise=robot.noise)
