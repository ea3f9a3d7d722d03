"""The report's words: one table from the diagnosis's internal names (effects, grammar terms
``term:where|form|driver|sharing``, drivers ``cov:k``, ``dir_i``, ``sag_i``, recordings
columns) to plain language, and what a lab should check next after a verdict.

The effects' own sentences are their ``summary`` (:data:`fitting.effects.EFFECTS`,
formats.md §3); the recordings columns' are their schema quantity
(:mod:`cstiffjax.io.schema`). Plain strings: the report escapes them.
"""

import re

from cstiffjax.io import schema
from fitting.effects import EFFECTS
from fitting.effects.grammar import POSE_NAMES, WRENCH_NAMES

_FORMS = {"offset": "a constant offset", "gain": "a scale (gain) error", "linear": "an error linear in {d}",
          "cgain": "a gain that changes with {d}", "step": "a step with the direction of each cable's last move",
          "quadratic": "an error quadratic in the value itself"}
_WHERES = {"l0": "the commanded cable lengths", "tension": "the load-cell readings", "EA": "the cables' stiffness EA",
           "load": "the whole external wrench", "anchors": "the anchor geometry",
           "attachments": "the attachment geometry"}
_DRIVERS = {"time": "time since the session's start", "index": "the sample number",
            "own_l0": "each cable's own commanded length", "dir": "the direction of each cable's last move"}

CHECKS = {
    "cable_mass": "weigh a metre of cable and set `mass_per_length`; run the fit with `--law catenary`",
    "anchor_offset": "re-measure the exit points (anchors) with the tracker or a tape and correct the description",
    "length_offset": "re-home the winch encoders (length zeros) and correct the commanded lengths' offsets",
    "length_drift": "look for creep or slip of the cables on the drums: repeat one pose at the start and the end",
    "tension_sensor_bias": "re-zero the load cells with the cables unloaded",
    "pose_frame_offset": "re-register the tracker's frame to the base (measure the base markers again)",
    "exit_friction": "check the exit eyelets or pulleys for friction; record poses approached from both sides",
    "nonlinear_elasticity": "measure the cables' force-strain curve (a tensile test) and use a nonlinear law",
    "platform_mass": "weigh the platform with its payload and measure its centre of mass",
    "pulley_kinematics": "state the pulleys' radii and swivel axes in the description (`pulley_radius`, `pulley_axis`)",
    "length_gain": "calibrate the winch transmission: command a known length change and measure it",
    "tension_sensor_gain": "recalibrate the load cells' gains with a reference weight",
    "attachment_offset": "re-measure the attachment points on the platform and correct the description",
}
"""What a lab does about each effect the verdict names (keyed like :data:`fitting.effects.EFFECTS`)."""


def _column(name: str) -> str | None:
    """Words for a recordings column (``t_3`` -> ``tension of cable 3``), None if not one."""
    group = schema.find(name)
    if group is None:
        return None
    cable = re.fullmatch(r"[a-z0-9]+_(\d+)", name) if group.per_cable else None
    return f"{group.quantity} of cable {cable.group(1)}" if cable else f"{group.quantity} {name}"


def _term(name: str, covariate_names) -> str:
    """Words for a grammar term ``term:where[row]|form|driver|sharing``."""
    where, form, driver, sharing = name[len("term:"):].split("|")
    row = re.fullmatch(r"(\w+)\[(\d+)\]", where)
    if row:
        base, k = row.group(1), int(row.group(2))
        names = WRENCH_NAMES if base == "wrench" else POSE_NAMES
        target = f"the {'' if base == 'wrench' else 'measured '}{schema.find(names[k]).quantity} {names[k]}"
    else:
        target = _WHERES.get(where, where)
    d = "-" if driver == "-" else words(driver, covariate_names)
    text = f"{_FORMS.get(form, form).format(d=d)} of {target}"
    return text + {"per_cable": ", one per cable", "shared": ", one for all cables"}.get(sharing, "")


