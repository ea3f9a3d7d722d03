"""Reporting of discovered corrections (formats.md §3 ``discovered``): the term as a
formula, what it acts on, its driver, parameters with units, and a plain-language
interpretation from a table of known forms; the JSON check, the Markdown section and the
residual-against-driver figure's plan."""

import numpy as np

from cstiffjax.core.text import figure as figure_text
from cstiffjax.core.text import markdown as md
from cstiffjax.core.text import markdown_code as md_code
from cstiffjax.io import schema
from fitting.effects.grammar import POSE_NAMES, WRENCH_NAMES

KNOWN_UNITS = {"temperature": "K", "humidity": "%", "index": "sample", "pressure": "Pa"}  # beside the schema's
L0_I, T_I = schema.cable_column("l0", "i"), schema.cable_column("t", "i")


def _driver(term, names):
    """(name, unit, symbol) of the driver of ``term``."""
    k = term.driver
    if k is None:
        return None, None, None
    if k == "dir":
        return "dir_i", "1", "dir_i"
    if k == "own_l0":
        return L0_I, schema.unit(L0_I), L0_I
    if k.startswith("cov:"):
        nm = names[int(k[4:])]
        return nm, KNOWN_UNITS.get(nm, f"unit of {nm}"), nm
    if k.startswith("w:"):
        nm = WRENCH_NAMES[int(k[2:])]
        return nm, schema.unit(nm), nm
    if k.startswith("t:"):
        nm = schema.cable_column("t", int(k[2:]) + 1)
        return nm, schema.unit(nm), nm
    return k, schema.unit(k) or KNOWN_UNITS.get(k, "1"), k


def _quantity(term):
    """(symbol, unit, acts_on) of the quantity a term modifies."""
    f = term.family
    shared = "all cables" if not f.per_cable else "per cable"
    if f.where == "l0":
        return L0_I, schema.unit(L0_I), f"l0 ({shared})"
    if f.where == "tension":
        return T_I, schema.unit(T_I), f"measured tension ({shared})"
    if f.where == "EA":
        return "EA_i", "N", f"cable stiffness EA ({shared})"
    if f.where == "load":
        return "w", "N, N·m", "external wrench (all components)"
    if f.where == "wrench":
        nm = WRENCH_NAMES[term.row]
        return nm, schema.unit(nm), f"external wrench {nm}"
    if f.where == "pose":
        nm = POSE_NAMES[term.row]
        return f"{nm}_meas", schema.unit(nm), f"measured {schema.find(nm).quantity} {nm}"
    return f"{f.where[:-1]}_i", "m", f"{f.where} (all)"


def _unit(form, qu, du):
    return {"offset": qu, "step": qu, "gain": "1", "linear": f"{qu}/{du}", "cgain": f"1/{du}",
            "quadratic": f"1/{qu}"}[form]


def formula(term, centre) -> str:
    """The term as a formula, e.g. ``l0_i <- l0_i * (1 + a * (temperature - 22.1))``."""
    f = term.family
    x = _quantity(term)[0]
    a = "a_i" if f.per_cable else "a"
    name = _driver(term, ())[2] if term.driver and not term.driver.startswith("cov:") else None
    c = "" if centre is None else f"{float(np.mean(centre)):.4g}"
    if f.form == "offset":
        return f"{x} <- {x} + {a}"
    if f.form == "gain":
        return f"{x} <- {x} * (1 + {a})"
    if f.form == "step":
        return f"{x} <- {x} + {a} * dir_i"
    if f.form == "quadratic":
        return f"{x} <- {x} + {a} * ({x} - {'c_i' if np.ndim(centre) else c})^2"
    d = f"({name or '{driver}'} - {'mean_i' if term.driver == 'own_l0' else c})"
    return f"{x} <- {x} + {a} * {d}" if f.form == "linear" else f"{x} <- {x} * (1 + {a} * {d})"


