"""The import graph of `jthermo/` follows the design: no import circle, layers import only
downward, and no module reaches for another module's private names; no package file is over
`MAX_LINES` lines, and the study scripts (`benchmarks/`, `experiments/`) import no circle either.

Every `jthermo/**/*.py` is parsed with `ast`; every import counts (module level, inside
functions, under `if TYPE_CHECKING:`), relative imports are resolved, and a package's
`__init__.py` is the package itself. `from pkg import name` is an edge to the submodule
`pkg.name` when there is one, else to `pkg`. Importing a submodule does not count as importing
its parent packages (Python runs their `__init__` too, but that is not a dependency the
importer chose).

Each failure message lists every violation, so one run shows all the work left.
"""

from __future__ import annotations

import ast
import itertools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PKG = "jthermo"

#: The layers, bottom first. A module may import a module of a LOWER layer, and any module of
#: its own unit (the first name below `jthermo`: `identify` for `jthermo.identify.fit`); an
#: import between two different units of the same layer is a violation too ("siblings").
#: The flow the package is designed around: data -> models -> identify/validate -> control ->
#: closed loop -> tuning, with the command line and the demo on top.
LAYERS: list[tuple[str, ...]] = [
    # Utilities that everything may use: errors, type aliases, atomic writes, the family
    # names, progress bars, the process's compiled programs (factory cache, memory-map guard).
    ("errors", "_types", "_files", "families", "progress", "programs"),
    # The JAX runtime settings (compilation cache, compile timing); it re-exports `programs`.
    ("runtime",),
    # Traced programs and numbers kept in the compilation cache's directory.
    ("stored",),
    # Shape checks of the public entry points (one-line errors instead of broadcasting ones).
    ("_checks",),
    # The package root `jthermo/__init__.py`: `__version__`, the error classes and a lazy
    # (PEP 562) facade, so it may import utilities only; that keeps `import jthermo` cheap.
    ("",),
    # A logged time axis onto a uniform grid (the records' loader uses it).
    ("time_grid",),
    # Records and excitation signals.
    ("data", "inputs"),
    ("models",),
    # Estimate models, judge them, convert them to python-control.
    ("identify", "validate", "interop"),
    # The two halves that `closedloop` joins, neither knowing the other: controllers and the
    # simulated plant (the printer needs records and excitation signals, no controller).
    # Beside them the presentation helpers: figures of records, fits and residual tests
    # (`plots` needs `validate`) and Markdown reports (plain values only); they sit this low
    # so that `diagnose`, and not only the command line, can write its figures and reports.
    ("control", "printer", "plots", "report"),
    # Plant + controller -> trajectories and costs. Beside it `io`, the model / controller
    # file format (it needs the model and controller base classes).
    ("closedloop", "io"),
    # Two consumers of the layers below, independent of each other.
    ("tune", "diagnose"),
    # 3D-printer firmware: printer logs as records, tuned settings in the firmware's syntax.
    ("firmware",),
    # Batch runs of fit / validate / tune.
    ("sweep",),
    # The demo's settings and stage runner, then the demo: it runs the whole tour; the command
    # line may launch it, never the reverse.
    ("demo_stages",),
    ("demo",),
    ("cli",),
]

RANK = {unit: rank for rank, units in enumerate(LAYERS) for unit in units}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def _parse() -> dict[str, tuple[Path, ast.Module]]:
    files = sorted((ROOT / PKG).rglob("*.py"))
    assert files, f"no Python files under {ROOT / PKG}"
    return {_module_name(p): (p, ast.parse(p.read_text(encoding="utf-8"), filename=str(p)))
            for p in files}


def _resolve_relative(module: str, is_pkg: bool, level: int, name: str | None) -> str | None:
    """The absolute name of `from <level dots><name> import ...` written in `module`."""
    package = module if is_pkg else module.rpartition(".")[0]
    parts = package.split(".") if package else []
    if level - 1 > len(parts):
        return None
    base = parts[: len(parts) - (level - 1)]
    if name:
        base += name.split(".")
    return ".".join(base)


class _Import:
    """`importer` imports module `target`: the names `names` from it, or (no names) the module
    itself, bound to the local name `bound` when the import binds one."""

    __slots__ = ("bound", "importer", "line", "names", "path", "target")

    def __init__(self, importer, target, names, path, line, bound=None):
        self.importer, self.target, self.names, self.bound, self.path, self.line = (
            importer, target, names, bound, path, line)

    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def _imports(modules) -> list[_Import]:
    """Every import of a `jthermo` module, as (importer, imported module, imported names)."""
    out = []
    for mod, (path, tree) in modules.items():
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name == PKG or alias.name.startswith(PKG + "."):
                        target = alias.name
                        # `import jthermo.a.b` of a name that is not a module: its longest module prefix
                        while target not in modules and "." in target:
                            target = target.rpartition(".")[0]
                        bound = alias.asname if target == alias.name else None
                        out.append(_Import(mod, target, (), path, node.lineno, bound))
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = _resolve_relative(mod, _is_package(path), node.level, node.module)
                else:
                    base = node.module
                if base is None or not (base == PKG or base.startswith(PKG + ".")):
                    continue
                plain = []
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    if alias.name != "*" and sub in modules:  # `from pkg import submodule`
                        out.append(_Import(mod, sub, (), path, node.lineno,
                                           alias.asname or alias.name))
                    else:
                        plain.append(alias.name)
                if plain:
                    out.append(_Import(mod, base, tuple(plain), path, node.lineno))
    return out


