"""Every third-party module imported anywhere in the repository comes from a distribution
declared in ``pyproject.toml`` (core dependencies or an extra), so a fresh machine that
runs the README's commands has it. Imports are read from the source (AST for Python
files, the code cells of the notebooks), not from what this interpreter happens to hold.
"""

import ast
import importlib.metadata as md
import json
import re
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("cstiffjax", "fitting", "tests", "benchmarks")


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def declared_distributions() -> set[str]:
    proj = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    reqs = list(proj.get("dependencies", []))
    reqs += [r for extra in proj.get("optional-dependencies", {}).values() for r in extra]
    return {_norm(re.split(r"[\s<>=!~\[;]", r, maxsplit=1)[0]) for r in reqs}


def _python_imports(path: Path):
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module.split(".")[0]


def _notebook_imports(path: Path):
    for cell in json.loads(path.read_text(encoding="utf-8"))["cells"]:
        if cell.get("cell_type") != "code":
            continue
        for line in "".join(cell.get("source", "")).splitlines():
            m = re.match(r"\s*(?:from|import)\s+([A-Za-z_]\w*)", line)
            if m:
                yield m.group(1)


def imported_modules() -> dict[str, str]:
    """Top-level module name -> first file that imports it."""
    found: dict[str, str] = {}
    for d in SOURCES:
        for p in sorted((ROOT / d).rglob("*.py")):
            for mod in _python_imports(p):
                found.setdefault(mod, str(p.relative_to(ROOT)))
    for nb in sorted((ROOT / "notebooks").rglob("*.ipynb")):
        for mod in _notebook_imports(nb):
            found.setdefault(mod, str(nb.relative_to(ROOT)))
    return found


def undeclared(found: dict[str, str], declared: set[str]) -> list[str]:
    own = {p.name for p in ROOT.iterdir() if p.is_dir()}  # the repository's own packages and folders (benchmarks)
    mod_to_dist = md.packages_distributions()
    bad = []
    for mod, where in sorted(found.items()):
        if mod in sys.stdlib_module_names or mod in own or mod.startswith("_"):
            continue
        dists = {_norm(d) for d in mod_to_dist.get(mod, [])}
        ok = bool(dists & declared) if dists else _norm(mod) in declared
        if not ok:
            bad.append(f"{mod} (imported in {where}; distribution {', '.join(sorted(dists)) or 'not installed'})")
    return bad


def test_every_import_is_declared():
    bad = undeclared(imported_modules(), declared_distributions())
    assert not bad, "imported but not declared in pyproject.toml (a fresh machine lacks them):\n" + "\n".join(bad)


def test_the_check_catches_an_undeclared_import(tmp_path):
    """The checker itself has power: dropping a declared distribution is reported."""
    found = imported_modules()
    assert "scipy" in found and "jax" in found  # sanity: the scan sees real imports
    declared = declared_distributions() - {"scipy"}
    bad = undeclared(found, declared)
    assert any(b.startswith("scipy ") for b in bad)
    assert undeclared({"mpmath": "x.py"}, declared - {"mpmath"}) != []


@pytest.mark.parametrize("name", ["mpmath", "tqdm", "scipy", "hypothesis"])
def test_known_needs_are_declared(name):
    assert name in declared_distributions()
