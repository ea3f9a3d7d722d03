"""Diagnosis output: the formats.md §3 JSON (with a validator), a Markdown report and
figures (matplotlib, Agg backend, imported lazily).

:func:`validate_diagnosis` checks a JSON document against formats.md §3 and raises
``ValueError`` naming the key path, the value and what is allowed. The diagnosis's own
document is checked by :func:`own_problems` *after* it was computed and never stops it
from being written: :func:`document` lists what the check found, and the parameters the
recordings do not determine, under the optional key ``warnings`` (a list of strings, each
naming the quantity); :func:`write_json` and :func:`write_report` write it atomically
(:mod:`cstiffjax.io.atomic`). Text from the inputs (the robot's name, covariate names) is
escaped in the report and the figures (:mod:`cstiffjax.core.text`); the JSON keeps it as it is.
"""

import json
import re
from pathlib import Path

import numpy as np

from cstiffjax.cable.laws import CableLaw, law_names
from cstiffjax.core.text import figure as figure_text
from cstiffjax.core.text import markdown as md
from cstiffjax.core.text import markdown_code as md_code
from cstiffjax.io import schema
from cstiffjax.io.atomic import best_effort, output_folder, write_text
from fitting.calibration.models import FIT_LAWS
from fitting.diagnosis.discover_report import considered_lines as considered_markdown
from fitting.diagnosis.discover_report import figures as discovered_figures
from fitting.diagnosis.discover_report import markdown_lines as discovered_markdown
from fitting.diagnosis.discover_report import validate_discovered
from fitting.diagnosis.localize import channel_labels
from fitting.diagnosis.sensor_faults import validate as validate_sensor_faults
from fitting.effects import EFFECTS

_RMS_KEYS = ("position", "rotation", "tension")
# every entry a report folder may hold (:func:`write_report`; discovered_<k>.png: discover_report.figures)
REPORT_PATTERNS = ("report.md", "diagnosis.json", "residuals.png", "chi2_shares.png", "robot.png", "discovered_*.png")


def _fail(path, msg):
    raise ValueError(f"diagnosis JSON: '{path}': {msg}")


def _num(d, key, path, allow_none=False):
    if key not in d:
        _fail(f"{path}.{key}" if path else key, "missing")
    v = d[key]
    if v is None and allow_none:
        return
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
        _fail(f"{path}.{key}" if path else key, f"value {v!r} is not a finite number")


def _rms(d, path):
    if not isinstance(d, dict):
        _fail(path, f"must be an object with keys {_RMS_KEYS}, got {d!r}")
    for k in _RMS_KEYS:
        _num(d, k, path, allow_none=True)  # a channel not measured (no tensions; version 3: no x y z) -> null
    for k in ("swivel", "ahrs"):  # version 3, optional
        if k in d:
            _num(d, k, path, allow_none=True)


