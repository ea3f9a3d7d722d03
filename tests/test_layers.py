"""The packages' layers hold: no import circle, no import from a lower layer to a higher one,
no import of another package's ``_private`` name, no read ``module._private`` of another
module's private name through an imported module (AST based, lazy imports inside functions
included). ``cstiffjax/README.md`` and ``fitting/README.md`` describe the layers.

The checker is tested on planted violations (an upward import, a circle, a private name, a
private attribute read) in a copy of the packages, so a checker that cannot fail does not pass.
"""

import ast
import itertools
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# bottom to top; a module may import its own layer and the layers before it
LAYERS = (
    "cstiffjax.core",
    "cstiffjax.io",
    "cstiffjax.cable",
    "cstiffjax.statics",
    "cstiffjax.stiffness",
    "cstiffjax.workspace",
    "cstiffjax.dynamics",
    "cstiffjax.csjm",
    "cstiffjax.plots",
    "cstiffjax.runtime",
    "cstiffjax.commands",
    "cstiffjax",  # the curated API (cstiffjax/__init__.py)
    "fitting.calibration",
    "fitting.posterior",
    "fitting.effects",
    "fitting.diagnosis",
    "fitting.synth",
    "fitting.plots",
    "fitting.commands",
    "fitting",  # the curated API (fitting/__init__.py)
)
# data packages that sit inside a layer
ALIASES = {"cstiffjax.examples": "cstiffjax.io"}


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def layer_of(module: str) -> int | None:
    """The rank of ``module``'s layer (the longest matching prefix), ``None`` outside both packages."""
    for alias, target in ALIASES.items():
        if module == alias or module.startswith(alias + "."):
            module = target
    best = None
    for rank, layer in enumerate(LAYERS):
        if module == layer or module.startswith(layer + "."):
            if best is None or len(layer) > len(LAYERS[best]):
                best = rank
    return best


def package_of(module: str) -> str:
    """The sub-package that owns ``module`` (its layer, or the package of a module at a top)."""
    rank = layer_of(module)
    return LAYERS[rank] if rank is not None else module


