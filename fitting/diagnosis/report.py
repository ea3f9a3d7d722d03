"""Diagnosis output: the summary lines, the Markdown report and the report folder.

The report folder (:func:`write_report`) holds ``report.md``, ``diagnosis.json`` and the
figures, written atomically (:mod:`cstiffjax.io.atomic`). The JSON document and its
formats.md §3 check are in :mod:`fitting.diagnosis.diagnosis_json` (``document``,
``validate_diagnosis``, ``own_problems``, ``write_json``), the figures in
:mod:`fitting.diagnosis.report_figures` (``write_figures``, ``open_figures``,
``robot_view``); those names are importable from here too. Text from the inputs (the
robot's name, covariate names) is escaped in the report and the figures
(:mod:`cstiffjax.core.text`); the JSON keeps it as it is.
"""

from pathlib import Path

import numpy as np

from cstiffjax.core.text import markdown as md
from cstiffjax.core.text import markdown_code as md_code
from cstiffjax.io.atomic import output_folder, write_text
from fitting.diagnosis.diagnosis_json import document as document
from fitting.diagnosis.diagnosis_json import own_problems as own_problems
from fitting.diagnosis.diagnosis_json import validate_diagnosis as validate_diagnosis
from fitting.diagnosis.diagnosis_json import write_json as write_json
from fitting.diagnosis.discover_report import considered_lines as considered_markdown
from fitting.diagnosis.discover_report import markdown_lines as discovered_markdown
from fitting.diagnosis.report_figures import open_figures as open_figures
from fitting.diagnosis.report_figures import robot_view as robot_view
from fitting.diagnosis.report_figures import write_figures as write_figures
from fitting.diagnosis.report_words import described, next_checks, own_reading_notes
from fitting.effects import EFFECTS

# every entry a report folder may hold (:func:`write_report`; discovered_<k>.png: discover_report.figure_plans)
REPORT_PATTERNS = ("report.md", "diagnosis.json", "residuals.png", "chi2_shares.png", "robot.png", "discovered_*.png")


# ------------------------------------------------------------------ summary
def left_out(d) -> str:
    """Summary-line part naming the samples without equilibrium and the dropped rows (if any)."""
    out = ""
    if d.failed_samples["count"]:
        fs = d.failed_samples
        out += f"; no equilibrium (left out): {fs['count']} samples, " + (
            f"rows {fs['rows']}" if fs["rows"] is not None else f"samples {fs['samples']}")
    if d.dropped_rows["count"]:
        out += f"; dropped: {d.dropped_rows['count']} rows {d.dropped_rows['rows']}"
    return out


def summary_lines(d) -> list[str]:
    """The verdict in a few lines (what ``cstiffjax diagnose`` prints; the whole document is
    the JSON / report)."""
    b, f = d.baseline, d.final
    lines = [f"sensor    {s.kind} on {s.to_json()['channel']}: {s.detail} (corrected before the physics)"
             for s in getattr(d, "sensor_faults", [])]
    lines.append(f"baseline  chi2/dof {b['chi2_per_dof']:.4g} ({b['model']} law, EA calibrated, {d.samples} samples)")
    if d.effects:
        for e in d.effects:
            params = "; ".join(f"{nm} {_value(p)}" for nm, p in f["parameters"].get(e, {}).items())
            lines.append(f"effect    {e}: {params}")
    else:
        lines.append("effects   none selected")
    for e in d.discovered:  # corrections found outside the vocabulary
        lines.append(f"discovered {e['term']} ({e['interpretation']})")
    verdict = "yes" if d.explained else "NO: structured residual remains (see the report's 'What remains')"
    lines.append(f"explained {verdict}; final chi2/dof {f['chi2_per_dof']:.4g}")
    left = left_out(d)
    if d.outliers or left:
        lines.append(f"left out  outlier rows {d.outliers or 'none'}{left}")
    return lines


def unit_suffix(unit) -> str:
    """`` unit`` after a value; nothing for a dimensionless one (``"1"``, ``""``: a gain is
    ``1.042 ± 0.0021``, never ``1.042 ± 0.0021 1``)."""
    unit = "" if unit is None else str(unit).strip()
    return "" if unit in ("", "1", "-") else f" {unit}"