def interpretation(term, driver, value, unit) -> str:
    """Plain-language reading of a term from the table of known forms."""
    f = term.family
    v = float(np.mean(value))
    key = (f.where, f.form)
    if key == ("l0", "cgain") and driver == "temperature":
        return (f"cable lengths change in proportion to temperature, as thermal expansion would make, "
                f"α = {v:.2g}/K")
    if key == ("EA", "cgain"):
        return (f"the cables' stiffness EA changes with {driver} ({100 * v:.2g}% per {unit.split('/')[-1]}), "
                f"as a cable's modulus does with its temperature")
    if key == ("l0", "cgain"):
        return f"cable lengths change in proportion to {driver} ({v:.2g} per {unit.split('/')[-1]})"
    if key == ("l0", "linear"):
        return f"cable lengths follow {driver} ({v:.3g} {unit})"
    if key == ("l0", "step"):
        return ("cable lengths depend on the direction of the last move (hysteresis or backlash in the winch "
                f"or the cable), step {np.abs(np.asarray(value)).mean() * 1e3:.2g} mm")
    if key == ("l0", "quadratic"):
        return "the commanded-length error grows quadratically with the length (a winding-radius change on the drum)"
    if key == ("load", "gain"):
        return f"the external loads were {abs(100 * v):.2g}% {'larger' if v > 0 else 'smaller'} than recorded"
    if f.where == "wrench":
        comp = WRENCH_NAMES[term.row]
        if f.form == "gain":
            return f"the recorded {comp} is off by {100 * v:.2g}% (load-measurement scale error)"
        if f.form == "offset":
            return f"an unrecorded constant {comp} of {v:.3g} {unit} acts on the platform"
        return f"an unrecorded {comp} that follows {driver or 'the load itself'} acts on the platform"
    if f.where == "pose":
        comp = POSE_NAMES[term.row]
        if f.form == "gain":
            return f"the pose tracker reads {comp} with a scale error of {v:.2g} ({v * 1e6:.0f} ppm)"
        if f.form == "linear" and driver and schema.find(driver) is schema.group("tension"):
            return f"the measured {comp} shifts with the tension of cable {driver[2:]} (a compliant tracker mount)"
        return f"the measured {comp} has an error that follows {driver or comp} ({v:.3g} {unit})"
    if f.where == "tension":
        if f.form == "linear":
            return f"the load cells drift with {driver} ({v:.3g} {unit})"
        if f.form == "cgain":
            return f"the load-cell gain changes with {driver} ({v:.3g} {unit})"
        if f.form == "quadratic":
            return "the load cells read nonlinearly (quadratic in the tension)"
        if f.form == "step":
            return "the load cells read differently after paying out and hauling in, per cable"
    if f.where in ("anchors", "attachments"):
        return f"the {f.where} are {abs(v) * 1e6:.0f} ppm {'farther from' if v > 0 else 'closer to'} the origin (scale)"
    return f"{_quantity(term)[2]}: {f.form} correction" + (f" driven by {driver}" if driver else "")


def describe(term, a, data, *, delta_bic: float, chi2_per_dof: float) -> dict:
    """The formats.md §3 ``discovered`` entry of ``term`` with fitted ``a``
    (``{value, std}`` from the diagnosis, physical units)."""
    specs = {s.name: s for s in term.family.specs(None, data)}
    centre = specs.get("centre")
    cval = None if centre is None else np.asarray(centre.null)
    if cval is not None and term.family.drivers:
        cval = cval[..., term.column]
    if cval is not None and term.row is not None and term.family.form == "quadratic":
        cval = cval[term.row]
    driver, du, _ = _driver(term, data.covariate_names)
    _qsym, qu, acts_on = _quantity(term)
    unit = _unit(term.family.form, qu, du or "1")
    text = formula(term, cval)
    if driver and "{driver}" in text:
        text = text.replace("{driver}", driver)
    return {"term": text, "acts_on": acts_on, "driver": driver,
            "parameters": {"a": {"value": a["value"], "std": a["std"], "unit": unit}},
            "delta_bic": delta_bic, "chi2_per_dof": chi2_per_dof,
            "interpretation": interpretation(term, driver, a["value"], unit), "key": term.name}


def validate_discovered(doc: dict) -> None:
    """Check the optional ``discovered`` key against formats.md §3 (``ValueError`` names the path)."""
    if "discovered" not in doc:
        return
    items = doc["discovered"]
    if not isinstance(items, list):
        raise ValueError(f"diagnosis JSON 'discovered': must be a list, got {items!r}")
    for i, e in enumerate(items):
        p = f"discovered[{i}]"
        if not isinstance(e, dict):
            raise ValueError(f"diagnosis JSON '{p}': must be an object, got {e!r}")
        for k, typ in (("term", str), ("acts_on", str), ("parameters", dict), ("interpretation", str)):
            if not isinstance(e.get(k), typ):
                raise ValueError(f"diagnosis JSON '{p}.{k}': missing or not a {typ.__name__}")
        if "driver" not in e or not (e["driver"] is None or isinstance(e["driver"], str)):
            raise ValueError(f"diagnosis JSON '{p}.driver': missing or not a string/null")
        for k in ("delta_bic", "chi2_per_dof"):
            if isinstance(e.get(k), bool) or not isinstance(e.get(k), int | float):
                raise ValueError(f"diagnosis JSON '{p}.{k}': missing or not a number")
        for nm, v in e["parameters"].items():
            if not isinstance(v, dict) or not {"value", "std", "unit"} <= set(v):
                raise ValueError(f"diagnosis JSON '{p}.parameters.{nm}': needs value, std and unit, got {v!r}")