@pytest.fixture(scope="module")
def graph():
    modules = _parse()
    imports = _imports(modules)
    unknown = sorted({f"{i.where()}: {i.target}" for i in imports if i.target not in modules})
    assert not unknown, "imports of modules that do not exist:\n  " + "\n  ".join(unknown)
    return modules, imports


def _unit(module: str) -> str:
    """`jthermo.identify.fit` -> `identify`; the package root -> ``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """One circle through every strongly connected component of more than one module (or a
    module importing itself), found with Tarjan's algorithm (iterative)."""
    index, low, on_stack, stack, sccs = {}, {}, set(), [], []
    counter = 0
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            advanced = False
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                    advanced = True
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1 or v in edges[v]:
                    sccs.append(set(comp))
    circles = []
    for comp in sccs:
        start = min(comp)
        # the shortest circle back to `start` inside the component (breadth first)
        prev, frontier, found = {start: None}, [start], None
        while frontier and found is None:
            nxt = []
            for v in frontier:
                for w in sorted(edges[v] & comp):
                    if w == start:
                        found = v
                        break
                    if w not in prev:
                        prev[w] = v
                        nxt.append(w)
                if found is not None:
                    break
            frontier = nxt
        path, v = [], found
        while v is not None:
            path.append(v)
            v = prev[v]
        circle = path[::-1] + [start]
        rest = sorted(comp - set(circle))
        circles.append(circle + ([f"(component also holds: {', '.join(rest)})"] if rest else []))
    return sorted(circles)


def test_every_unit_has_a_layer(graph):
    modules, _ = graph
    missing = sorted({_unit(m) for m in modules} - set(RANK))
    assert not missing, f"modules of jthermo with no layer in LAYERS: {missing}"


def test_no_import_circle(graph):
    modules, imports = graph
    edges: dict[str, set[str]] = {m: set() for m in modules}
    where: dict[tuple[str, str], str] = {}
    for i in imports:
        edges[i.importer].add(i.target)
        where.setdefault((i.importer, i.target), i.where())
    circles = _cycles(edges)
    lines = []
    for c in circles:
        hops = [m for m in c if not m.startswith("(")]
        steps = [f"{a} -> {b} ({where[a, b]})" for a, b in itertools.pairwise(hops)]
        lines.append(" -> ".join(c) + "\n      " + "\n      ".join(steps))
    assert not circles, f"{len(circles)} import circle(s):\n  " + "\n  ".join(lines)


def test_layers_import_only_downward(graph):
    _, imports = graph
    bad = []
    for i in imports:
        a, b = _unit(i.importer), _unit(i.target)
        if a == b or a not in RANK or b not in RANK:
            continue  # within a unit, circles are test_no_import_circle's business
        if RANK[b] > RANK[a]:
            bad.append(f"{i.where()}: {i.importer} (layer {RANK[a]}) imports {i.target} "
                       f"(layer {RANK[b]}): upward")
        elif RANK[b] == RANK[a]:
            bad.append(f"{i.where()}: {i.importer} imports {i.target}: siblings in layer "
                       f"{RANK[a]} {LAYERS[RANK[a]]} must not import each other")
    assert not bad, f"{len(bad)} import(s) against the layers:\n  " + "\n  ".join(sorted(bad))


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _private_uses(modules, imports) -> list[str]:
    """Private names of one module used by another: imported by name, or read through a
    module alias (`from . import mechanisms as M` ... `M._x`)."""
    bad = [f"{i.where()}: {i.importer} imports {n} from {i.target}"
           for i in imports for n in i.names if _private(n)]
    for mod, (path, tree) in modules.items():
        aliases = {i.bound: i.target for i in imports
                   if i.importer == mod and i.bound and i.target != mod}
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases and _private(node.attr)):
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: {mod} uses "
                           f"{node.value.id}.{node.attr} of {aliases[node.value.id]}")
    return sorted(set(bad))


def test_no_private_name_crosses_modules(graph):
    """`from .design import _as_ss` reaches into another module's internals: a violation.
    Importing a private MODULE (`from ._base import AbstractController`,
    `from . import _lm`) is fine; the rule is about the names."""
    bad = _private_uses(*graph)
    assert not bad, f"{len(bad)} private name(s) used outside their module:\n  " + "\n  ".join(bad)


#: the most lines a file of the package may have (a longer one is split along a seam)
MAX_LINES = 500
STUDY_DIRS = ("benchmarks", "experiments")


def test_no_package_file_over_max_lines(graph):
    modules, _ = graph
    lines = {path: len(path.read_text(encoding="utf-8").splitlines())
             for path, _ in modules.values()}
    long = sorted(f"{p.relative_to(ROOT)}: {n} lines" for p, n in lines.items() if n > MAX_LINES)
    assert not long, f"{len(long)} package file(s) over {MAX_LINES} lines:\n  " + "\n  ".join(long)