def validate_diagnosis(doc: dict) -> dict:
    """Check ``doc`` against formats.md §3; return it unchanged or raise ``ValueError``.

    Checks: every required key and its type, the effect names against the vocabulary
    (:data:`fitting.effects.EFFECTS`), ``candidates`` sorted by ``delta_bic``, parameters
    as ``{name: {value, std}}``, ``effects`` a subset of the candidates' effects,
    ``explained`` a bool, optional ``outliers`` a list of 1-based sample rows, optional
    ``failed_samples`` ``{count, samples, rows}`` and ``dropped_rows`` ``{count, rows}``
    (lists of ``count`` integers; ``failed_samples.rows`` may be null), optional ``warnings``
    a list of strings, optional ``sensor_faults`` entries ``{kind, channel, detail, rows?}``,
    optional ``candidates[].rejected_because``/``equivalent`` sentences and an optional
    ``equivalent`` ``{selected effect: sentence}``.
    """
    if not isinstance(doc, dict):
        _fail("", f"the document must be a JSON object, got {type(doc).__name__}")
    for key, typ in (("robot", str), ("samples", int), ("baseline", dict), ("localization", list),
                     ("candidates", list), ("effects", list), ("explained", bool), ("final", dict)):
        if key not in doc:
            _fail(key, "missing")
        if not isinstance(doc[key], typ) or (typ is int and isinstance(doc[key], bool)):
            _fail(key, f"must be {typ.__name__}, got {doc[key]!r}")
    if doc["samples"] <= 0:
        _fail("samples", f"must be positive, got {doc['samples']}")
    b = doc["baseline"]
    try:
        model = CableLaw.parse(b.get("model"))
    except ValueError:
        model = None
    if model not in FIT_LAWS:
        _fail("baseline.model", f"value {b.get('model')!r}; allowed: {law_names(FIT_LAWS)}")
    _num(b, "chi2_per_dof", "baseline")
    _rms(b.get("rms"), "baseline.rms")
    ea = b.get("calibrated", {}).get("EA") if isinstance(b.get("calibrated"), dict) else None
    if not isinstance(ea, list) or not all(isinstance(v, int | float) and v > 0 for v in ea):
        _fail("baseline.calibrated.EA", f"must be a list of positive numbers (N), got {ea!r}")
    for i, e in enumerate(doc["localization"]):
        p = f"localization[{i}]"
        if not isinstance(e, dict) or not isinstance(e.get("where"), str):
            _fail(f"{p}.where", f"must be a string, got {e!r}")
        _num(e, "share_of_chi2", p)
        if not 0.0 <= e["share_of_chi2"] <= 1.0:
            _fail(f"{p}.share_of_chi2", f"value {e['share_of_chi2']} outside [0, 1]")
        if "correlates_with" not in e or not (e["correlates_with"] is None or isinstance(e["correlates_with"], str)):
            _fail(f"{p}.correlates_with", "missing or not a string")
        _num(e, "r", p)
        if abs(e["r"]) > 1.0 + 1e-9:
            _fail(f"{p}.r", f"value {e['r']} outside [-1, 1]")
    last = -np.inf
    for i, c in enumerate(doc["candidates"]):
        p = f"candidates[{i}]"
        if not isinstance(c, dict) or c.get("effect") not in EFFECTS:
            _fail(f"{p}.effect", f"value {c.get('effect') if isinstance(c, dict) else c!r}; "
                                 f"allowed: {', '.join(EFFECTS)}")
        for k in ("delta_bic", "chi2_per_dof"):  # null: the candidate's fit failed (listed last)
            if k not in c or not (c[k] is None or isinstance(c[k], int | float)):
                _fail(f"{p}.{k}", "missing or not a number")
        dbic = np.inf if c["delta_bic"] is None else c["delta_bic"]
        if dbic < last:
            _fail(f"{p}.delta_bic", f"candidates must be sorted by delta_bic; {c['delta_bic']} < {last}")
        last = dbic
        if not isinstance(c.get("parameters"), dict):
            _fail(f"{p}.parameters", "must be an object {name: {value, std}}")
        for nm, v in c["parameters"].items():
            if not isinstance(v, dict) or "value" not in v or "std" not in v:
                _fail(f"{p}.parameters.{nm}", f"must have 'value' and 'std', got {v!r}")
        for k in ("rejected_because", "equivalent"):  # optional sentences
            if k in c and not (isinstance(c[k], str) and c[k]):
                _fail(f"{p}.{k}", f"must be a non-empty string, got {c[k]!r}")
    tried = {c["effect"] for c in doc["candidates"]}
    for i, e in enumerate(doc["effects"]):
        if e not in EFFECTS:
            _fail(f"effects[{i}]", f"value {e!r}; allowed: {', '.join(EFFECTS)}")
        if e not in tried:
            _fail(f"effects[{i}]", f"effect {e!r} is not among the candidates")
    eq = doc.get("equivalent", {})
    if not isinstance(eq, dict) or not all(k in doc["effects"] and isinstance(v, str) and v for k, v in eq.items()):
        _fail("equivalent", f"must map selected effects to non-empty sentences, got {eq!r}")
    _num(doc["final"], "chi2_per_dof", "final")
    _rms(doc["final"].get("rms"), "final.rms")
    for key, fields in (("failed_samples", ("samples", "rows")), ("dropped_rows", ("rows",))):
        if key in doc:
            v = doc[key]
            if not isinstance(v, dict) or not isinstance(v.get("count"), int) or isinstance(v.get("count"), bool):
                _fail(key, f"must be an object with an integer 'count', got {v!r}")
            for f in fields:
                lst = v.get(f)
                if not (lst is None and f == "rows") and not (
                        isinstance(lst, list) and len(lst) == v["count"] and all(isinstance(r, int) for r in lst)):
                    _fail(f"{key}.{f}", f"must be a list of {v['count']} integer rows, got {lst!r}")
    if "outliers" in doc:
        rows = doc["outliers"]
        if not isinstance(rows, list) or not all(isinstance(r, int) and 1 <= r <= doc["samples"] for r in rows):
            _fail("outliers", f"must be a list of 1-based sample rows in 1..{doc['samples']}, got {rows!r}")
    validate_discovered(doc)  # the optional `discovered` key
    validate_sensor_faults(doc)  # the optional `sensor_faults` key
    notes = doc.get("warnings", [])
    if not (isinstance(notes, list) and all(isinstance(w, str) for w in notes)):
        _fail("warnings", f"must be a list of strings, got {notes!r}")
    return doc


