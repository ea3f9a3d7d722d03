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
  any measurement system's (``noise.position = 20`` m); and :func:`proportion_checks`.
- :func:`proportion_checks`: quantities of the description against each other (the
  anchors' spread against the attachments' spread and the pulley radii, the platform's
  weight against the cables' EA and ``tension_max``, ...): all anchors or all attachments
  written in mm.

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

PLATFORM_WIDER = 10.0
"""Attachments' spread over the anchors' spread above which a CDPR's platform is wider than
its frame can hold (an error; the attachments written in mm?)."""

FRAME_WIDER = (1e3, 3e3, 100.0)
"""Anchors' spread over the attachments' spread: above the first, a warning; above the
second with a frame wider than the third (m), an error (the anchors written in mm: a lab
robot's 3-40 becomes 3 000-40 000). The largest real robots (stadium cameras, ~400) stay below."""

CSJM_RATIO = 30.0
"""A CSJM's base and platform holes lie around one joint: spreads more than this many times
apart are an error."""

PULLEY_SHARE = 0.25
"""A pulley radius above this share of the anchors' spread is an error (pulleys that would
overlap their neighbours; the radius in mm?)."""

STRAIN = (0.1, 1.0)
"""Lower bound ``|weight| / sum(EA)`` on the strain of the most stretched cable: above the
first a warning, above the second (a cable stretched to twice its length) an error."""

LARGEST = 2e3
"""Anchors' spread (m) above which the robot is larger than any the toolkit is tested on
(benchmarks/LIMITS.md: cables of ~1 km); a warning."""

FINEST = 1e-8
"""``noise.position`` below this fraction of the anchors' spread is a warning (no position
measurement resolves 1e-8 of its range: lengths in mm with the noise in m?)."""

COMPACT = 1e-4
"""The largest principal inertia below this fraction of ``mass * (attachments' spread / 2)**2``
is a warning (a platform with its mass 1/100 of its size from the centre; lengths in mm?)."""


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
    more_errors, more_warnings = proportion_checks(robot, where)
    return errors + more_errors, warnings + more_warnings


def spread(points) -> float:
    """The largest distance between two of ``points`` ``(k, 3)``, m (0 for one point)."""
    p = np.asarray(points, dtype=float)
    return float(np.max(np.linalg.norm(p[:, None] - p[None], axis=-1)))


def _mm(ratio: float, typical: float) -> str:
    """The hint ending a message about a ratio whose usual value is ``typical``: ``"written
    in mm instead of m?"`` when it is 100 to 10 000 times that (a factor 1000 within the spread
    of real robots), else a typo or another unit slip."""
    return "written in mm instead of m?" if 1e2 < ratio / typical < 1e4 else "a typo or another unit slip?"


def _spread_checks(robot, where: str, big: float, small: float) -> tuple[list[str], list[str]]:
    """The anchors' spread ``big`` against the attachments' spread ``small`` (m)."""
    said = f"{where}: the anchors lie within {big:.4g} m of each other and the attachments within {small:.4g} m"
    if small == 0 or big == 0:
        return [], []
    if robot.kind == "csjm":
        ratio = max(big / small, small / big)
        if ratio > CSJM_RATIO:
            which = "anchors" if big > small else "attachments"
            hint = _mm(ratio, 1.0)
            return [f"{said}: {ratio:.4g} times apart, but both lie around the joint; the {which} {hint}"], []
        return [], []
    if small > PLATFORM_WIDER * big:
        return [f"{said}: a platform {small / big:.4g} times wider than its frame; the attachments "
                f"{_mm(small / big, 0.07)}"], []
    ratio = big / small
    text = (f"{said}: a frame {ratio:.4g} times wider than its platform (real robots: up to a few hundred); "
            f"the anchors {_mm(ratio, 15.0)}")
    if ratio > FRAME_WIDER[1] and big > FRAME_WIDER[2]:
        return [text], []
    if ratio > FRAME_WIDER[0]:
        return [], [text]
    return [], []


def _load_checks(robot, where: str, big: float) -> tuple[list[str], list[str]]:
    """The platform's weight against the cables' EA, ``tension_max`` and own weight."""
    errors, warnings = [], []
    weight = float(np.linalg.norm(np.asarray(robot.weight)))
    ea, m = float(np.sum(np.asarray(robot.EA))), robot.num_cables
    tmax = float(robot.tension_max)
    strain = weight / ea
    said = (f"{where}: the platform's weight {weight:.4g} N against the cables' total EA {ea:.4g} N: some cable "
            f"stretches by at least {100 * strain:.3g}% of its length (EA in kN, or the mass in g?)")
    if strain > STRAIN[1]:
        errors.append(said)
    elif strain > STRAIN[0]:
        warnings.append(said)
    if np.isfinite(tmax) and m * tmax < weight:
        errors.append(f"{where}: the platform's weight {weight:.4g} N is more than the {m} cables hold at "
                      f"tension_max = {tmax:.4g} N ({m * tmax:.4g} N together); tension_max "
                      + ("in kN instead of N?" if weight < 1e3 * m * tmax else "too low?"))
    mu = float(np.max(np.asarray(robot.mass_per_length)))
    g = float(np.linalg.norm(np.asarray(robot.gravity)))
    if np.isfinite(tmax) and mu * g * big / 2 > tmax:
        warnings.append(f"{where}: a cable of mass_per_length = {mu:.4g} kg/m across half the anchors' spread "
                        f"({big / 2:.4g} m) weighs {mu * g * big / 2:.4g} N, more than tension_max = {tmax:.4g} N; "
                        f"mass_per_length in g/m or the anchors in mm?")
    return errors, warnings


def proportion_checks(robot, where: str = "robot") -> tuple[list[str], list[str]]:
    """Quantities of the description against each other: unit slips no single range sees.

    **Arguments:** ``robot`` (a CDPR or CSJM description); ``where`` the file named in the
    messages.

    **Returns:** ``(errors, warnings)``, each naming the quantities that disagree and their
    values (SI). Errors: a CDPR platform wider than :data:`PLATFORM_WIDER` times its frame,
    a frame :data:`FRAME_WIDER` times its platform (the anchors in mm), a CSJM's holes
    :data:`CSJM_RATIO` apart, a pulley radius above :data:`PULLEY_SHARE` of the frame, a
    weight that stretches some cable beyond twice its length (:data:`STRAIN`) or that the
    cables cannot hold at ``tension_max``. Warnings: a frame 1000 times its platform, a
    strain above 10 %, a frame beyond :data:`LARGEST`, ``noise.position`` finer than
    :data:`FINEST` of the frame, an inertia too small for the platform's size
    (:data:`COMPACT`), a cable whose own weight across half the frame exceeds ``tension_max``.
    A description with every length in mm (anchors and attachments alike) keeps its
    proportions: only these warnings see it; its recordings' ``l0_i`` then do.
    """
    big, small = spread(robot.anchors), spread(robot.attachments)
    errors, warnings = _spread_checks(robot, where, big, small)
    radius = float(np.max(np.asarray(robot.pulley_radius)))
    if big > 0 and radius > PULLEY_SHARE * big:
        errors.append(f"{where}: pulley_radius = {radius:.4g} m against the anchors' spread of {big:.4g} m: pulleys "
                      f"wider than a quarter of the frame; the radius {_mm(radius / big, 0.01)}")
    more_errors, more_warnings = _load_checks(robot, where, big)
    errors, warnings = errors + more_errors, warnings + more_warnings
    if big > LARGEST:
        warnings.append(f"{where}: the anchors lie within {big:.4g} m of each other, larger than any robot the "
                        f"toolkit is tested on (~1 km); lengths written in mm instead of m?")
    position = float(getattr(robot.noise, "position", np.nan))
    if np.isfinite(position) and 0 < big and position < FINEST * big:
        warnings.append(f"{where}: noise.position = {position:g} m is {position / big:.2g} of the anchors' spread "
                        f"({big:.4g} m), finer than any position measurement; lengths written in mm instead of m?")
    inertia = np.asarray(robot.inertia, dtype=float)
    mass = float(robot.platform_mass)
    if robot.kind == "cdpr" and small > 0 and np.all(np.isfinite(inertia)):
        top = float(np.max(np.linalg.eigvalsh(0.5 * (inertia + inertia.T))))
        if top < COMPACT * mass * (small / 2) ** 2:
            warnings.append(f"{where}: inertia up to {top:.4g} kg m² for a {mass:.4g} kg platform whose attachments "
                            f"lie within {small:.4g} m: its mass within {np.sqrt(top / mass):.3g} m of the centre; "
                            f"lengths written in mm instead of m?")
    return errors, warnings


__all__ = ["cable_length_checks", "geometry_checks", "length_ratios", "proportion_checks", "spread",
           "straight_distances", "unit_mismatch"]