def _value(p) -> str:
    """``value ± std unit`` of one parameter; arrays shortened to their largest entry."""
    v, s = np.ravel(p["value"]).astype(float), np.ravel(p["std"]).astype(float)
    if v.size == 1:
        return f"{v[0]:.4g} ± {s[0]:.2g}{unit_suffix(p['unit'])}"
    k = int(np.argmax(np.abs(v)))
    return f"{v.size} values, largest |{v[k]:.4g}| ± {s[k]:.2g}{unit_suffix(p['unit'])}"


# ----------------------------------------------------------------- markdown
def _fmt_param(p):
    v, s = np.asarray(p["value"], dtype=float), np.asarray(p["std"], dtype=float)
    unit = md(unit_suffix(p["unit"]))
    if v.ndim == 0:
        return f"{float(v):.4g} ± {float(s):.2g}{unit}"
    rows = v.reshape(len(v), -1)
    srows = s.reshape(len(s), -1)
    return "<br>".join(f"[{i + 1}] " + ", ".join(f"{a:.4g} ± {b:.2g}" for a, b in zip(r, sr, strict=True))
                       + unit for i, (r, sr) in enumerate(zip(rows, srows, strict=True)))


def _posterior_line(effect, post):
    """One report line for the posterior check of a selected effect
    (:func:`fitting.diagnosis.effect_posterior.posterior_check`)."""
    flags = np.concatenate([np.ravel(p["null_outside_999"]) for p in post["parameters"].values()])
    z = np.concatenate([np.ravel(p["z_null"]) for p in post["parameters"].values()]).astype(float)
    tau = "n/a" if post["tau"] is None else f"{post['tau']:.2g}"
    chain = (f"acceptance {post['acceptance_fraction']:.2f}, τ {tau} steps, {post['walkers']} walkers × "
             f"{post['steps']} steps ({'≥' if post['converged'] else '**< (not converged; indicative only)**'} 50 τ)")
    agree = ("agrees with Gauss-Newton: null outside the joint 99.9% credible region" if post["agrees"] else
             "**disagrees with Gauss-Newton: null inside the joint 99.9% credible region** (effect kept, see JSON)")
    return (f"- **{effect}**: {agree} (tail {post['null_tail']:.2g} of {post['samples']} samples); "
            f"{int(flags.sum())}/{flags.size} parameters exclude the null from their 99.9% interval, "
            f"|z| of the null {np.min(np.abs(z)):.3g} to {np.max(np.abs(z)):.3g}; {chain}.")


def described_words(name, names=()) -> str:
    """The words of an internal name (:func:`fitting.diagnosis.report_words.words`), ``-``
    when they are only the name."""
    w = described(name, names)
    return w[len(str(name)) + 2:-1] if w != str(name) else "-"


def _localization_table(entries, names) -> list[str]:
    """The table of localized channels: share of χ², the driver with its words, r, lag-1."""
    lines = ["| channel | share of χ² | follows | r | lag-1 |", "|---|---|---|---|---|"]
    for e in entries:
        lines.append(f"| {md(e['where'])} | {e['share_of_chi2']:.2f} | {md(described(e['correlates_with'], names))} | "
                     f"{e['r']:.2f} | {e['lag1']:.2f} |")
    return lines


def _round_lines(it, names, shown: int = 8) -> list[str]:
    """A later round of the greedy search: its model, what it added, and its best candidates."""
    lines = ["", f"Round {it['round']} (model: baseline + {md(', '.join(it['model']))}, χ²/dof "
                 f"{it['chi2_per_dof']:.4g}): added {md(it['added'] or 'nothing')}."]
    tried = sorted(it.get("tried", []), key=lambda c: c["delta_bic"])[:shown]
    if tried:
        lines += ["", "| candidate | what it is | ΔBIC | χ²/dof | verdict |", "|---|---|---|---|---|"]
        lines += [f"| {md_code(c['effect'])} | {md(described_words(c['effect'], names))} | {c['delta_bic']:.1f} | "
                  f"{c['chi2_per_dof']:.4g} | {md(c.get('rejected_because') or c['reason'])} |" for c in tried]
        more = len(it.get("tried", [])) - len(tried)
        if more > 0:
            lines += ["", f"({more} more candidates with a higher ΔBIC; all in the JSON's `iterations`.)"]
    return lines


