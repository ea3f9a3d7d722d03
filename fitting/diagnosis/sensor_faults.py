"""Faults of the load cells, found before the physics is fitted: a fault changes what the
physics should be fitted to, and each has a physical look-alike (a saturated cell reads
like a gain error, a delayed one like noise) that must not be named in its place.

Each detector works on one tension channel's readings ``t`` (N), the recorded mask and the
baseline fit's predicted readings ``p`` (N) at the same samples (numpy, in time order):

- **saturation / stuck** (:func:`find_stuck`): one value read *exactly* on at least
  :data:`MIN_REPEATS` samples (continuous readings never repeat). At the channel's top with
  the predictions above it (their mean excess over the value, in units of the channel's
  noise, ``z >=`` :data:`Z_SATURATION`): ``saturation``; anywhere else, with predictions
  that spread over the rows far beyond the noise (χ² of their spread above its
  :data:`Z_SATURATION`-sigma bound): ``stuck``. Corrected by leaving those readings out.
- **exchanged pair** (:func:`find_exchanged`) and **delay** by 1..:data:`MAX_DELAY` whole
  samples (:func:`find_delays`): the corrected readings must fit the predictions far better
  than the recorded ones: the likelihood ratio with the variance free, ``N ln(χ²_0 / χ²_1)``
  over the ``N`` readings compared, at least :data:`LR_THRESHOLD`, and the correction
  removes at least :data:`MIN_EXPLAINED` of the channels' excess χ² (``χ²_0 - N``). On clean
  data a swap or a shift makes the fit far worse (different cables, different poses: the
  ratio is well below 1); on near-identical channels it is 1 within ``2/√N``, an LR of
  ``±2√N``. Corrected by swapping back / shifting back (the last readings of a shifted
  channel are left out).
- **quantization** (:func:`quantization_step`, :func:`find_quantization`): every reading on
  one grid ``k q`` (to 1e-6 of ``q``) with ``q >=`` :data:`QUANT_STEP` σ (the rounding then
  adds at least a third of the noise's variance); a finer grid (a file's decimals, a
  converter at the noise level) is no fault. Corrected by leaving the channel out (one
  tension σ holds for every channel).

:func:`check` runs them in that order on a baseline fit, corrects the recordings and
refits; the diagnosis then describes the corrected data. :func:`validate` checks the
``sensor_faults`` entries of the formats.md §3 document.
"""

from dataclasses import dataclass

import equinox as eqx
import numpy as np

from cstiffjax.io import schema

KINDS = ("saturation", "stuck", "exchanged", "delay", "quantization")
MIN_REPEATS = 3  # readings of one exact value that make a stuck/saturated channel
Z_SATURATION = 5.0  # predictions above the repeated value by this many σ (of their mean)
LR_THRESHOLD = 50.0  # N ln(χ²_0/χ²_1) an exchange or a delay must reach
MIN_EXPLAINED = 0.5  # share of the channels' excess χ² the correction must remove
MAX_DELAY = 3  # whole samples
QUANT_STEP = 2.0  # grid step, in tension σ, from which quantization is a fault
GRID_TOLERANCE = 1e-6  # of the step: a reading on the grid


@dataclass(frozen=True)
class SensorFault:
    """One fault: ``kind`` (:data:`KINDS`), ``channels`` (0-based cables), ``detail`` (a
    sentence with the numbers), ``rows`` (0-based samples whose readings it concerns, or
    None: the whole channel), ``value`` (the repeated value or grid step, N; shift in
    samples for a delay)."""

    kind: str
    channels: tuple[int, ...]
    detail: str
    rows: tuple[int, ...] | None = None
    value: float = 0.0

    def to_json(self) -> dict:
        """The formats.md §3 entry ``{kind, channel, detail, rows?}`` (``rows`` 1-based samples)."""
        out = {"kind": self.kind, "channel": ",".join(schema.cable_column("t", j + 1) for j in self.channels),
               "detail": self.detail}
        return out | ({} if self.rows is None else {"rows": [int(i) + 1 for i in self.rows]})


def _col(j) -> str:
    return schema.cable_column("t", j + 1)


def _lr(c0: float, c1: float, n: int) -> float:
    """Likelihood ratio (variance free) of χ² ``c0`` -> ``c1`` over ``n`` readings."""
    return float(n * np.log(max(c0, 1e-300) / max(c1, 1e-300)))