def own_problems(doc: dict) -> list[str]:
    """What the formats.md §3 check (:func:`validate_diagnosis`) finds wrong in a document this
    program made: ``[]``, or one message naming the key (a fault of the diagnosis, not of its
    inputs)."""
    try:
        validate_diagnosis(doc)
    except ValueError as e:
        detail = re.sub(r"^diagnosis JSON:? ", "", str(e))
        return [f"the diagnosis result fails its own consistency check (formats.md §3): {detail}. The result "
                f"was written as computed; this is a fault of the diagnosis, not of the robot or the recordings"]
    return []


def document(diagnosis) -> dict:
    """The formats.md §3 document of ``diagnosis`` (JSON types, non-finite numbers as null),
    with ``warnings`` (only when there is one): one string per parameter the recordings do not determine
    (``baseline``/``final`` ``calibrated.unidentified``) and per problem :func:`own_problems`
    finds. Never raises on a problem of the document itself."""
    doc = json.loads(json.dumps(_finite(diagnosis.to_json()), default=_default))
    notes = list(doc.get("warnings", []))  # the diagnosis's own (the recordings, the elasticity)
    for stage in ("baseline", "final"):
        cal = doc.get(stage, {}).get("calibrated") if isinstance(doc.get(stage), dict) else None
        for u in (cal or {}).get("unidentified", []) if isinstance(cal, dict) else []:
            notes.append(f"{stage}.calibrated.EA: {u['reason']}")
    notes += own_problems(doc)
    if notes:  # optional key: present only when there is something to say
        doc["warnings"] = notes
    return doc


def write_json(diagnosis, path, doc: dict | None = None) -> dict:
    """Write the document of ``diagnosis`` (``doc``, default :func:`document`) to ``path``
    atomically, whatever its check found (listed in its ``warnings``); returns the document."""
    doc = document(diagnosis) if doc is None else doc
    write_text(path, json.dumps(doc, indent=1) + "\n")
    return doc


def _finite(o):
    """Non-finite floats -> None (JSON has no inf/nan), recursively."""
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_finite(v) for v in o]
    if isinstance(o, float) and not np.isfinite(o):
        return None
    return o


def _default(o):
    if isinstance(o, np.generic | np.ndarray):
        return o.tolist()
    if isinstance(o, float) and not np.isfinite(o):
        return None
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


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


def _value(p) -> str:
    """``value ± std unit`` of one parameter; arrays shortened to their largest entry."""
    v, s = np.ravel(p["value"]).astype(float), np.ravel(p["std"]).astype(float)
    if v.size == 1:
        return f"{v[0]:.4g} ± {s[0]:.2g} {p['unit']}"
    k = int(np.argmax(np.abs(v)))
    return f"{v.size} values, largest |{v[k]:.4g}| ± {s[k]:.2g} {p['unit']}"


# ------------------------------------------------------------------ figures
def _localizer(diagnosis):
    """(channel index, covariate name) that localized the mismatch (top channel)."""
    ch = diagnosis.localization["channels"]
    if not ch:
        return None, None
    labels = channel_labels(diagnosis.arrays["r_base"].shape[1] - 6)
    return labels.index(ch[0]["where"]), ch[0]["correlates_with"]


def _unit(name) -> str:
    """SI unit of a covariate of :func:`fitting.diagnosis.localize.covariates` ('' when unknown):
    a recordings column's from :mod:`cstiffjax.io.schema`, m/kg for the sag parameter ``sag_i``."""
    return "m/kg" if name.startswith("sag_") else schema.unit(name)


