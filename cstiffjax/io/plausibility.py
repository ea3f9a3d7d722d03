"""Plausibility of a robot description and its recordings: the values a loader accepts
(finite, positive where required) but that cannot be what the user meant.

One implementation for every place that judges them: ``cstiffjax check`` (errors and
warnings before any work) and the diagnosis (the likeliest cause when samples have no
equilibrium, :func:`fitting.diagnosis.sample_checks.no_equilibrium_cause`).

- :func:`straight_distances`: anchor-attachment distances at measured poses (numpy).
- :func:`length_ratios`: per cable, the median of ``l0 / distance`` over the samples.
- :func:`unit_mismatch`: whether a ratio is a factor 1000 off (mm against m).
- :func:`cable_length_checks`: errors (a cable's lengths in mm, or not positive) and
  warnings (a cable much shorter or longer than its anchor-attachment distance), naming
  the cable's column, its median ``l0`` and distance.
- :func:`geometry_checks`: an anchor or attachment far outside the others (one point
  written in mm); gravity pointing up or of an implausible size; noise sigmas larger than
  any measurement system's (``noise.position = 20`` m).

All lengths are in m (formats.md §1, §2); ratios are unit-free.
"""

import numpy as np

from cstiffjax.io import schema

MM_BANDS = ((300.0, 3000.0), (3e-4, 3e-3))
"""Ratios (value / expected) that mean a factor 1000 off: mm written where m is expected, or m where mm."""

SHORT, LONG = 0.9, 1.1
"""Median ``l0 / distance`` outside ``[SHORT, LONG]``: the cable would stretch by >11 % or be slack."""

OUTLIER_FACTOR = 50.0
"""A point farther than this many times the others' spread from their median is an outlier."""

NOISE_LIMITS = {"position": (0.1, "m"), "rotation": (0.5, "rad")}
"""Largest plausible one-sigma noise per ``[noise]`` key (a measurement noise of 10 cm or
0.5 rad is no measurement); the tension sigma is judged against ``tension_max``."""

G = 9.80665
"""Standard gravity, m/s²."""


