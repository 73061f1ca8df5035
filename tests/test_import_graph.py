"""No circcal module imports another that imports it back (issue 32).

The import-linter contract (pyproject.toml, run by tests/test_layout.py) keeps the layers pointing downward, but it
says nothing about cycles *inside* a layer or a package. This test parses every module of ``circcal`` with ``ast``
and builds the graph module -> module from every ``import`` / ``from ... import`` that can run: at module level, in
class bodies and inside functions (a function-level import is a cycle that waits for its first call), with relative
imports resolved; the bodies of ``if TYPE_CHECKING:`` blocks are left out (they never run; their ``else`` runs).

How a name is resolved (what Python itself executes):

* ``import circcal.a.b`` and ``from circcal.a.b import name`` are edges to ``circcal.a.b`` (for a package, its
  ``__init__``);
* ``from circcal.a import b`` is an edge to ``circcal.a.b`` when ``b`` is a submodule, else to ``circcal.a``: a
  submodule taking a name from its own package's ``__init__`` while that ``__init__`` imports the submodule is a
  cycle in Python too (the name may not exist yet), and it counts;
* the parent packages Python imports on the way (``circcal.a`` before ``circcal.a.b``) are not edges: a parent is
  already in ``sys.modules`` when its children run, so that order never breaks;
* dynamic imports (``importlib.import_module``, entry points) are not seen.

The strongly connected components of that graph (Tarjan's algorithm) with more than one module are the cycles. The
known ones are listed in :data:`KNOWN_CYCLES`, each with what removes it; the list only shrinks: a cycle outside it
fails, and so does an entry whose cycle no longer exists exactly as listed (remove or narrow it).
"""

from __future__ import annotations

import ast
import os
from collections import Counter, deque
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = "circcal"

#: The cycles that exist today, each (its modules, what will remove it). Shrink it; never add to it to make a new
#: cycle pass: break the new cycle instead (move what both need into a smaller module, or pass a function).
KNOWN_CYCLES: tuple[tuple[frozenset[str], str], ...] = ()


@dataclass(frozen=True)
class Edge:
    """One import statement's edge: ``importer`` imports ``imported`` at ``line``; ``in_function``: inside a def."""

    importer: str
    imported: str
    line: int
    in_function: bool

    def __str__(self) -> str:
        where = "function-level" if self.in_function else "module-level"
        return f"{self.importer}:{self.line} -> {self.imported} ({where})"


def module_files(root: Path, package: str) -> dict[str, Path]:
    """Every module of ``package`` (its folder ``root``; links followed) by dotted name; a package is its
    ``__init__``."""
    out = {}
    for d, dirs, files in os.walk(root, followlinks=True):
        dirs[:] = sorted(x for x in dirs if x != "__pycache__")
        for f in files:
            if f.endswith(".py"):
                parts = (package, *(Path(d) / f).relative_to(root).with_suffix("").parts)
                name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
                out[name] = Path(d) / f
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.Module) -> list[tuple[ast.Import | ast.ImportFrom, bool]]:
    """Every import statement that can run, with whether it sits inside a function; ``if TYPE_CHECKING:`` bodies
    left out."""
    out: list[tuple[ast.Import | ast.ImportFrom, bool]] = []
    todo: list[tuple[ast.AST, bool]] = [(tree, False)]
    while todo:
        node, in_function = todo.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            out.append((node, in_function))
            continue
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            children = [node.test, *node.orelse]
        else:
            children = list(ast.iter_child_nodes(node))
        inner = in_function or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        todo.extend((c, inner) for c in children)
    return sorted(out, key=lambda x: x[0].lineno)


def _targets(
    node: ast.Import | ast.ImportFrom, importer: str, is_package: bool, modules: set[str], package: str
) -> list[str]:
    """The modules of ``package`` one statement imports (see the module docstring); a name that is no module of
    ``package`` and no name taken from one is returned as is, for the caller to report."""

    def ours(name: str) -> bool:
        return name == package or name.startswith(package + ".")

    if isinstance(node, ast.Import):
        return [a.name for a in node.names if ours(a.name)]
    if node.level:
        parts = importer.split(".") if is_package else importer.split(".")[:-1]
        parts = parts[: len(parts) - (node.level - 1)]
        base = ".".join(parts + ([node.module] if node.module else []))
    else:
        base = node.module or ""
    if not ours(base):
        return []
    out = []
    for a in node.names:
        sub = f"{base}.{a.name}"
        out.append(sub if a.name != "*" and sub in modules else base)
    return out


