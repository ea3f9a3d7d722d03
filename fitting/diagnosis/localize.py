"""Locate a model mismatch in whitened residuals: which measurement channel carries the
χ², which input or covariate it follows, where in the workspace, whether it is white in
sample order, and which samples are gross outliers.

All functions take the whitened residuals ``r`` ``(n, 6 + m [+ sensors])`` of
:func:`fitting.calibration.models.cdpr_residuals` (columns ``x y z rx ry rz t_1 … t_m``, then
``swivel_1 … swivel_m`` and ``roll pitch yaw`` when the recordings have them), so ``Σ r²`` is
the χ² against the ``[noise]`` sigmas. Plain numpy: this is bookkeeping.
"""

import numpy as np

from cstiffjax.io import schema
from fitting.calibration.models import measured_mask, residual_channels


def channel_labels(m: int, sensors: tuple[str, ...] = ()) -> list[str]:
    """Human-readable names of the residual columns: the quantity of the column's schema
    group and its name (``position x``, ``orientation rx``, ``tension t_3``, ``swivel angle
    swivel_2``)."""
    return [f"{schema.find(c, m).quantity} {c}" for c in residual_channels(m, sensors)]


def covariates(recordings, data) -> dict[str, np.ndarray]:
    """Candidate explanatory variables per sample (name -> (n,)): inputs ``l0_i``, the
    external wrench, measured pose and tensions, the sag parameter ``sag_i = g l0_i / t_i``
    (m/kg; times the unknown mass per length it is the ``w·L/T`` of Yuan et al. 2015), the direction of the
    last length change ``dir_i``, ``time`` and every extra numeric column. Constant or
    non-finite columns are dropped."""
    out = {}
    l0 = np.asarray(recordings.l0)
    m = l0.shape[1]
    for field in ("l0", "wrench", "pose"):
        out.update(zip(schema.field_columns(field, m), np.asarray(getattr(recordings, field)).T, strict=True))
    if recordings.has_tensions:
        t = np.where(np.asarray(recordings.tension_mask), np.asarray(recordings.tensions), np.nan)
        for i, name in enumerate(schema.field_columns("tensions", m)):
            out[name] = t[:, i]
            out[f"sag_{i + 1}"] = 9.81 * l0[:, i] / np.where(t[:, i] > 0, t[:, i], np.nan)
    direction = np.asarray(data.ctx.direction)
    for i in range(m):
        out[f"dir_{i + 1}"] = direction[:, i]
    if np.all(np.isfinite(np.asarray(recordings.time))):
        out.update(zip(schema.field_columns("time", m), [np.asarray(recordings.time)], strict=True))
    for k, nm in enumerate(recordings.covariate_names):
        out[nm] = np.asarray(recordings.covariates)[:, k]
    return {k: v for k, v in out.items() if np.all(np.isfinite(v)) and np.ptp(v) > 0}


PROXY_R = 0.99
"""A covariate whose ``|Pearson r|`` with a channel's own reading is at least this is a
proxy of that reading (a tension set-point ``t_set_i`` that the load cell follows): no
driver of the channel's misfit."""


def readings(recordings, sensors: tuple[str, ...] = ()) -> np.ndarray:
    """``(n, 6 + m [+ sensors])`` the recorded value behind each residual column
    (:func:`~fitting.calibration.models.residual_channels` order: pose, tensions, swivel
    angles, AHRS), ``nan`` where it was not recorded."""
    def masked(values, mask):
        return np.where(np.asarray(mask, dtype=bool), np.asarray(values, dtype=float), np.nan)

    cols = [masked(recordings.pose, recordings.pose_mask), masked(recordings.tensions, recordings.tension_mask)]
    if "swivel" in sensors:
        cols.append(masked(recordings.swivel, recordings.swivel_mask))
    if "ahrs" in sensors:
        cols.append(masked(recordings.ahrs, recordings.ahrs_mask))
    return np.hstack(cols)


def derived_from(column: str) -> set[str]:
    """The covariates :func:`covariates` computes from the reading of ``column`` (the column
    itself; ``sag_i`` from ``t_i``)."""
    return {column} | ({f"sag_{column[2:]}"} if column.startswith("t_") else set())