def from_target(node: ast.ImportFrom, path: Path, root: Path) -> str:
    """The module a ``from ... import`` statement in ``path`` imports from (relative levels resolved)."""
    if not node.level:
        return node.module or ""
    me = module_name(path, root)
    base = (me if is_package(path) else me.rpartition(".")[0]).split(".")
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports(path: Path, root: Path):
    """``(line, imported module, imported names)`` for every import in the file."""
    tree = ast.parse(path.read_text(), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name, ()
        elif isinstance(node, ast.ImportFrom):
            names = tuple(a.name for a in node.names)
            yield node.lineno, from_target(node, path, root), names


def is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def module_bindings(tree: ast.AST, path: Path, root: Path, known: set) -> dict[str, str]:
    """The names a file binds to modules of both packages (``import a.b as m``, ``from a import b``)."""
    bound = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in ("cstiffjax", "fitting"):
                    bound[a.asname or a.name.split(".")[0]] = a.name if a.asname else a.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            target = from_target(node, path, root)
            for a in node.names:
                if f"{target}.{a.name}" in known:
                    bound[a.asname or a.name] = f"{target}.{a.name}"
    return bound


def dotted(node: ast.AST) -> list[str] | None:
    """``a.b.c`` as ``["a", "b", "c"]``, ``None`` for anything but names and attributes."""
    if isinstance(node, ast.Name):
        return [node.id]
    if isinstance(node, ast.Attribute):
        head = dotted(node.value)
        return None if head is None else [*head, node.attr]
    return None


def private_reads(path: Path, root: Path, known: set):
    """``(line, module, name)`` for every read ``module._name`` of an imported module's private name."""
    me = module_name(path, root)
    tree = ast.parse(path.read_text(), str(path))
    bound = module_bindings(tree, path, root, known)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and is_private(node.attr):
            chain = dotted(node.value)
            if chain and chain[0] in bound:
                mod = ".".join([bound[chain[0]], *chain[1:]])
                if mod in known and mod != me:
                    yield node.lineno, mod, node.attr


def sources(root: Path):
    for pkg in ("cstiffjax", "fitting"):
        yield from sorted((root / pkg).rglob("*.py"))


def existing_module(target: str, names: tuple, known: set) -> list[str]:
    """The modules an import statement loads: ``from pkg import mod`` loads ``pkg.mod``."""
    modules = [f"{target}.{n}" for n in names if f"{target}.{n}" in known]
    plain = not names or len(modules) < len(names)
    return [target] * plain + modules


def violations(root: Path) -> list[str]:
    files = list(sources(root))
    known = {module_name(f, root) for f in files}
    graph: dict[str, set] = {m: set() for m in known}
    where: dict[tuple, str] = {}
    found = []
    for f in files:
        me = module_name(f, root)
        my_rank = layer_of(me)
        rel = f.relative_to(root)
        for line, target, names in imports(f, root):
            if target.split(".")[0] not in ("cstiffjax", "fitting"):
                continue
            for mod in existing_module(target, names, known):
                rank = layer_of(mod)
                if rank is not None and my_rank is not None and rank > my_rank:
                    found.append(f"{rel}:{line}: upward import: {me} ({LAYERS[my_rank]}) imports {mod} "
                                 f"({LAYERS[rank]})")
                if mod in known and mod != me:
                    graph[me].add(mod)
                    where.setdefault((me, mod), f"{rel}:{line}")
            other = package_of(target) != package_of(me)
            private = [n for n in names if is_private(n)]
            private_module = any(is_private(p) for p in target.split("."))
            if other and (private or private_module):
                found.append(f"{rel}:{line}: private import across packages: {me} imports "
                             f"{target}{' ' + ', '.join(private) if private else ''}")
        found += [f"{rel}:{line}: private attribute read: {me} reads {mod}.{name}"
                  for line, mod, name in private_reads(f, root, known)]
    found += [f"import circle: {' -> '.join(c)} ({', '.join(where[(a, b)] for a, b in itertools.pairwise(c))})"
              for c in cycles(graph)]
    return found


def cycles(graph: dict[str, set]) -> list[list[str]]:
    """One circle per strongly connected component of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(circle_in(graph, set(comp)))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def circle_in(graph, comp: set) -> list[str]:
    """A closed path inside one strongly connected component, by breadth-first search."""
    start = min(comp)
    prev = {start: None}
    queue = [start]
    while queue:
        v = queue.pop(0)
        for w in sorted(graph[v] & comp):
            if w == start:
                path = [v]
                while prev[path[-1]] is not None:
                    path.append(prev[path[-1]])
                return [*reversed(path), start]
            if w not in prev:
                prev[w] = v
                queue.append(w)
    raise AssertionError("not a strongly connected component")


def test_the_layers_hold():
    found = violations(ROOT)
    assert not found, "layering violations:\n" + "\n".join(found)


def test_every_module_has_a_layer():
    orphans = [str(f.relative_to(ROOT)) for f in sources(ROOT) if layer_of(module_name(f, ROOT)) is None]
    assert not orphans


@pytest.fixture
def copy(tmp_path):
    for pkg in ("cstiffjax", "fitting"):
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__", "*.csv"))
    assert violations(tmp_path) == []
    return tmp_path


def plant(path: Path, line: str) -> int:
    text = path.read_text()
    path.write_text(text + line + "\n")
    return len(text.splitlines()) + 1


def test_a_planted_upward_import_is_found_with_its_line(copy):
    n = plant(copy / "cstiffjax/core/arrays.py", "from cstiffjax.stiffness.matrix import stiffness  # noqa")
    found = violations(copy)
    assert found[0] == (f"cstiffjax/core/arrays.py:{n}: upward import: cstiffjax.core.arrays (cstiffjax.core) "
                        f"imports cstiffjax.stiffness.matrix (cstiffjax.stiffness)")


def test_physics_importing_fitting_is_upward(copy):
    planted = "def _planted():\n    import fitting.diagnosis.diagnose  # noqa"
    n = plant(copy / "cstiffjax/statics/geometry.py", planted) + 1
    assert f"cstiffjax/statics/geometry.py:{n}: upward import: cstiffjax.statics.geometry (cstiffjax.statics) " \
           f"imports fitting.diagnosis.diagnose (fitting.diagnosis)" in violations(copy)


def test_a_planted_circle_inside_one_layer_is_found(copy):
    n = plant(copy / "fitting/diagnosis/localize.py", "from fitting.diagnosis import diagnose  # noqa")
    found = violations(copy)
    assert len(found) == 1 and found[0].startswith("import circle: fitting.diagnosis.")
    assert f"fitting/diagnosis/localize.py:{n}" in found[0]


def test_a_private_name_across_packages_is_found(copy):
    n = plant(copy / "fitting/synth/generate_oov.py", "from cstiffjax.statics.geometry import _external  # noqa")
    assert violations(copy) == [f"fitting/synth/generate_oov.py:{n}: private import across packages: "
                                f"fitting.synth.generate_oov imports cstiffjax.statics.geometry _external"]


def test_a_private_attribute_read_through_an_imported_module_is_found(copy):
    planted = "def _planted(robot):\n    return geometry._external(robot)  # noqa"
    target = copy / "cstiffjax/workspace/interference.py"
    assert "from cstiffjax.statics import geometry" not in target.read_text()
    n = plant(target, "from cstiffjax.statics import geometry  # noqa\n" + planted) + 2
    assert violations(copy) == [f"cstiffjax/workspace/interference.py:{n}: private attribute read: "
                                f"cstiffjax.workspace.interference reads cstiffjax.statics.geometry._external"]


def test_a_private_attribute_read_through_an_aliased_dotted_import_is_found(copy):
    n = plant(copy / "fitting/synth/generate_oov.py",
              "import cstiffjax.statics as st  # noqa\nX = st.geometry._external  # noqa") + 1
    assert violations(copy) == [f"fitting/synth/generate_oov.py:{n}: private attribute read: "
                                f"fitting.synth.generate_oov reads cstiffjax.statics.geometry._external"]


def test_a_module_reading_its_own_private_name_or_a_dunder_is_not_a_violation(copy):
    plant(copy / "cstiffjax/statics/geometry.py",
          "from cstiffjax.statics import geometry as _me  # noqa\nY = _me._external, _me.__name__  # noqa")
    plant(copy / "fitting/synth/generate_oov.py",
          "from cstiffjax.statics import geometry  # noqa\nZ = geometry.__doc__")
    assert violations(copy) == []