def _passes(c0: float, c1: float, n: int) -> bool:
    return n > 0 and _lr(c0, c1, n) >= LR_THRESHOLD and c0 - c1 >= MIN_EXPLAINED * (c0 - n)


def quantization_step(values) -> float | None:
    """The grid step ``q`` (N) every value of ``values`` lies on (``k q`` up to an offset, to
    :data:`GRID_TOLERANCE` of ``q``), the coarsest of the smallest gap between distinct values
    divided by 1..5; None when there are fewer than 3 distinct values or none fits."""
    u = np.unique(np.asarray(values, dtype=float))
    if u.size < 3:
        return None
    gaps = np.diff(u)
    tol = 1e-12 * max(1.0, float(np.max(np.abs(u))))
    gaps = gaps[gaps > tol]
    for k in range(1, 6):
        q = float(np.min(gaps)) / k
        x = gaps / q
        if np.all(np.abs(x - np.round(x)) < GRID_TOLERANCE + tol / q):
            return q
    return None


def find_quantization(t, mask, sigma: float) -> list[SensorFault]:
    """Channels of ``t`` (n, m) whose recorded readings (``mask``) lie on a grid of step at
    least :data:`QUANT_STEP` ``sigma`` (N)."""
    out = []
    for j in range(t.shape[1]):
        q = quantization_step(t[mask[:, j], j])
        if q is not None and q >= QUANT_STEP * sigma:
            out.append(SensorFault("quantization", (j,), f"{_col(j)} reads on a grid of {q:.4g} N, {q / sigma:.3g} "
                                   f"times its noise σ {sigma:.3g} N: its readings are left out", None, q))
    return out


def _noise(chi2_per_value, j, sigma, q=None) -> float:
    """The noise (N) of channel ``j``'s readings about the predictions: ``sigma`` times the
    misfit of the other channels (median χ² per reading, at least 1), plus the rounding of a
    grid ``q``."""
    others = np.delete(chi2_per_value, j)
    others = others[np.isfinite(others)]
    s2 = max(1.0, float(np.median(others))) if others.size else 1.0
    return float(np.sqrt(s2 * sigma**2 + (q or 0.0) ** 2 / 12.0))


def _chi2_per_value(t, mask, p, sigma) -> np.ndarray:
    r2 = np.where(mask, ((t - p) / sigma) ** 2, 0.0)
    cnt = mask.sum(0)
    return np.where(cnt > 0, r2.sum(0) / np.maximum(cnt, 1), np.nan)


def find_stuck(t, mask, p, sigma: float, grids=None) -> list[SensorFault]:
    """Channels reading one exact value on at least :data:`MIN_REPEATS` samples while the
    predictions ``p`` move: ``saturation`` (the channel's largest reading, the predictions above
    it by ``z >=`` :data:`Z_SATURATION`) or ``stuck`` (the predictions' χ² about their mean on
    those rows beyond ``k + Z_SATURATION √(2k)``, ``k`` = rows - 1). ``grids`` {channel: step}:
    the quantization steps found (their rounding widens the noise)."""
    out, c2 = [], _chi2_per_value(t, mask, p, sigma)
    for j in range(t.shape[1]):
        rec = np.flatnonzero(mask[:, j])
        if rec.size < MIN_REPEATS:
            continue
        vals, counts = np.unique(t[rec, j], return_counts=True)
        s = _noise(c2, j, sigma, (grids or {}).get(j))
        for v in vals[counts >= MIN_REPEATS]:
            rows = rec[t[rec, j] == v]
            d = p[rows, j] - v
            z = float(np.sum(d) / (s * np.sqrt(rows.size)))
            if v == vals[-1] and z >= Z_SATURATION and np.mean(d > 0) >= 0.5:
                out.append(SensorFault("saturation", (j,), f"{_col(j)} reads its largest value {v:.6g} N on "
                                       f"{rows.size} samples whose predicted readings lie above it (by "
                                       f"{np.mean(d):.3g} N on average, z {z:.3g}): the load cell saturates; "
                                       f"these readings are left out", tuple(rows.tolist()), float(v)))
                continue
            k = rows.size - 1
            spread = float(np.sum(((d - np.mean(d)) / s) ** 2))
            if spread > k + Z_SATURATION * np.sqrt(2 * k):
                out.append(SensorFault("stuck", (j,), f"{_col(j)} reads {v:.6g} N on {rows.size} samples whose "
                                       f"predicted readings spread over {np.ptp(p[rows, j]):.3g} N (χ² {spread:.3g} "
                                       f"on {k} degrees of freedom): the reading is stuck; these readings are left "
                                       f"out", tuple(rows.tolist()), float(v)))
    return out