def own_reading(residual, reading, cov: dict, column: str) -> tuple[float | None, list[str]]:
    """How a channel's misfit follows its own reading, and the covariates that are that
    reading: a residual (reading − prediction) follows its own reading whenever the
    prediction misses part of the reading's variation, so neither the reading nor a proxy
    of it (computed from it, :func:`derived_from`, or ``|r| ≥`` :data:`PROXY_R` with it, e.g.
    a set-point the reading tracks) says what drives the misfit.

    **Arguments:** ``residual``, ``reading`` ``(k,)`` of the kept samples; ``cov`` the
    covariates of those samples (name -> ``(k,)``); ``column`` the channel's recordings
    column (``t_3``).

    **Returns:** ``(r, names)``: the Pearson r of the residual with the reading (``None``
    when the reading was not recorded in every kept sample or is constant) and the names of
    the covariates to leave out (the column itself and its proxies).
    """
    ok = bool(np.all(np.isfinite(reading)) and np.ptp(reading) > 0)
    derived = derived_from(column)
    proxies = [name for name, v in cov.items() if name in derived or (ok and abs(pearson(v, reading)) >= PROXY_R)]
    return (pearson(residual, reading) if ok else None), proxies


def pearson(a, b) -> float:
    """Pearson correlation of two 1-D arrays (0 when either is constant)."""
    a, b = a - a.mean(), b - b.mean()
    den = np.sqrt(np.sum(a * a) * np.sum(b * b))
    return float(np.sum(a * b) / den) if den > 0 else 0.0


def lag1(a) -> float:
    """Lag-1 autocorrelation in sample order (≈ 0 for white residuals, ± 2/√n)."""
    a = a - a.mean()
    den = np.sum(a * a)
    return float(np.sum(a[1:] * a[:-1]) / den) if den > 0 else 0.0


def per_sample_chi2(r) -> np.ndarray:
    """χ² of each sample, ``(n,)``."""
    return np.sum(np.asarray(r) ** 2, axis=1)


def detect_outliers(r, keep, *, ratio: float = 20.0, z: float = 5.0, floor: float = 100.0,
                    max_fraction: float = 0.1) -> list[int]:
    """Samples whose χ² stands far above the rest (0-based indices).

    A sample is a gross outlier when its χ² exceeds ``ratio`` × the median sample χ²,
    ``floor``, and is ``z`` robust standard deviations (median/MAD of ``log χ²``) above
    the median; at most ``max_fraction`` of the samples (the largest), because many
    "outliers" are a structure, not a few bad readings.

    **Arguments:** ``r`` ``(n, 6+m)`` whitened residuals; ``keep`` ``(n,)`` bool, the
    samples to consider.
    """
    c = per_sample_chi2(r)
    idx = np.flatnonzero(keep)
    if len(idx) < 5:
        return []
    lc = np.log(np.maximum(c[idx], 1e-12))
    med = np.median(lc)
    mad = 1.4826 * np.median(np.abs(lc - med)) + 1e-9
    bad = idx[(c[idx] > ratio * np.exp(med)) & (c[idx] > floor) & ((lc - med) / mad > z)]
    bad = bad[np.argsort(-c[bad])][: int(max_fraction * len(idx))]
    return sorted(int(i) for i in bad)


def channel_shares(r, keep) -> np.ndarray:
    """Share of the χ² carried by each residual column, ``(6 + m,)``."""
    c = np.sum(np.asarray(r)[keep] ** 2, axis=0)
    return c / max(np.sum(c), 1e-300)