def words(name, covariate_names=()) -> str:
    """Plain words for an internal name of the diagnosis: a vocabulary effect (its summary),
    a grammar term, a driver (``cov:k`` the ``k``-th covariate of ``covariate_names``,
    ``w:j`` a wrench component, ``t:i`` a predicted tension, ``own_l0``, ``dir``), a
    localization covariate (``dir_i``, ``sag_i``, ``time``, a recordings column) or, when
    none of these, the name itself.

    **Arguments:** ``name``: the name (``None`` gives ``"-"``); ``covariate_names``: the
    recordings' covariate columns (for ``cov:k``).

    **Returns:** a short phrase, unescaped.
    """
    if name is None:
        return "-"
    name = str(name)
    if name in EFFECTS:
        return EFFECTS[name].summary
    if name.startswith("term:") and name.count("|") == 3:
        return _term(name, covariate_names)
    if name in _DRIVERS:
        return _DRIVERS[name]
    cov = re.fullmatch(r"cov:(\d+)", name)
    if cov:
        k = int(cov.group(1))
        return f"the covariate {covariate_names[k]}" if k < len(covariate_names) else f"covariate {k + 1}"
    if re.fullmatch(r"w:\d+", name) and int(name[2:]) < len(WRENCH_NAMES):
        return words(WRENCH_NAMES[int(name[2:])])
    if re.fullmatch(r"t:\d+", name):
        return f"the predicted tension of cable {int(name[2:]) + 1}"
    special = re.fullmatch(r"(dir|sag|t_set)_(\d+)", name)
    if special:
        kind, i = special.groups()
        return {"dir": f"the direction of cable {i}'s last length change (+1 paid out, -1 hauled in)",
                "sag": f"the sag parameter of cable {i}, g·l0_{i}/t_{i} (m/kg)",
                "t_set": f"the tension set-point of cable {i}"}[kind]
    return _column(name) or name


def described(name, covariate_names=()) -> str:
    """``name (words)``, or just ``name`` when the words are the name."""
    w = words(name, covariate_names)
    return str(name) if w == str(name) else f"{name} ({w})"


def own_reading_notes(localization: dict) -> list[str]:
    """One sentence per localized channel whose misfit follows its own reading
    (``|r| ≥ 0.5``; :func:`fitting.diagnosis.localize.own_reading`), saying what that means."""
    out = []
    for e, own in zip(localization["channels"], localization.get("own_readings", []), strict=False):
        if own["r"] is not None and abs(own["r"]) >= 0.5:
            left = ", ".join(own["not_drivers"])
            out.append(f"{e['where']}: the misfit follows its own reading (r {own['r']:.2f}): the prediction misses "
                       f"part of this reading's variation, as a scale (gain) error of the sensor, or of what sets "
                       f"the reading, would make. Its reading and its proxies ({left}) are not taken for drivers.")
    return out


def next_checks(d, value=None) -> list[str]:
    """The report's closing advice, one item a line, from the verdict of the diagnosis ``d``
    (:class:`~fitting.diagnosis.diagnose.Diagnosis`): what to correct for each selected
    effect, sensor fault and discovered correction, and, when structure remains, where it is
    and which measurement would tell what drives it; ``value`` formats one estimated parameter
    (``{value, std, unit}`` -> text) to quote the sizes found. Plain text, unescaped."""
    names = d.covariate_names
    out = [f"{f.kind} of {f.to_json()['channel']} (corrected here from the recordings): repair or recalibrate that "
           f"channel, then record again" for f in d.sensor_faults]
    for e in d.effects:
        found = d.final.get("parameters", {}).get(e, {}) if value is not None else {}
        sizes = "; ".join(f"{nm} {value(p)}" for nm, p in found.items())
        out.append(f"{e} ({EFFECTS[e].summary}{'; found ' + sizes if sizes else ''}): "
                   f"{CHECKS.get(e, 'correct the description')}")
    out += [f"{e['interpretation']} ({e['term']}): find what ties {e['acts_on']} to {e['driver'] or 'it'}; hold "
            f"{e['driver'] or 'it'} constant in a repeat of these poses to confirm" for e in d.discovered]
    if not d.explained:
        remains = d.final.get("residual_localization") or d.localization["channels"]
        for e in remains[:2]:
            drv = e["correlates_with"]
            by = (f"follows {described(drv, names)} (r {e['r']:.2f}): repeat these poses with {drv} held "
                  f"constant, or spanning a wider range, to tell whether it drives it") if drv else \
                "follows no recorded input: record a candidate cause (temperature, time) alongside"
            out.append(f"still unexplained: {e['where']} carries {e['share_of_chi2']:.0%} of the remaining χ² and {by}")
    elif not d.effects and not d.discovered and not d.sensor_faults:
        out.append("nothing to correct: the description explains these recordings down to the noise; keep these "
                   "recordings as the reference for the next check")
    if d.outliers:
        out.append(f"look at the outlier rows {d.outliers} (a slipped marker, a cable off its pulley, a wrong load "
                   f"entry?): they were left out of every fit")
    return out