def markdown_lines(diagnosis) -> list[str]:
    """Report section on discovered corrections and on what the residual checks found."""
    lines = []
    if diagnosis.discovered:
        lines += ["", "## Discovered corrections (outside the vocabulary)", "",
                  "| term | acts on | driver | a | ΔBIC | χ²/dof | interpretation |", "|---|---|---|---|---|---|---|"]
        for e in diagnosis.discovered:
            a = e["parameters"]["a"]
            v, s = np.ravel(a["value"]), np.ravel(a["std"])
            val = "; ".join(f"{x:.3g} ± {y:.2g}" for x, y in zip(v, s, strict=True))
            lines.append(f"| {md_code(e['term'])} | {md(e['acts_on'])} | {md(e['driver'] or '-')} | {val} "
                         f"{md(a['unit'])} | {e['delta_bic']:.1f} | {e['chi2_per_dof']:.4g} | "
                         f"{md(e['interpretation'])} |")
    chk = diagnosis.final.get("residual_checks")
    if chk and chk["structured"]:
        lines += ["", f"## Structure left in the residual ({len(chk['findings'])} of {chk['tests']} tests rejected, "
                      f"Holm, family-wise α = {chk['alpha']})", "", "| channel | test | against | statistic | p |",
                  "|---|---|---|---|---|"]
        for e in chk["findings"][:12]:
            lines.append(f"| {e['channel']} | {e['test']} | {md(e['driver'])} | {e['statistic']:.3g} | {e['p']:.2g} |")
    return lines


def considered_lines(d) -> list[str]:
    """The report's list of every candidate rejected on physical grounds (a bound, a size
    no hardware makes, an implausible correction, a look-alike of a named effect) and of the
    grammar corrections fitted in each round, with why each lost (empty when there are none)."""
    rows = [(it["round"], c) for it in d.iterations for c in it["tried"]
            if c.get("rejected_because") or c["effect"].startswith("term:")]
    if not rows:
        return []
    lines = ["", "## Corrections considered and why each lost", "", "| round | candidate | ΔBIC | outcome |",
             "|---|---|---|---|"]
    for rnd, c in rows:
        outcome = "selected" if c["accepted"] else c.get("rejected_because") or c["reason"]
        lines.append(f"| {rnd} | {md_code(c['effect'])} | {c['delta_bic']:.1f} | {md(outcome)} |")
    return lines


def figure_plans(diagnosis) -> list[tuple[str, dict]]:
    """``[(discovered_<k>.png, plan)]``: the plan (:func:`fitting.diagnosis.figure_render.discovered`)
    of the baseline and final residual of the localizing channel against each discovered
    term's driver (when the driver is a recorded column)."""
    from fitting.diagnosis.localize import channel_labels

    a = diagnosis.arrays
    if not diagnosis.discovered or "r_base" not in a:
        return []
    keep = np.asarray(a["keep"], bool)
    labels = channel_labels(a["robot"].num_cables, tuple(a.get("sensors", ())))
    ch = diagnosis.localization["channels"]
    j = labels.index(ch[0]["where"]) if ch else int(np.argmax(np.sum(a["r_base"][keep] ** 2, 0)))
    plans = []
    for k, e in enumerate(diagnosis.discovered):
        drv = e["driver"]
        if drv in (None, L0_I, "dir_i"):
            drv = ch[0]["correlates_with"] if ch else None
        x = a["covariates"].get(drv) if drv else None
        if x is None and drv == "index":
            x = np.arange(len(keep), dtype=float)
        if x is None:
            continue
        panels = [(np.asarray(r)[:, j], f"{title}: {labels[j]}")
                  for r, title in ((a["r_base"], "before (baseline)"), (a["r_final"], "after (with the term)"))]
        plans.append((f"discovered_{k + 1}.png", {"x": np.asarray(x, dtype=float), "keep": keep, "panels": panels,
                                                   "xlabel": figure_text(drv), "suptitle": figure_text(e["term"])}))
    return plans
