"""Every command's JSON output has the layout `cstiffjax/io/outputs.md` documents.

The documented keys are parsed from the document itself (one section per command, one
table row per key path), so the document and the outputs cannot drift apart: each command
runs once, small, on a bundled example, and every key path it writes must be documented
with a matching type, and every key the document marks "always" must be written."""

import json
import re
from importlib import resources
from pathlib import Path

import pytest

from cstiffjax.commands.cli import main
from cstiffjax.examples import example_path

TYPES = {"number", "integer", "string", "boolean", "object", "array", "null"}


def outputs_document() -> str:
    return resources.files("cstiffjax.io").joinpath("outputs.md").read_text(encoding="utf-8")


def documented_layouts(text: str) -> dict[str, dict[str, tuple[set[str], bool]]]:
    """``{section: {key path: (types, always)}}`` from the tables of outputs.md: a section is
    a ``## name`` heading, a key a table row ``| `path` | type | unit | when | meaning |``."""
    layouts, section = {}, None
    for no, line in enumerate(text.splitlines(), 1):
        if line.startswith("## "):
            section = line[3:].split()[0].strip("`")
            layouts[section] = {}
        m = re.match(r"^\|\s*`([^`]+)`\s*\|([^|]*)\|([^|]*)\|([^|]*)\|", line)
        if m and section is not None:
            key, typ, when = m.group(1), m.group(2).strip(), m.group(4).strip()
            types = {alt.strip().split()[0] for alt in typ.split(" or ") if alt.strip()}
            assert types and types <= TYPES, f"outputs.md line {no}: type {typ!r} of {key}: allowed {sorted(TYPES)}"
            assert key not in layouts[section], f"outputs.md line {no}: {key} documented twice in {section}"
            layouts[section][key] = (types, when == "always")
    return layouts


def key_paths(doc, prefix=""):
    """``{path: value}`` of every key of a JSON document at every depth: ``a.b`` for objects,
    ``a[].b`` for the objects inside a list (a top-level list: ``[].b``)."""
    out = {}
    if isinstance(doc, dict):
        for k, v in doc.items():
            path = f"{prefix}.{k}" if prefix else k
            out[path] = v
            out.update(key_paths(v, path))
    elif isinstance(doc, list):
        for item in doc:
            if isinstance(item, dict):
                out.update(key_paths(item, f"{prefix}[]"))
    return out


def json_type(v) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "boolean"
    if isinstance(v, int):
        return "integer"
    if isinstance(v, float):
        return "number"
    return {str: "string", dict: "object", list: "array"}[type(v)]


def _pattern(path: str) -> re.Pattern:
    """A documented path as a regex: ``<name>`` stands for any key text (no dots)."""
    parts = re.split(r"(<[^>]+>)", path)
    return re.compile("".join("[^.]+" if p.startswith("<") else re.escape(p) for p in parts) + r"\Z")


def compare(section: str, doc, layouts) -> list[str]:
    """What differs between a command's JSON ``doc`` and its documented section."""
    documented = layouts[section]
    patterns = [(_pattern(k), k) for k in documented]
    found, problems = set(), []
    for path, value in key_paths(doc).items():
        match = [k for p, k in patterns if p.match(path)]
        if not match:
            problems.append(f"{section}: {path} is written but not documented")
            continue
        key = min(match, key=len) if path not in documented else path
        found.add(key)
        types, _ = documented[key]
        t = json_type(value)
        if not (t in types or (t == "integer" and "number" in types)):
            problems.append(f"{section}: {path} is {t}, documented {sorted(types)}")
    for key, (_, always) in documented.items():
        if always and key not in found:
            problems.append(f"{section}: {key} is documented as always written but is missing")
    return problems


# --------------------------------------------------------------------------- the runs
def _small_recordings(folder: Path) -> None:
    """``folder/small.csv``: the header and first 12 samples of example02's recordings (for ``fit``)."""
    lines = example_path("example02/recordings.csv").read_text().splitlines()
    (folder / "small.csv").write_text("\n".join(lines[:13]) + "\n")


POSE = ["0", "0", "0.83", "0", "0", "0"]


