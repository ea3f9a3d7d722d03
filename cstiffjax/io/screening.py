"""Screening of loaded recordings for readings no cable robot produces and for copied samples.

- :func:`negative_tensions`: a cable pulls and never pushes, so a load cell that reads
  below zero by more than :data:`NEGATIVE_SIGMAS` noise sigmas (the robot's ``[noise]
  tension``) has an offset, a sign error or a fault. Readings within that band of zero are
  noise around a slack or lightly loaded cable and pass.
- :func:`duplicate_groups`: samples whose commanded lengths, external wrench, session and
  readings (pose, tensions, CSJM moment, swivel angles, AHRS) are identical to the last
  digit are copies of one measurement (real repeats differ by the sensors' noise). They are one sample's worth of
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


def duplicate_groups(recordings) -> np.ndarray:
    """``(n,)`` group of each sample: samples with identical commanded lengths, wrench,
    session and readings (pose, recorded tensions, CSJM moment, swivel angles, AHRS; each
    where measured; ``time`` and covariates are not compared) share a group. Groups are
    numbered ``0, 1, ...`` in the order of their first sample, so recordings without copies
    get ``arange(n)``."""
    def masked(values, mask):
        values, mask = np.asarray(values, dtype=float), np.asarray(mask, dtype=bool)
        return [np.where(mask, values, 0.0), mask.astype(float)]

    key = np.hstack([np.asarray(recordings.l0, dtype=float), np.asarray(recordings.wrench, dtype=float),
                     *masked(recordings.pose, recordings.pose_mask),
                     *masked(recordings.tensions, recordings.tension_mask),
                     np.asarray(recordings.moment, dtype=float),
                     *masked(recordings.swivel, recordings.swivel_mask),
                     *masked(recordings.ahrs, recordings.ahrs_mask),
                     np.asarray(recordings.session, dtype=float)[:, None]]) + 0.0  # -0.0 -> 0.0
    if key.shape[0] == 0:
        return np.zeros(0, dtype=int)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    rank = np.empty(first.size, dtype=int)
    rank[np.argsort(first)] = np.arange(first.size)
    return rank[np.asarray(inverse).reshape(-1)]


def distinct(recordings, rows=None, groups=None):
    """The first sample of each set of copies (:func:`duplicate_groups`), in file order: the
    samples a fit or a diagnosis counts, each distinct measurement once (``n`` copies of one
    reading are one reading's worth of evidence, and counted ``n`` times they would turn
    noise into "significant" structure).

    **Returns:** ``(recordings, rows)``, unchanged (the same objects) when there are no copies;
    ``rows`` (file line of each sample, or ``None``) subset with the samples.
    """
    groups = duplicate_groups(recordings) if groups is None else np.asarray(groups)
    if groups.size == 0 or int(groups.max()) + 1 == groups.size:
        return recordings, rows
    keep = np.sort(np.unique(groups, return_index=True)[1])
    return recordings.select(keep), None if rows is None else [rows[i] for i in keep]


def duplicate_samples(recordings, groups=None, rows=None) -> list[str]:
    """One sentence naming the samples that are copies of an earlier one (``[]`` when
    there is none; ``groups`` from :func:`duplicate_groups`, ``rows`` as in
    :func:`negative_tensions`)."""
    rows = _rows_of(recordings, rows)
    groups = duplicate_groups(recordings) if groups is None else np.asarray(groups)
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
    return [f"{recordings.source}: {n - distinct} of {n} samples are exact copies of another (identical commanded "
            f"lengths, wrench and readings; {distinct} distinct): {listed}. Copies add no information: a fit "
            f"or a diagnosis counts each distinct sample once (the first of its copies)"]


def recordings_warnings(recordings, robot, rows=None) -> list[str]:
    """The sentences of :func:`negative_tensions` (with ``robot.noise.tension``) and
    :func:`duplicate_samples` for ``recordings`` recorded on ``robot``."""
    return negative_tensions(recordings, float(robot.noise.tension), rows) + duplicate_samples(recordings, rows=rows)