def _study_edges(scripts: dict[str, Path]) -> dict[str, set[str]]:
    """`folder/name` -> the study scripts it imports. A script imports another by its bare name
    (`import identification`, `from common import load`): one of its own folder when there is
    one, else one of `benchmarks/` (experiments put that folder on `sys.path`)."""
    edges: dict[str, set[str]] = {key: set() for key in scripts}
    for key, path in scripts.items():
        folder = key.partition("/")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.partition(".")[0]
                target = next((t for t in (f"{folder}/{top}", f"benchmarks/{top}")
                               if t in scripts), None)
                if target is not None and target != key:
                    edges[key].add(target)
    return edges


def test_no_import_circle_among_study_scripts():
    scripts = {f"{d}/{p.stem}": p for d in STUDY_DIRS for p in sorted((ROOT / d).glob("*.py"))}
    assert scripts, f"no study scripts under {', '.join(STUDY_DIRS)}"
    circles = _cycles(_study_edges(scripts))
    assert not circles, f"{len(circles)} import circle(s) among the study scripts:\n  " + \
        "\n  ".join(" -> ".join(c) for c in circles)


# --- the checker itself, on a small made-up package ---------------------------------------

def test_checker_finds_circles_and_resolves_relative_imports():
    assert _resolve_relative("jthermo.control.lqg", False, 1, "design") == "jthermo.control.design"
    assert _resolve_relative("jthermo.control", True, 1, "_base") == "jthermo.control._base"
    assert _resolve_relative("jthermo.control.lqg", False, 2, "errors") == "jthermo.errors"
    assert _resolve_relative("jthermo.cli", False, 1, None) == "jthermo"
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"d"}, "e": {"a"}}
    assert _cycles(edges) == [["a", "b", "c", "a"], ["d", "d"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
    assert _unit("jthermo.identify.fit") == "identify" and _unit("jthermo") == ""


def test_checker_reads_imports_names_and_aliases():
    src = {
        "jthermo.control.lqg": ("jthermo/control/lqg.py",
                                ("from .design import _as_ss, lambda_gains\n"
                                 "from ._base import AbstractController\n"
                                 "def f():\n    from .. import __version__, data as D\n"
                                 "    return D._private\n")),
        "jthermo.control.design": ("jthermo/control/design.py", ""),
        "jthermo.control._base": ("jthermo/control/_base.py", ""),
        "jthermo.control": ("jthermo/control/__init__.py", "from . import lqg\n"),
        "jthermo.data": ("jthermo/data.py", "import jthermo.control.lqg as L\nimport numpy\n"),
        "jthermo": ("jthermo/__init__.py", ""),
    }
    modules = {m: (ROOT / p, ast.parse(s)) for m, (p, s) in src.items()}
    imports = _imports(modules)
    got = {(i.importer, i.target, i.names, i.bound) for i in imports}
    assert got == {
        ("jthermo.control.lqg", "jthermo.control.design", ("_as_ss", "lambda_gains"), None),
        ("jthermo.control.lqg", "jthermo.control._base", ("AbstractController",), None),
        ("jthermo.control.lqg", "jthermo", ("__version__",), None),
        ("jthermo.control.lqg", "jthermo.data", (), "D"),
        ("jthermo.control", "jthermo.control.lqg", (), "lqg"),
        ("jthermo.data", "jthermo.control.lqg", (), "L"),
    }
    assert [n for n in ("_as_ss", "lambda_gains", "__version__", "_base") if _private(n)] == [
        "_as_ss", "_base"]
    assert _private_uses(modules, imports) == [
        "jthermo/control/lqg.py:1: jthermo.control.lqg imports _as_ss from jthermo.control.design",
        "jthermo/control/lqg.py:5: jthermo.control.lqg uses D._private of jthermo.data",
    ]


def test_checker_resolves_study_imports(tmp_path):
    """Own folder first, then `benchmarks/`; package and library imports are no edges."""
    src = {"benchmarks/common": "import os\n",
           "benchmarks/identification": "from common import load\nimport peers_fair\n",
           "benchmarks/peers_fair": "def f():\n    from identification import T\n",
           "experiments/identify": "import identification, jthermo.data\nfrom . import x\n",
           "experiments/common": "import numpy\n",
           "experiments/uses_own": "from common import cpu_seconds\n"}
    scripts = {}
    for key, text in src.items():
        path = tmp_path / f"{key}.py"
        path.parent.mkdir(exist_ok=True)
        path.write_text(text)
        scripts[key] = path
    edges = _study_edges(scripts)
    assert edges["benchmarks/identification"] == {"benchmarks/common", "benchmarks/peers_fair"}
    assert edges["experiments/identify"] == {"benchmarks/identification"}
    assert edges["experiments/uses_own"] == {"experiments/common"}
    assert _cycles(edges) == [["benchmarks/identification", "benchmarks/peers_fair",
                               "benchmarks/identification"]]