def _covariate_axis(ax, name, x, rng):
    """x positions and the axis label of a covariate; the direction of the last length
    change (``dir_i``, values -1/0/+1) is drawn as three categories (jittered)."""
    if not name.startswith("dir_"):
        ax.set_xlabel(figure_text(f"{name} ({_unit(name)})" if _unit(name) else name))
        return x
    ax.set_xticks([-1, 0, 1], ["shortened\n(−1)", "unchanged\n(0)", "lengthened\n(+1)"])
    ax.set_xlim(-1.6, 1.6)
    ax.set_xlabel(f"direction of the last length change of cable {name[4:]}")
    return x + rng.uniform(-0.15, 0.15, size=x.shape)


def _finish(fig, path, **options):
    """Write ``fig`` to ``path`` and close it; with ``path`` None return it open (to show)."""
    if path is None:
        return fig
    import matplotlib.pyplot as plt

    fig.savefig(path, **options)
    plt.close(fig)
    return path


def _residual_figure(diagnosis, j, cov, path):
    import matplotlib.pyplot as plt

    a = diagnosis.arrays
    keep = a["keep"]
    labels = channel_labels(a["r_base"].shape[1] - 6)
    # each panel on its own scale: the final residual is often far smaller than the baseline's
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.4), sharex=True, layout="constrained")
    rng = np.random.default_rng(0)
    x = a["covariates"][cov]
    for k, (r, c2, title) in enumerate(((a["r_base"], diagnosis.baseline["chi2_per_dof"], "baseline"),
                                        (a["r_final"], diagnosis.final["chi2_per_dof"],
                                         " + ".join(["baseline", *diagnosis.effects])))):
        xk = _covariate_axis(ax[k], cov, np.asarray(x, dtype=float), rng)
        ax[k].axhspan(-1, 1, color="0.92", zorder=0, label="±1 σ (noise level)")
        ax[k].scatter(xk[keep], r[keep, j], s=12, label="samples")
        if np.any(~keep):
            ax[k].scatter(xk[~keep], r[~keep, j], s=30, marker="x", color="red", label="outliers (left out)")
        ax[k].axhline(0, color="k", lw=0.5)
        ax[k].set_title(f"{title} (χ²/dof {c2:.3g})")
        ax[k].set_ylabel(f"whitened residual of {labels[j]} (σ)")
        ax[k].yaxis.set_tick_params(labelleft=True)
    fig.suptitle(f"{figure_text(diagnosis.robot)}: {labels[j]} against {figure_text(cov)}, before and after the "
                 f"diagnosis")
    handles, names = ax[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="outside lower center", ncol=len(names), fontsize=8)
    return _finish(fig, path, dpi=110)


def _chi2_figure(diagnosis, path):
    import matplotlib.pyplot as plt

    a = diagnosis.arrays
    keep = a["keep"]
    m, sensors = a["robot"].num_cables, a.get("sensors", ())
    labels = channel_labels(m, sensors)
    idx = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(max(6.5, 0.65 * len(labels)), 4.4), layout="constrained")
    for k, (r, lab, c2) in enumerate(((a["r_base"], "baseline", diagnosis.baseline["chi2_per_dof"]),
                                      (a["r_final"], " + ".join(["baseline", *diagnosis.effects]),
                                       diagnosis.final["chi2_per_dof"]))):
        c = np.sum(r[keep] ** 2, 0)
        ax.bar(idx + 0.4 * k - 0.2, c, 0.4, label=f"{lab} (χ²/dof {c2:.3g}, total χ² {np.sum(c):.4g})")
    expected = np.count_nonzero(a["r_base"][keep], axis=0)  # recorded values per channel
    ax.scatter(idx, expected, marker="_", s=400, color="k", zorder=3, label="noise level (χ² = number of values)")
    ax.set_yscale("log")
    low = min(np.min(np.sum(r[keep] ** 2, 0)) for r in (a["r_base"], a["r_final"]))
    ax.set_ylim(bottom=10.0 ** np.floor(np.log10(max(0.5 * low, 1e-3))))  # bars start well below the data
    ax.set_xticks(idx, [lb.rpartition(" ")[2] for lb in labels], rotation=90 if len(labels) > 16 else 0)
    ax.set_xlabel("channel (" + ", ".join(["position", "orientation", "cable tensions",
                                           *(("swivel angles",) if "swivel" in sensors else ()),
                                           *(("AHRS",) if "ahrs" in sensors else ())]) + ")")
    ax.set_ylabel("χ² of the channel (whitened, log scale)")
    ax.set_title(f"{figure_text(diagnosis.robot)}: χ² per channel, baseline vs final model")
    fig.legend(loc="outside lower center", ncol=2, fontsize=8)
    return _finish(fig, path, dpi=110)