def find_exchanged(t, mask, p, sigma: float) -> list[SensorFault]:
    """Pairs of channels whose readings fit the predictions ``p`` far better exchanged
    (:func:`_passes`), best first, each channel in one pair at most."""
    m, found = t.shape[1], []
    for i in range(m):
        for j in range(i + 1, m):
            both = mask[:, i] & mask[:, j]
            n2 = 2 * int(both.sum())
            ti, tj, pi, pj = t[both, i], t[both, j], p[both, i], p[both, j]
            c0 = float(np.sum((ti - pi) ** 2 + (tj - pj) ** 2)) / sigma**2
            c1 = float(np.sum((tj - pi) ** 2 + (ti - pj) ** 2)) / sigma**2
            if _passes(c0, c1, n2):
                found.append((_lr(c0, c1, n2), i, j, c0, c1, n2))
    out, used = [], set()
    for lr, i, j, c0, c1, n2 in sorted(found, reverse=True):
        if used & {i, j}:
            continue
        used |= {i, j}
        out.append(SensorFault("exchanged", (i, j), f"{_col(i)} and {_col(j)} are exchanged: read the other way "
                               f"round they fit the predictions with χ² {c1:.4g} instead of {c0:.4g} on {n2} "
                               f"readings (likelihood ratio {lr:.4g}); swapped back"))
    return out


def find_delays(t, mask, p, sigma: float, valid=None) -> list[SensorFault]:
    """Channels whose reading of each sample appears ``s`` samples later (1 <= s <=
    :data:`MAX_DELAY`, the order of the rows): the readings ``s`` rows on fit the predictions
    ``p`` of the sample far better (:func:`_passes`; the best ``s`` of each channel).
    ``valid`` (n,): samples with predictions (default all)."""
    n, m = t.shape
    valid = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
    out = []
    for j in range(m):
        best = None
        for s in range(1, min(MAX_DELAY, n - 1) + 1):
            k = np.flatnonzero(valid[: n - s] & mask[: n - s, j] & mask[s:, j])
            c0 = float(np.sum((t[k, j] - p[k, j]) ** 2)) / sigma**2
            c1 = float(np.sum((t[k + s, j] - p[k, j]) ** 2)) / sigma**2
            if _passes(c0, c1, k.size) and (best is None or _lr(c0, c1, k.size) > best[0]):
                best = (_lr(c0, c1, k.size), s, c0, c1, k.size)
        if best is not None:
            lr, s, c0, c1, cnt = best
            out.append(SensorFault("delay", (j,), f"{_col(j)} reads each sample {s} sample(s) late: shifted back it "
                                   f"fits the predictions with χ² {c1:.4g} instead of {c0:.4g} on {cnt} readings "
                                   f"(likelihood ratio {lr:.4g}); shifted back, its last {s} reading(s) left out",
                                   None, float(s)))
    return out


def correct(t, mask, faults) -> tuple[np.ndarray, np.ndarray]:
    """``(t, mask)`` with ``faults`` undone: readings of stuck/saturated rows and quantized
    channels left out (mask false), exchanged pairs swapped back, delayed channels shifted back
    (their last readings left out)."""
    t, mask = np.array(t, dtype=float), np.array(mask, dtype=bool)
    n = t.shape[0]
    for f in faults:
        (j, *rest) = f.channels
        if f.kind in ("saturation", "stuck"):
            mask[list(f.rows), j] = False
        elif f.kind == "quantization":
            mask[:, j] = False
        elif f.kind == "exchanged":
            (i,) = rest
            t[:, [j, i]], mask[:, [j, i]] = t[:, [i, j]], mask[:, [i, j]]
        elif f.kind == "delay":
            s = int(f.value)
            t[: n - s, j], mask[: n - s, j] = t[s:, j], mask[s:, j]
            mask[n - s:, j] = False
    return t, mask