def import_graph(root: Path, package: str) -> tuple[dict[str, list[Edge]], list[Edge], set[str]]:
    """The import graph of ``package`` (folder ``root``): module -> its edges to modules of the package (self-imports
    left out), the edges whose target is no module of the package (broken imports), and every module."""
    files = module_files(root, package)
    modules = set(files)
    graph: dict[str, list[Edge]] = {m: [] for m in sorted(modules)}
    unresolved = []
    for name, path in sorted(files.items()):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node, in_function in _imports(tree):
            for target in dict.fromkeys(_targets(node, name, path.name == "__init__.py", modules, package)):
                edge = Edge(name, target, node.lineno, in_function)
                if target not in modules:
                    unresolved.append(edge)
                elif target != name:
                    graph[name].append(edge)
    return graph, unresolved, modules


def strongly_connected(graph: dict[str, list[Edge]]) -> list[frozenset[str]]:
    """Tarjan's strongly connected components of ``graph`` (iterative), those of more than one module only."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted({e.imported for e in graph[start]})))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted({e.imported for e in graph[w]}))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = set()
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.add(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(frozenset(comp))
    return out


def _shortest_cycle(graph: dict[str, list[Edge]], comp: frozenset[str]) -> list[Edge]:
    """A shortest cycle through the first module (by name) of the component ``comp``, as its edges."""
    start = min(comp)
    came: dict[str, Edge | None] = {start: None}
    todo = deque([start])
    while todo:
        v = todo.popleft()
        for e in graph[v]:
            if e.imported == start:
                path = [e]
                while came[path[0].importer] is not None:
                    path.insert(0, came[path[0].importer])  # type: ignore[arg-type]
                return path
            if e.imported in comp and e.imported not in came:
                came[e.imported] = e
                todo.append(e.imported)
    raise AssertionError(f"{sorted(comp)} is no strongly connected component")


def describe(graph: dict[str, list[Edge]], comp: frozenset[str]) -> str:
    """A cycle in words: its modules, a shortest loop and every edge between its modules, with line numbers."""
    edges = sorted(
        (e for m in comp for e in graph[m] if e.imported in comp), key=lambda e: (e.importer, e.line, e.imported)
    )
    loop = _shortest_cycle(graph, comp)
    return "\n".join(
        [
            f"cycle of {len(comp)} modules: {', '.join(sorted(comp))}",
            "  shortest loop: " + " -> ".join([e.importer for e in loop] + [loop[0].importer]),
            *(f"    {e}" for e in edges),
        ]
    )


# --- the checker itself, on a package generated here ---------------------------------------------------------------


def _write_package(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root / "pkg"


def test_checker_resolves_imports_as_python_runs_them(tmp_path):
    """Relative imports, submodule vs name, function-level imports, ``TYPE_CHECKING`` left out (its else kept),
    outside packages ignored, broken names reported."""
    root = _write_package(
        tmp_path,
        {
            "pkg/__init__.py": "from pkg.sub import thing\n",
            "pkg/base.py": "import os\nimport pkg.sub.leaf\n",
            "pkg/sub/__init__.py": "from .leaf import x\nfrom . import other\n",
            "pkg/sub/leaf.py": (
                "import typing\nfrom typing import TYPE_CHECKING\n"
                "if TYPE_CHECKING:\n    from pkg import base\nelse:\n    from ..base import os\n"
                "if typing.TYPE_CHECKING:\n    import pkg.sub.other\n"
                "def f():\n    from pkg.sub import other, x\n    from pkg.nothere import y\n"
                "    return other, x, y\n"
            ),
            "pkg/sub/other.py": "class A:\n    from pkg.sub import leaf as _l\n",
        },
    )
    graph, unresolved, modules = import_graph(root, "pkg")
    assert modules == {"pkg", "pkg.base", "pkg.sub", "pkg.sub.leaf", "pkg.sub.other"}
    got = {(e.importer, e.imported, e.line, e.in_function) for es in graph.values() for e in es}
    assert got == {
        ("pkg", "pkg.sub", 1, False),
        ("pkg.base", "pkg.sub.leaf", 2, False),
        ("pkg.sub", "pkg.sub.leaf", 1, False),
        ("pkg.sub", "pkg.sub.other", 2, False),
        ("pkg.sub.leaf", "pkg.base", 6, False),
        ("pkg.sub.leaf", "pkg.sub.other", 10, True),
        ("pkg.sub.leaf", "pkg.sub", 10, True),
        ("pkg.sub.other", "pkg.sub.leaf", 2, False),
    }
    assert [(e.importer, e.imported, e.line) for e in unresolved] == [("pkg.sub.leaf", "pkg.nothere", 11)]
    comps = strongly_connected(graph)
    assert comps == [frozenset({"pkg.base", "pkg.sub", "pkg.sub.leaf", "pkg.sub.other"})]
    text = describe(graph, comps[0])
    assert "pkg.sub.leaf:10 -> pkg.sub (function-level)" in text
    assert "shortest loop: pkg.base -> pkg.sub.leaf -> pkg.base" in text


def test_checker_finds_no_cycle_in_a_chain_and_each_of_several_cycles(tmp_path):
    """A diamond without a cycle has no component; two separate loops are two components; a self-import is no
    cycle."""
    root = _write_package(
        tmp_path,
        {
            "pkg/__init__.py": "",
            "pkg/a.py": "from pkg import b, c\nimport pkg.a\n",
            "pkg/b.py": "import pkg.d\n",
            "pkg/c.py": "def f():\n    import pkg.d\n",
            "pkg/d.py": "",
        },
    )
    graph, unresolved, _ = import_graph(root, "pkg")
    assert unresolved == [] and strongly_connected(graph) == []
    (root / "d.py").write_text("def f():\n    from pkg import c\n")
    (root / "x.py").write_text("from pkg.y import z\n")
    (root / "y.py").write_text("z = 1\ndef g():\n    from . import x\n")
    graph, _, _ = import_graph(root, "pkg")
    assert sorted(map(sorted, strongly_connected(graph))) == [["pkg.c", "pkg.d"], ["pkg.x", "pkg.y"]]


# --- circcal -------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def circcal_graph():
    return import_graph(REPO / PACKAGE, PACKAGE)


def test_every_circcal_import_names_a_module(circcal_graph):
    """Every import of a circcal name names a circcal module that exists (a stale function-level import fails only
    when its function first runs)."""
    _, unresolved, modules = circcal_graph
    assert len(modules) > 100  # the walk saw the package, links included
    assert unresolved == [], "\n".join(map(str, unresolved))


def test_no_import_cycles_beyond_the_shrinking_allow_list(circcal_graph):
    """No cycle among circcal modules outside :data:`KNOWN_CYCLES`, and every listed cycle still exists exactly as
    listed (a fixed or narrowed one must leave the list)."""
    graph, _, _ = circcal_graph
    per_module = Counter(e.importer for es in graph.values() for e in es if e.in_function)
    print(
        f"\nfunction-level imports of circcal modules (statement x module imported): {sum(per_module.values())}"
        f" in {len(per_module)} modules"
    )
    for m, n in sorted(per_module.items(), key=lambda x: (-x[1], x[0])):
        print(f"  {n:3d}  {m}")
    comps = strongly_connected(graph)
    known = {mods for mods, _ in KNOWN_CYCLES}
    assert len(known) == len(KNOWN_CYCLES), "KNOWN_CYCLES lists a cycle twice"
    new = [c for c in comps if c not in known]
    stale = [(mods, why) for mods, why in KNOWN_CYCLES if mods not in comps]
    problems = [describe(graph, c) + "\n  (new: break it; do not add it to KNOWN_CYCLES)" for c in new]
    for mods, why in stale:
        now = [c for c in comps if c & mods]
        problems.append(
            f"KNOWN_CYCLES entry {sorted(mods)} ({why}) no longer exists as listed: "
            + (
                "".join(f"its modules now form {sorted(c)}; " for c in now)
                + "replace the entry by a narrower cycle, break a wider one"
                if now
                else "fixed: remove it"
            )
        )
    assert not problems, "\n\n".join(problems)