def robot_view(diagnosis):
    """What ``robot.png`` shows: ``(pose, highlight, arrows, arrow_label)``: the recorded
    pose nearest to the samples' mean position; the cables whose tension channels carry
    the most baseline χ² (the top one, and the second when it has at least half as much);
    the anchor or attachment offsets the diagnosis found (``arrows`` None when it found none)."""
    a = diagnosis.arrays
    poses, keep = np.asarray(a["poses"]), a["keep"]
    centre = poses[keep, :3].mean(0)
    pose = poses[int(np.argmin(np.where(keep, np.linalg.norm(poses[:, :3] - centre, axis=1), np.inf)))]
    chi2 = np.sum(np.asarray(a["r_base"])[keep, 6:] ** 2, 0)
    order = np.argsort(chi2)[::-1]
    highlight = [int(order[0])] + ([int(order[1])] if len(order) > 1 and chi2[order[1]] >= 0.5 * chi2[order[0]]
                                   else [])
    for effect, where in (("anchor_offset", "anchors"), ("attachment_offset", "attachments")):
        if effect in diagnosis.effects:
            offset = np.asarray(diagnosis.final["parameters"][effect]["offset"]["value"], float)
            return pose, highlight, (offset, where), effect.replace("_", " ") + "s found"
    return pose, highlight, None, None


def _robot_figure(diagnosis, path):
    import matplotlib.pyplot as plt

    from cstiffjax.plots.robot import draw_robot

    robot = diagnosis.arrays["robot"]
    pose, highlight, arrows, label = robot_view(diagnosis)
    fig = plt.figure(figsize=(8, 6.5))
    ax = fig.add_subplot(projection="3d")
    draw_robot(ax, robot, pose, highlight=highlight, arrows=None if arrows is None else arrows[0],
               arrow_at="anchors" if arrows is None else arrows[1], arrow_label=label)
    cables = ", ".join(str(i + 1) for i in highlight)
    ax.set_title(f"{figure_text(diagnosis.robot)} at a central recorded pose\nred: cable{'s' * (len(highlight) > 1)} "
                 f"{cables}, the largest tension misfit of the baseline", fontsize=9)
    return _finish(fig, path, dpi=110, bbox_inches="tight")


def open_figures(diagnosis) -> dict:
    """The report's figures as open matplotlib figures, ``{file name: Figure}`` (a notebook
    shows them; :func:`write_figures` writes them)."""
    out = {}
    j, cov = _localizer(diagnosis)
    if j is not None and cov in diagnosis.arrays["covariates"]:
        out["residuals.png"] = _residual_figure(diagnosis, j, cov, None)
    out["chi2_shares.png"] = _chi2_figure(diagnosis, None)
    if "robot" in diagnosis.arrays and getattr(diagnosis.arrays["robot"], "kind", "") == "cdpr":
        out["robot.png"] = _robot_figure(diagnosis, None)
    return out


def write_figures(diagnosis, out_dir, problems: list | None = None) -> list[str]:
    """``residuals.png`` (baseline and final residual of the localizing channel against the
    covariate that localized it, each panel on its own scale; the direction of the last length
    change as three categories), ``chi2_shares.png`` (absolute χ² per channel, baseline
    vs final, with the noise level) and ``robot.png`` (the robot at a central recorded pose,
    the cables with the largest misfit in red, found anchor/attachment offsets as scaled
    arrows: :func:`robot_view`). Returns the file names written.

    With ``problems`` (a list), a figure that cannot be drawn is left out and the reason
    appended there (:func:`cstiffjax.io.atomic.best_effort`); without it, the error is raised."""
    out = Path(out_dir)
    files = []

    def draw(name, fn):
        if problems is None:
            fn()
        elif not best_effort(problems, out / name, fn):
            return
        files.append(name)

    j, cov = _localizer(diagnosis)
    if j is not None and cov in diagnosis.arrays["covariates"]:
        draw("residuals.png", lambda: _residual_figure(diagnosis, j, cov, out / "residuals.png"))
    draw("chi2_shares.png", lambda: _chi2_figure(diagnosis, out / "chi2_shares.png"))
    if "robot" in diagnosis.arrays and getattr(diagnosis.arrays["robot"], "kind", "") == "cdpr":
        draw("robot.png", lambda: _robot_figure(diagnosis, out / "robot.png"))
    try:  # the residual against each discovered driver
        files += discovered_figures(diagnosis, out)
    except Exception as e:
        if problems is None or isinstance(e, OSError):
            raise
        for f in out.glob("discovered_*.png"):
            f.unlink()
        problems.append(f"discovered_*.png: not written ({type(e).__name__}: {e})")
    return files