def markdown(diagnosis, figures=(), warnings=None) -> str:
    """The human-readable report (Markdown); ``warnings`` (default: those of :func:`document`)
    are listed under the verdict. Text from the inputs is escaped (:func:`cstiffjax.core.text.markdown`)."""
    d = diagnosis
    warnings = document(diagnosis).get("warnings", []) if warnings is None else warnings
    b, f = d.baseline, d.final
    verdict = ("the nominal model explains the recordings down to the noise" if not d.effects and d.explained
               else f"left out: **{', '.join(d.effects)}**" if d.effects else "no candidate effect explains it")
    if d.equivalent:  # a selected effect with a look-alike the recordings cannot tell from it
        verdict += " (" + "; ".join(f"{e}: {md(why)}" for e, why in d.equivalent.items()) + ")"
    if d.discovered:  # corrections outside the vocabulary
        verdict = (f"left out: **{', '.join(d.effects)}**; " if d.effects else "") + "discovered outside the " \
            "vocabulary: " + "; ".join(f"**{md(e['interpretation'])}** ({md_code(e['term'])})" for e in d.discovered)
    if d.sensor_faults:
        verdict = "sensor faults corrected (" + "; ".join(f"{f.kind} of {md(f.to_json()['channel'])}"
                                                       for f in d.sensor_faults) + "), then " + verdict
    lines = [f"# Mismatch diagnosis: {md(d.robot)}", "",
             f"{d.samples} samples, baseline cable law `{d.law.name}`, elapsed {d.elapsed_s:.1f} s.", "",
             f"**Verdict:** {verdict}; "
             f"{'explained' if d.explained else '**structured residual remains** (not explained)'} "
             f"(χ²/dof {b['chi2_per_dof']:.4g} → {f['chi2_per_dof']:.4g}).", ""]
    if warnings:
        lines += ["**Warnings**:", ""] + [f"- {md(w)}" for w in warnings] + [""]
    if d.sensor_faults:  # found before the physics; every fit below uses the corrected readings
        lines += ["**Sensor faults** (found before the physics; every fit below uses the corrected readings):", ""]
        lines += [f"- **{f.kind}** of {md(f.to_json()['channel'])}: {md(f.detail)}"
                  + (f" (sample rows {f.to_json()['rows']})" if f.rows is not None else "") + "."
                  for f in d.sensor_faults] + [""]
    if d.outliers:
        lines += [f"**Outliers** (left out of every fit): sample rows {d.outliers}.", ""]
    if d.failed_samples["count"]:
        fs = d.failed_samples
        which = f"file rows {fs['rows']}" if fs["rows"] is not None else f"samples {fs['samples']}"
        lines += [f"**No equilibrium in the nominal model** for {fs['count']} of {d.samples} samples ({which}); "
                  f"they are left out of every fit.", ""]
    if d.dropped_rows["count"]:
        lines += [f"**Dropped** {d.dropped_rows['count']} invalid row(s) of the recordings (drop_invalid): "
                  f"rows {d.dropped_rows['rows']}.", ""]
    if d.sorted_by_time:
        lines += ["**Sorted by time**: the rows were not in time order; sample numbers count in time order.", ""]
    for name, note in d.assumptions.items():  # e.g. the swivel axes pulley_kinematics assumed
        lines += [f"**Assumed** (`{name}`): {note}.", ""]

    onboard = [k for k in ("swivel", "ahrs") if k in b["rms"]]  # version-3 channels, when recorded

    def rms_row(name, r, c2):
        cells = ["n/a (not recorded)" if r.get(k) is None else f"{r[k]:.3g}"
                 for k in ("position", "rotation", "tension", *onboard)]
        return f"| {name} | {c2:.4g} | " + " | ".join(cells) + " |"

    heads = ["rms position (m)", "rms rotation (rad)", "rms tension (N)",
             *(f"rms {'swivel' if k == 'swivel' else 'AHRS'} (rad)" for k in onboard)]
    lines += ["## Fit", "", "| model | χ²/dof | " + " | ".join(heads) + " |", "|---" * (2 + len(heads)) + "|",
              rms_row("baseline (EA free)", b["rms"], b["chi2_per_dof"]),
              rms_row(" + ".join(["baseline", *d.effects]), f["rms"], f["chi2_per_dof"]), ""]
    names = d.covariate_names
    lines += ["## Where the baseline misfits", "", *_localization_table(d.localization["channels"], names)]
    notes = own_reading_notes(d.localization)
    if notes:
        lines += [""] + [f"- {md(n)}" for n in notes]
    reg = d.localization["regions"][:2]
    lines += ["", "Workspace regions with the most χ² per sample: " + "; ".join(
        f"{r['region']} ({r['share_of_chi2']:.0%} of χ², {r['share_of_samples']:.0%} of samples)" for r in reg), ""]
    lines += ["## Candidates (first round, against the baseline)", "",
              "| effect | what it is | ΔBIC | χ²/dof | Wald | held-out χ²/datum | verdict |",
              "|---|---|---|---|---|---|---|"]
    for c in d.candidates:
        cv = "" if c.cv is None else f"{c.cv:.4g} (baseline {c.cv_reference:.4g})"
        lines.append(f"| {md_code(c.effect)} | {md(described_words(c.effect, names))} | {c.delta_bic:.1f} | "
                     f"{c.chi2_per_dof:.4g} | {c.wald:.1f} | {cv} | {md(c.reason)} |")
    for it in d.iterations[1:]:
        lines += _round_lines(it, names)
    lines += considered_markdown(d)
    if d.not_applicable:
        lines += ["", "Not applicable: " + "; ".join(f"{k} ({v})" for k, v in d.not_applicable.items())]
    if d.effects:
        lines += ["", "## Estimated parameters of the left-out physics", "",
                  "(Gauss-Newton standard deviations, inflated by √(χ²/dof) when above 1)", ""]
        for e, params in f["parameters"].items():
            lines.append(f"- **{e}** ({EFFECTS[e].summary}):")
            for nm, p in params.items():
                lines.append(f"  - {nm}: {_fmt_param(p)}")
    if f.get("posterior"):
        lines += ["", "## Posterior check (emcee)", ""]
        lines += [_posterior_line(e, post) for e, post in f["posterior"].items()]
    if not d.explained and f.get("residual_localization"):
        lines += ["", "## What remains", "", *_localization_table(f["residual_localization"], names)]
    lines += discovered_markdown(d)  # discovered corrections, structure left over
    lines += ["", "## What to check next", ""] + [f"- {md(c)}" for c in next_checks(d, _value)]
    if figures:
        lines += ["", "## Figures", ""] + [f"![{fn}]({fn})" for fn in figures]
    return "\n".join(lines) + "\n"


