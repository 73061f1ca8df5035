"""Every public function of the listed packages has a numpydoc docstring: a 'Parameters' section when it takes
parameters, and a 'Returns' (or 'Yields') section when it returns something (issue 32).

Read from the source (ast), so nothing is imported. Public: a module-level function or class whose name has no
leading underscore or is in the module's ``__all__``, and the public methods of a public class (properties
excepted: they are documented as attributes). Modules whose name starts with an underscore are skipped.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent / "circcal"

#: The packages (folders under circcal/) held to the rule; "" is circcal/'s own modules (not its folders).
PACKAGES: tuple[str, ...] = (
    "",
    "model",
    "solver",
    "formats",
    "analysis",
    "validators",
    "fixtures",
    "calreport",
    "report",
    "study",
    "commands",
    "detector",
    "rig",
)


def _sections(doc: str | None) -> set[str]:
    """The numpydoc section titles of a docstring: a line followed by a line of dashes."""
    lines = (doc or "").splitlines()
    return {a.strip() for a, b in zip(lines, lines[1:]) if a.strip() and b.strip() and set(b.strip()) == {"-"}}


_NESTED = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)


def _own_nodes(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> Iterator[ast.AST]:
    """The nodes of a function's body, not descending into nested functions, lambdas or classes."""
    stack: list[ast.AST] = [n for n in fn.body if not isinstance(n, _NESTED)]
    while stack:
        node = stack.pop()
        yield node
        stack.extend(c for c in ast.iter_child_nodes(node) if not isinstance(c, _NESTED))


def _needs(fn: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> tuple[bool, bool, bool]:
    """(takes parameters, returns something, is a generator) for a function node."""
    a = fn.args
    params = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
    if method and params and params[0] in ("self", "cls"):
        params = params[1:]
    takes = bool(params or a.vararg or a.kwarg)
    body = list(_own_nodes(fn))
    generator = any(isinstance(n, (ast.Yield, ast.YieldFrom)) for n in body)
    if fn.returns is not None:
        r = fn.returns
        none = isinstance(r, ast.Constant) and r.value is None
        never = isinstance(r, ast.Name) and r.id in ("NoReturn", "Never")
        returns = not (none or never)
    else:
        returns = any(
            isinstance(n, ast.Return)
            and n.value is not None
            and not (isinstance(n.value, ast.Constant) and n.value.value is None)
            for n in body
        )
    return takes, returns, generator


def _is_property(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    """A property (or a typing overload stub, documented on its implementation): no sections needed."""
    for d in fn.decorator_list:
        if (isinstance(d, ast.Name) and d.id == "overload") or (isinstance(d, ast.Attribute) and d.attr == "overload"):
            return True
        if isinstance(d, ast.Name) and d.id in ("property", "cached_property"):
            return True
        if isinstance(d, ast.Attribute) and d.attr in ("setter", "deleter", "cached_property"):
            return True
    return False


def public_functions(package: str) -> Iterator[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef, bool]]:
    """(where, node, is_method) for every public function and public method of a package under circcal/."""
    paths = (ROOT / package).rglob("*.py") if package else ROOT.glob("*.py")
    for path in sorted(paths):
        rel = path.relative_to(ROOT.parent)
        if any(p.startswith("_") and p != "__init__.py" for p in rel.parts):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names: set[str] = set()
        for node in tree.body:
            if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets
            ):
                if isinstance(node.value, (ast.List, ast.Tuple)):
                    names = {e.value for e in node.value.elts if isinstance(e, ast.Constant)}
        for node in tree.body:
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                continue
            public = not node.name.startswith("_") or node.name in names
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and public and not _is_property(node):
                yield f"{rel}:{node.lineno} {node.name}", node, False
            elif isinstance(node, ast.ClassDef) and public:
                for m in node.body:
                    if (
                        isinstance(m, (ast.FunctionDef, ast.AsyncFunctionDef))
                        and not m.name.startswith("_")
                        and not _is_property(m)
                    ):
                        yield f"{rel}:{m.lineno} {node.name}.{m.name}", m, True


def missing_sections(node: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> list[str]:
    """What a function's docstring lacks: "docstring", "Parameters", "Returns", "Yields"."""
    doc = ast.get_docstring(node)
    if doc is None:
        return ["docstring"]
    takes, returns, generator = _needs(node, method)
    have = _sections(doc)
    missing = []
    if takes and "Parameters" not in have:
        missing.append("Parameters")
    if generator and not have & {"Yields", "Returns"}:
        missing.append("Yields")
    elif returns and not generator and "Returns" not in have:
        missing.append("Returns")
    return missing


@pytest.mark.parametrize("package", PACKAGES)
def test_public_functions_have_numpydoc_sections(package: str) -> None:
    found = list(public_functions(package))
    assert found, f"no public function found in circcal/{package or '*.py'}"
    bad = [f"{where}: lacks {', '.join(m)}" for where, node, method in found if (m := missing_sections(node, method))]
    assert not bad, f"{len(bad)} of {len(found)} public functions lack numpydoc sections:\n" + "\n".join(bad)


def _parse_def(src: str) -> tuple[ast.FunctionDef, bool]:
    tree = ast.parse(src)
    node = tree.body[0]
    if isinstance(node, ast.ClassDef):
        return node.body[0], True  # type: ignore[return-value]
    return node, False  # type: ignore[return-value]


@pytest.mark.parametrize(
    "src, missing",
    [
        ('def f(a):\n    """One line."""\n    return a\n', ["Parameters", "Returns"]),
        ("def f():\n    return 1\n", ["docstring"]),
        ('def f() -> None:\n    """One line."""\n', []),
        ('def f():\n    """One line."""\n    def g():\n        return 1\n', []),
        ('def f():\n    """One line."""\n    yield 1\n', ["Yields"]),
        ('def f(x) -> int:\n    """One.\n\n    Parameters\n    ----------\n    x : int\n    """\n', ["Returns"]),
        ('class C:\n    def m(self) -> None:\n        """One line."""\n', []),
        ('class C:\n    def m(self, x):\n        """One line."""\n        return x\n', ["Parameters", "Returns"]),
        (
            'def f(x):\n    """One.\n\n    Parameters\n    ----------\n    x : int\n\n    Returns\n    -------\n'
            '    int\n    """\n    return x\n',
            [],
        ),
    ],
)
def test_the_rule_itself(src: str, missing: list[str]) -> None:
    node, method = _parse_def(src)
    assert missing_sections(node, method) == missing