def regions(recordings, r, keep) -> list[dict]:
    """χ² share of each workspace octant (split at the median x, y, z of the measured
    positions), with its share of the samples, sorted by ``excess`` (χ² share / sample share)."""
    pos = np.asarray(recordings.pose)[:, :3]
    c = per_sample_chi2(r)
    med = np.median(pos[keep], axis=0)
    code = (pos > med).astype(int) @ np.array([4, 2, 1])
    out = []
    total = max(np.sum(c[keep]), 1e-300)
    for k in range(8):
        sel = keep & (code == k)
        if not np.any(sel):
            continue
        name = ", ".join(f"{ax}{'>' if (k >> (2 - j)) & 1 else '<'}{med[j]:.3g}" for j, ax in enumerate("xyz"))
        cs, ss = float(np.sum(c[sel]) / total), float(np.sum(sel) / np.sum(keep))
        out.append({"region": name, "share_of_chi2": cs, "share_of_samples": ss, "excess": cs / ss})
    return sorted(out, key=lambda d: -d["excess"])


def localize(recordings, data, r, keep, *, top: int = 6, min_share: float = 0.02) -> dict:
    """Where the χ² sits and what it follows.

    **Returns:** ``{"channels": [...], "own_readings": [...], "regions": [...],
    "whiteness": {...}}`` where each channel entry is ``{where, share_of_chi2,
    correlates_with, r, lag1}`` (formats.md §3 ``localization``), for the ``top`` columns
    with at least ``min_share`` of the χ², sorted by share; ``correlates_with`` is the
    covariate (:func:`covariates`) with the largest ``|Pearson r|`` against the signed
    residual of that column, leaving out the column's own reading and its proxies
    (:func:`own_reading`). ``own_readings`` (for the report), one per channel entry:
    ``{"r": the residual's r with its own reading or None, "not_drivers": [names left out]}``.
    """
    r = np.asarray(r)
    keep = np.asarray(keep, dtype=bool)
    m = recordings.num_cables
    labels, columns = channel_labels(m, data.sensors), residual_channels(m, data.sensors)
    shares = channel_shares(r, keep)
    cov = {name: v[keep] for name, v in covariates(recordings, data).items()}
    own = readings(recordings, data.sensors)[keep]
    entries, owns = [], []
    for j in np.argsort(-shares)[:top]:
        if shares[j] < min_share:
            break
        res = r[keep, j]
        own_r, left_out = own_reading(res, own[:, j], cov, columns[j])
        best, best_r = None, 0.0
        for name, v in cov.items():
            rho = pearson(res, v)
            if name not in left_out and abs(rho) > abs(best_r):
                best, best_r = name, rho
        entries.append({"where": labels[j], "share_of_chi2": float(shares[j]), "correlates_with": best,
                        "r": float(best_r), "lag1": lag1(res)})
        owns.append({"r": own_r, "not_drivers": left_out})
    chi = per_sample_chi2(r)[keep]
    whiteness = {"lag1_sample_chi2": lag1(chi),
                 "lag1_by_channel": {labels[j]: lag1(r[keep, j]) for j in range(r.shape[1])},
                 "bound_95": 2.0 / np.sqrt(max(int(np.sum(keep)), 1))}
    return {"channels": entries, "own_readings": owns, "regions": regions(recordings, r, keep),
            "whiteness": whiteness}


def rms(r, keep, noise, recordings, sensors: tuple[str, ...] = ()) -> dict[str, float | None]:
    """Physical RMS of the residuals over the measured values: position (m), rotation
    (rad), tension (N) and, when recorded, ``swivel`` (rad) and ``ahrs`` (rad, the three
    angles pooled); ``None`` for a channel that was not measured."""
    r, mask = np.asarray(r)[keep], measured_mask(recordings, sensors)[keep]
    m = recordings.num_cables
    spans = {"position": (slice(0, 3), noise.position), "rotation": (slice(3, 6), noise.rotation),
             "tension": (slice(6, 6 + m), noise.tension)}
    col = 6 + m
    for f, width in (("swivel", m), ("ahrs", 3)):
        if f in sensors:
            spans[f] = (slice(col, col + width), getattr(noise, f))
            col += width
    out = {}
    for name, (sl, sigma) in spans.items():
        rs, ms = r[:, sl], mask[:, sl]
        sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (rs.shape[1],))
        out[name] = float(np.sqrt(np.sum((rs * sigma)[ms] ** 2) / ms.sum())) if ms.any() else None
    return out