def find_faults(t, mask, p, sigma: float, valid=None) -> tuple[list[SensorFault], np.ndarray, np.ndarray]:
    """Every detector on readings ``t`` (n, m) N, ``mask`` (n, m), predictions ``p`` (n, m) N
    and the tension noise ``sigma`` (N); ``valid`` (n,): samples the baseline fitted (the
    others are not judged). Quantization and stuck/saturated readings first, then exchanged
    pairs on those corrected, then delays on those corrected.

    **Returns:** ``(faults, t, mask)``, the last two corrected (:func:`correct`)."""
    t, p, recorded = np.asarray(t, dtype=float), np.asarray(p, dtype=float), np.asarray(mask, bool)
    valid = np.ones(t.shape[0], bool) if valid is None else np.asarray(valid, bool)
    mask = recorded & valid[:, None]  # the readings judged
    faults = find_quantization(t, mask, sigma)
    faults += find_stuck(t, mask, p, sigma, {f.channels[0]: f.value for f in faults})
    tc, mc = correct(t, mask, faults)
    swaps = find_exchanged(tc, mc, p, sigma)
    tc, mc = correct(tc, mc, swaps)
    faults += swaps + find_delays(tc, mc, p, sigma, valid)
    return (faults, *correct(t, recorded, faults))  # once, from the recorded readings


def check(fitter, model, fit, weight, recordings):
    """The sensor-fault check of a diagnosis: :func:`find_faults` on the baseline ``fit``
    (``model``, a :class:`~fitting.effects.fit.MaskedFit` on ``weight``) of ``fitter``
    (:class:`~fitting.diagnosis.fitter.Fitter`); when a fault is found the fitter's recordings
    are replaced by the corrected ones and the baseline refitted.

    **Returns:** ``(faults, recordings, (model, fit))``: as given when nothing is found."""
    if not recordings.has_tensions:
        return [], recordings, (model, fit)
    sigma = float(fitter.robot.noise.tension)
    t, mask = np.asarray(recordings.tensions, dtype=float), np.asarray(recordings.tension_mask, bool)
    valid = (np.asarray(weight) > 0) & np.asarray(fit.ok, bool)
    p = np.where(mask, t - sigma * np.asarray(fit.r)[:, 6:6 + t.shape[1]], np.nan)
    faults, tc, mc = find_faults(t, mask, p, sigma, valid)
    if not faults:
        return [], recordings, (model, fit)
    corrected = eqx.tree_at(lambda r: (r.tensions, r.tension_mask), recordings, (tc, mc))
    fitter.use_recordings(corrected)
    return faults, corrected, fitter.fit([], weight, (model, fit.theta))


def validate(doc: dict) -> None:
    """Check the optional ``sensor_faults`` list of a formats.md §3 document: entries
    ``{kind, channel, detail, rows?}`` (``kind`` in :data:`KINDS`, ``channel`` and ``detail``
    strings, ``rows`` 1-based samples); raises ``ValueError`` naming the key."""
    faults = doc.get("sensor_faults", [])
    if not isinstance(faults, list):
        raise ValueError(f"diagnosis JSON: 'sensor_faults': must be a list, got {faults!r}")
    for i, f in enumerate(faults):
        p = f"sensor_faults[{i}]"
        if not isinstance(f, dict) or f.get("kind") not in KINDS:
            raise ValueError(f"diagnosis JSON: '{p}.kind': value {f.get('kind') if isinstance(f, dict) else f!r}; "
                             f"allowed: {', '.join(KINDS)}")
        for k in ("channel", "detail"):
            if not isinstance(f.get(k), str):
                raise ValueError(f"diagnosis JSON: '{p}.{k}': must be a string, got {f.get(k)!r}")
        rows = f.get("rows", [])
        if not (isinstance(rows, list) and all(isinstance(r, int) and not isinstance(r, bool)
                                               and 1 <= r <= doc.get("samples", 0) for r in rows)):
            raise ValueError(f"diagnosis JSON: '{p}.rows': must be a list of 1-based sample rows in "
                             f"1..{doc.get('samples')}, got {rows!r}")
