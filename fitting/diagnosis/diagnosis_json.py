"""The diagnosis's JSON document (formats.md §3): building it, checking it, writing it.

:func:`validate_diagnosis` checks a JSON document against formats.md §3 and raises
``ValueError`` naming the key path, the value and what is allowed. The diagnosis's own
document is checked by :func:`own_problems` *after* it was computed and never stops it
from being written: :func:`document` lists what the check found, and the parameters the
recordings do not determine, under the optional key ``warnings`` (a list of strings, each
naming the quantity); :func:`write_json` writes it atomically (:mod:`cstiffjax.io.atomic`).
Text from the inputs keeps its characters in the JSON (the report escapes it).
"""

import json
import re

import numpy as np

from cstiffjax.cable.laws import CableLaw, law_names
from cstiffjax.io.atomic import write_text
from fitting.calibration.models import FIT_LAWS
from fitting.diagnosis.discover_report import validate_discovered
from fitting.diagnosis.sensor_faults import validate as validate_sensor_faults
from fitting.effects import EFFECTS

_RMS_KEYS = ("position", "rotation", "tension")


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