def _runs(d: Path) -> dict:
    """``{section: (argv, JSON file)}``: each command small and fast on a bundled example
    (nothing is written here; ``fit`` reads ``d/small.csv``, :func:`_small_recordings`)."""
    ex2 = str(example_path("example02/robot.toml"))
    box = "-5 5 -5 5 -5 5 -0.5 0.5 -0.5 0.5 -0.5 0.5".split()
    return {
        "check": (["check", ex2, str(example_path("example02/recordings.csv")), "--json", str(d / "c.json")],
                  d / "c.json"),
        "stiffness": (["stiffness", "tcpr8.toml", "--pose", *POSE, "--json", str(d / "s.json")], d / "s.json"),
        "statics": (["statics", "suspended4.toml", "--lengths", "2.7", "2.7", "2.7", "2.7", "--json",
                     str(d / "st.json")], d / "st.json"),
        "tensions": (["tensions", "tcpr8.toml", "--pose", *POSE, "--method", "cfm", "--json", str(d / "t.json")],
                     d / "t.json"),
        "csjm": (["csjm", "csjm.toml", "--json", str(d / "m.json")], d / "m.json"),
        "csjm-identify": (["csjm", "csjm.toml", "--identify", "csjm_recordings.csv", "--json", str(d / "i.json")],
                          d / "i.json"),
        "fit": (["fit", ex2, str(d / "small.csv"), "--max-steps", "5", "--json", str(d / "f.json")],
                d / "f.json"),
        "frf": (["frf", "prototype_8mm.toml", "--pose", "0", "0", "0.5", "0", "0", "0", "--fmax", "5", "--n", "20",
                 "--sweep", "2", "--out", str(d / "frf")], d / "frf" / "frf.json"),
        "sag": (["sag", "prototype_4mm.toml", "--pose", "0", "0", "0.5", "0", "0", "0", "--load-sweep", "--masses",
                 "20", "60", "--map", "--grid", "2", "--out", str(d / "sag")], d / "sag" / "sag.json"),
        "css": (["css", "tcpr8.toml", "--pose-grid", "-0.02", "0.02", "2", "-0.02", "0.02", "2", "0.82", "0.84", "2",
                 "--stiffness-at", *POSE, "--out", str(d / "css")], d / "css" / "summary.json"),
        "workspace": (["workspace", "tcpr8.toml", "--kind", "wrench-feasible", "--pose-grid", "-0.1", "0.1", "2",
                       "-0.1", "0.1", "2", "0.7", "0.9", "2", "--wrench-box", *box, "--out", str(d / "ws")],
                      d / "ws" / "summary.json"),
        "generate": (["generate", "--out", str(d / "gen"), "--samples", "3", "--cases", "proto_clean"],
                     d / "gen" / "key.json"),
    }


SECTIONS = list(_runs(Path("unused")))
SLOW = {"fit", "frf", "sag"}  # their solvers compile for more than a minute on a loaded machine


@pytest.fixture(scope="module")
def layouts():
    return documented_layouts(outputs_document())


def test_every_command_has_a_section_and_the_document_is_linked(layouts):
    assert set(layouts) == set(SECTIONS), sorted(set(layouts) ^ set(SECTIONS))
    assert all(layouts[s] for s in SECTIONS)
    formats = resources.files("cstiffjax.io").joinpath("formats.md").read_text(encoding="utf-8")
    assert "outputs.md" in formats
    assert re.search(r"^Version \d+", outputs_document(), re.M)


@pytest.mark.parametrize("section", [pytest.param(s, marks=pytest.mark.slow) if s in SLOW else s for s in SECTIONS])
def test_command_json_matches_the_documented_layout(section, layouts, tmp_path, capsys):
    argv, path = _runs(tmp_path)[section]
    _small_recordings(tmp_path)
    assert main([*argv, "--quiet"]) == 0
    if section not in ("check", "tensions"):  # every other command says what it wrote
        assert "wrote" in capsys.readouterr().out.split(path.name)[0].splitlines()[-1]
    doc = json.loads(path.read_text())
    problems = compare(section, doc, layouts)
    assert not problems, "\n".join(problems)
    if section in ("fit", "tensions"):
        assert doc["status"] == "ok"  # the documented text, not a Status object's repr


def test_answer_key_entries_of_every_case_match_the_layout(layouts):
    """Every case's key entry (what each conceals differs: effects with parameters, none, an
    out-of-vocabulary kind), built as the generator builds it, without simulating the data."""
    from fitting.synth.generate import default_cases, key_entry
    from fitting.synth.generate_oov import oov_cases, oov_key_entry

    keys = [{**key_entry(c, 3, 1, [4]), "base_seed": 0} for c in default_cases()]
    keys += [{**oov_key_entry(c, 3, 1), "base_seed": 0} for c in oov_cases()]
    assert any(k["truth"] for k in keys) and any(not k["truth"] for k in keys)
    problems = compare("generate", keys, layouts)
    assert not problems, "\n".join(problems)


def test_the_comparison_can_fail(layouts):
    doc = {"robot": "r", "pose": [0.0] * 6, "method": "cfm", "objective": None, "wrench": None,
           "tensions": [1.0], "residual": [0.0], "status": "ok", "num_steps": 3}
    assert compare("tensions", doc, layouts) == []
    assert "tensions: extra is written but not documented" in compare("tensions", {**doc, "extra": 1}, layouts)
    assert any("num_steps is documented as always" in p for p in
               compare("tensions", {k: v for k, v in doc.items() if k != "num_steps"}, layouts))
    assert any("robot is integer" in p for p in compare("tensions", {**doc, "robot": 3}, layouts))
    assert key_paths([{"a": {"b": 1}}]) == {"[].a": {"b": 1}, "[].a.b": 1}
    assert _pattern("values.<name>").match("values.EA") and not _pattern("values.<name>").match("values.EA.x")