def _rotations(rotvec: np.ndarray) -> np.ndarray:
    """``(n, 3, 3)`` rotation matrices of rotation vectors ``(n, 3)`` rad (Rodrigues, numpy)."""
    theta = np.linalg.norm(rotvec, axis=1)[:, None, None]
    k = np.where(theta[..., 0] > 0, rotvec / np.where(theta[..., 0] > 0, theta[..., 0], 1.0), 0.0)
    K = np.zeros((len(rotvec), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K = K - np.transpose(K, (0, 2, 1))
    return np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * K @ K


def straight_distances(robot, poses) -> np.ndarray:
    """Straight anchor-attachment distances.

    **Arguments:** ``robot`` (anchors, attachments ``(m, 3)`` m); ``poses`` ``(n, 6)`` or
    ``(6,)``: position m and rotation vector rad, base frame.

    **Returns:** ``(n, m)`` distances, m (numpy).
    """
    poses = np.array(poses, dtype=float, ndmin=2)
    points = poses[:, None, :3] + np.einsum("nij,mj->nmi", _rotations(poses[:, 3:]), np.asarray(robot.attachments))
    return np.linalg.norm(np.asarray(robot.anchors)[None] - points, axis=-1)


def length_ratios(robot, l0, poses) -> np.ndarray:
    """Per cable, the median over the samples of ``l0 / straight distance``.

    **Arguments:** ``l0`` ``(n, m)`` commanded unstrained lengths, m; ``poses`` ``(n, 6)``.

    **Returns:** ``(m,)`` ratios (``nan`` for a cable whose distances are all zero).
    """
    dist = straight_distances(robot, poses)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(dist > 0, np.asarray(l0, dtype=float) / dist, np.nan)
    return np.nanmedian(r, axis=0) if np.any(np.isfinite(r)) else np.full(r.shape[1], np.nan)


def unit_mismatch(ratio: float) -> bool:
    """Whether ``ratio`` (a value over what was expected) is a factor ~1000 off (:data:`MM_BANDS`)."""
    return any(lo < ratio < hi for lo, hi in MM_BANDS)


def cable_length_checks(robot, l0, poses, where: str = "recordings", *,
                        units_only: bool = False) -> tuple[list[str], list[str]]:
    """Each cable's commanded lengths against its anchor-attachment distances.

    **Arguments:** ``robot``; ``l0`` ``(n, m)`` m and ``poses`` ``(n, 6)`` of the samples;
    ``where`` the file named in the messages; ``units_only``: the poses are a guess (no
    ``x y z`` recorded, formats.md §2 version 3): only the units are judged (a factor ~1000),
    not a stretch or slack.

    **Returns:** ``(errors, warnings)``, one sentence per cable, naming the cable's column,
    its median ``l0`` and distance (m). Errors: lengths zero or negative, or a factor ~1000
    off (mm against m). Warnings: median ratio outside ``[SHORT, LONG]``.
    """
    l0 = np.asarray(l0, dtype=float)
    dist = straight_distances(robot, poses)
    ratios = length_ratios(robot, l0, poses)
    errors, warnings = [], []
    for j, ratio in enumerate(ratios):
        col = schema.cable_column("l0", j + 1)
        lj, dj = float(np.median(l0[:, j])), float(np.median(dist[:, j]))
        at = "the frame's centre (no x y z recorded)" if units_only else "the recorded poses"
        said = f"{where}: column {col} (cable {j + 1}): median {lj:.6g} m against a median anchor-attachment " \
               f"distance of {dj:.6g} m at {at}"
        if np.any(l0[:, j] <= 0):
            errors.append(f"{where}: column {col} (cable {j + 1}): {int(np.sum(l0[:, j] <= 0))} lengths are zero or "
                          f"negative (e.g. {float(l0[np.argmax(l0[:, j] <= 0), j]):g} m); lengths must be > 0 m")
        elif not np.isfinite(ratio):
            continue
        elif unit_mismatch(ratio):
            errors.append(f"{said} ({ratio:.4g} times): wrong units (mm against m?); lengths are in m")
        elif units_only:
            continue
        elif ratio < SHORT:
            warnings.append(f"{said} (ratio {ratio:.3g}): the cable would stretch by {100 * (1 / ratio - 1):.0f}%; "
                            f"a missing length offset or wrong units?")
        elif ratio > LONG:
            warnings.append(f"{said} (ratio {ratio:.3g}): the cable would be slack; a length offset or wrong units?")
    return errors, warnings


def _outliers(points: np.ndarray) -> list[tuple[int, float, float]]:
    """``(index, distance from the others' median, their spread)`` of the points farther than
    :data:`OUTLIER_FACTOR` times the others' spread (median distance from their median, at
    least 1 mm) from the others' median."""
    out = []
    for k in range(len(points)):
        others = np.delete(points, k, axis=0)
        centre = np.median(others, axis=0)
        spread = float(np.median(np.linalg.norm(others - centre, axis=1)))
        d = float(np.linalg.norm(points[k] - centre))
        if len(others) >= 2 and d > OUTLIER_FACTOR * max(spread, 1e-3):
            out.append((k, d, spread))
    return out


def geometry_checks(robot, where: str = "robot") -> tuple[list[str], list[str]]:
    """Plausibility of the robot description itself.

    **Returns:** ``(errors, warnings)``. Errors: an anchor or attachment more than 300 times
    the others' spread away from their median (one point written in mm). Warnings: one more
    than :data:`OUTLIER_FACTOR` times away; gravity pointing up (a
    positive z component: the toolkit's z axis points up, gravity ``[0, 0, -9.81]``) or of
    a size other than ~9.81 m/s² (and not 0); ``[noise]`` sigmas above :data:`NOISE_LIMITS`
    or a tension sigma above ``tension_max``.
    """
    errors, warnings = [], []
    for key in ("anchor", "attachment"):
        points = np.asarray(getattr(robot, key + "s"), dtype=float)
        for k, d, spread in _outliers(points):
            text = (f"{where}: cable {k + 1}: {key} = {np.round(points[k], 6).tolist()} m lies {d:.4g} m from the "
                    f"other {key}s, which lie within {spread:.4g} m (median) of their median")
            if d > MM_BANDS[0][0] * max(spread, 1e-3):
                errors.append(text + ": written in mm instead of m? (lengths are in m)")
            else:
                warnings.append(text + ": a typo?")
    g = np.asarray(robot.gravity, dtype=float)
    gn = float(np.linalg.norm(g))
    if gn > 0 and g[2] > 0.5 * gn:
        warnings.append(f"{where}: gravity = {g.tolist()} points up (+z); z points up in this toolkit, "
                        f"so gravity is normally [0, 0, -9.81] m/s²")
    if gn > 0 and not 0.9 * G < gn < 1.1 * G:
        warnings.append(f"{where}: |gravity| = {gn:.6g} m/s², not ~{G:.4g} m/s²"
                        + (" (in mm/s²?)" if unit_mismatch(gn / G) else ""))
    noise = getattr(robot, "noise", None)
    for key, (limit, unit) in NOISE_LIMITS.items():
        value = float(getattr(noise, key, np.nan)) if noise is not None else np.nan
        if np.isfinite(value) and value > limit:
            warnings.append(f"{where}: noise.{key} = {value:g} {unit}: implausibly large for a one-sigma "
                            f"measurement noise (above {limit:g} {unit}); in mm or degrees instead of m or rad?")
    tension, tmax = float(getattr(noise, "tension", np.nan)), float(getattr(robot, "tension_max", np.inf))
    if np.isfinite(tension) and np.isfinite(tmax) and tension > tmax > 0:
        warnings.append(f"{where}: noise.tension = {tension:g} N is larger than tension_max = {tmax:g} N")
    return errors, warnings


__all__ = ["cable_length_checks", "geometry_checks", "length_ratios", "straight_distances", "unit_mismatch"]