# ----------------------------------------------------------------- markdown
def _fmt_param(p):
    v, s = np.asarray(p["value"], dtype=float), np.asarray(p["std"], dtype=float)
    if v.ndim == 0:
        return f"{float(v):.4g} ± {float(s):.2g} {p['unit']}"
    rows = v.reshape(len(v), -1)
    srows = s.reshape(len(s), -1)
    return "<br>".join(f"[{i + 1}] " + ", ".join(f"{a:.4g} ± {b:.2g}" for a, b in zip(r, sr, strict=True))
                       + f" {p['unit']}" for i, (r, sr) in enumerate(zip(rows, srows, strict=True)))


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
    lines += ["## Where the baseline misfits", "", "| channel | share of χ² | follows | r | lag-1 |",
              "|---|---|---|---|---|"]
    for e in d.localization["channels"]:
        lines.append(f"| {e['where']} | {e['share_of_chi2']:.2f} | {md(e['correlates_with'])} | {e['r']:.2f} | "
                     f"{e['lag1']:.2f} |")
    reg = d.localization["regions"][:2]
    lines += ["", "Workspace regions with the most χ² per sample: " + "; ".join(
        f"{r['region']} ({r['share_of_chi2']:.0%} of χ², {r['share_of_samples']:.0%} of samples)" for r in reg), ""]
    lines += ["## Candidates (first round, against the baseline)", "",
              "| effect | ΔBIC | χ²/dof | Wald | held-out χ²/datum | verdict |", "|---|---|---|---|---|---|"]
    for c in d.candidates:
        cv = "" if c.cv is None else f"{c.cv:.4g} (baseline {c.cv_reference:.4g})"
        lines.append(f"| {c.effect} | {c.delta_bic:.1f} | {c.chi2_per_dof:.4g} | {c.wald:.1f} | {cv} | {c.reason} |")
    for it in d.iterations[1:]:
        lines += ["", f"Round {it['round']} (model: baseline + {', '.join(it['model'])}, "
                      f"χ²/dof {it['chi2_per_dof']:.4g}): added {it['added'] or 'nothing'}."]
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
        lines += ["", "## What remains", "", "| channel | share of χ² | follows | r | lag-1 |", "|---|---|---|---|---|"]
        for e in f["residual_localization"]:
            lines.append(f"| {e['where']} | {e['share_of_chi2']:.2f} | {md(e['correlates_with'])} | {e['r']:.2f} | "
                         f"{e['lag1']:.2f} |")
    lines += discovered_markdown(d)  # discovered corrections, structure left over
    if figures:
        lines += ["", "## Figures", ""] + [f"![{fn}]({fn})" for fn in figures]
    return "\n".join(lines) + "\n"


def write_report(diagnosis, out_dir, doc: dict | None = None, problems: list | None = None,
                 on_replace=None) -> Path:
    """Write ``report.md``, ``diagnosis.json`` and the figures into the folder ``out_dir``, which
    appears whole or not at all (:func:`cstiffjax.io.atomic.output_folder`; an earlier report
    there is replaced, its figures that this one does not draw removed).

    **Arguments:** ``doc``: the document (default :func:`document`); ``problems``: a list that
    gets one line per figure that could not be drawn (also added to ``doc["warnings"]`` and to
    the report's warnings; the report and the JSON are written regardless); ``on_replace``:
    called with one sentence when an earlier report in ``out_dir`` is about to be replaced
    (the command line prints it).

    **Returns:** the path of ``report.md``.
    """
    doc = document(diagnosis) if doc is None else doc
    problems = [] if problems is None else problems
    with output_folder(out_dir, REPORT_PATTERNS, on_replace=on_replace) as tmp:
        first = len(problems)
        figures = write_figures(diagnosis, tmp, problems)
        if problems[first:]:
            doc["warnings"] = [*doc.get("warnings", []), *(f"report figure {p}" for p in problems[first:])]
        write_json(diagnosis, tmp / "diagnosis.json", doc)
        write_text(tmp / "report.md", markdown(diagnosis, figures, doc.get("warnings", [])))
    return Path(out_dir) / "report.md"