def write_report(diagnosis, out_dir, doc: dict | None = None, problems: list | None = None,
                 on_replace=None, figures=None) -> Path:
    """Write ``report.md``, ``diagnosis.json`` and the figures into the folder ``out_dir``, which
    appears whole or not at all (:func:`cstiffjax.io.atomic.output_folder`; an earlier report
    there is replaced, its figures that this one does not draw removed).

    **Arguments:** ``doc``: the document (default :func:`document`); ``problems``: a list that
    gets one line per figure that could not be drawn (also added to ``doc["warnings"]`` and to
    the report's warnings; the report and the JSON are written regardless); ``on_replace``:
    called with one sentence when an earlier report in ``out_dir`` is about to be replaced
    (the command line prints it); ``figures``: a :class:`~fitting.diagnosis.figure_worker.FigureWorker`
    that was handed this diagnosis: its figures are moved in instead of being drawn here
    (drawn here when it failed).

    **Returns:** the path of ``report.md``.
    """
    doc = document(diagnosis) if doc is None else doc
    problems = [] if problems is None else problems
    with output_folder(out_dir, REPORT_PATTERNS, on_replace=on_replace) as tmp:
        first = len(problems)
        drawn = None if figures is None else figures.move_into(tmp, problems)
        if drawn is None:
            drawn = write_figures(diagnosis, tmp, problems)
        if problems[first:]:
            doc["warnings"] = [*doc.get("warnings", []), *(f"report figure {p}" for p in problems[first:])]
        write_json(diagnosis, tmp / "diagnosis.json", doc)
        write_text(tmp / "report.md", markdown(diagnosis, drawn, doc.get("warnings", [])))
    return Path(out_dir) / "report.md"
