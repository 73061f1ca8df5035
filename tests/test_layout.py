"""The repository's layout promises: one installed import package (``circcal``), layers that import only downward
(the import-linter contract in pyproject.toml), and no code that imports the repository folders by their own
top-level names."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from tests.repo_copy import git_files_copy

REPO = Path(__file__).resolve().parents[1]
#: Top-level import names the repository must not install (PyPI has popular packages called validators and
#: fixtures; benchmarks are run from the checkout, never installed).
FORBIDDEN_TOP_LEVEL = ("validators", "fixtures", "benchmarks", "tests")


def _layers() -> list[str]:
    import tomllib

    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]
    (contract,) = [c for c in cfg["contracts"] if c["type"] == "layers"]
    return [m.strip() for layer in contract["layers"] for m in layer.split("|")]


def test_import_contract_holds_and_covers_every_module():
    """lint-imports passes, and the graph it checks holds every module of every layer (a layer whose package the
    graph cannot see would make the contract pass vacuously)."""
    import grimp

    exe = Path(sys.executable).with_name("lint-imports")
    run = subprocess.run(
        [str(exe), "--config", str(REPO / "pyproject.toml")], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "1 kept, 0 broken" in run.stdout, run.stdout
    graph = grimp.build_graph("circcal")
    on_disk = {
        ".".join((Path(d) / f).relative_to(REPO).with_suffix("").parts).removesuffix(".__init__")
        for d, _, files in os.walk(REPO / "circcal", followlinks=True)
        for f in files
        if f.endswith(".py")
    }
    assert on_disk - set(graph.modules) == set()
    for layer in _layers():
        assert any(m == layer or m.startswith(layer + ".") for m in graph.modules), f"layer {layer} is empty"
    every = {m for m in graph.modules if m != "circcal"}
    layered = {m for m in every if any(m == x or m.startswith(x + ".") for x in _layers())}
    assert every - layered == set(), "modules outside every layer (add them to the contract)"


def test_wheel_installs_only_circcal(tmp_path):
    """``pip install .`` installs the import package circcal and nothing else at the top level; the validators and
    fixtures folders arrive as circcal.validators and circcal.fixtures."""
    # built from a copy of what git would commit (so a build leaves nothing in the checkout, and a file that is
    # not added cannot make the test pass); links are copied as links
    src = tmp_path / "src"
    git_files_copy(src)
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(tmp_path),
            str(src),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    (wheel,) = tmp_path.glob("circcal-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names}
    assert {t for t in top if not t.endswith((".dist-info", ".data"))} == {"circcal"}, sorted(top)
    for sub in (
        "circcal/validators/base.py",
        "circcal/fixtures/scenarios.py",
        "circcal/report/__init__.py",
        "circcal/detector/__init__.py",
        "circcal/solver/__init__.py",
        "circcal/report/templates/report.md.j2",
        "circcal/report/templates/report.html.j2",
    ):
        assert sub in names
    info = next(n for n in names if n.endswith(".dist-info/top_level.txt"))
    assert zipfile.ZipFile(wheel).read(info).decode().split() == ["circcal"]
    entry = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "circcal = circcal.validators.pytest_plugin" in entry


@pytest.mark.parametrize("folder", ["circcal", "validators", "fixtures", "tests", "benchmarks"])
def test_no_code_imports_the_folders_by_their_top_level_names(folder):
    """Inside the checkout ``import validators`` would work (the repository root is on the path) and break for
    every user of the installed package: the code says circcal.validators / circcal.fixtures everywhere."""
    pattern = re.compile(r"^\s*(from|import)\s+(validators|fixtures)\b", re.M)
    offenders = [
        str(p.relative_to(REPO))
        for p in (REPO / folder).rglob("*.py")
        if not p.is_symlink() and pattern.search(p.read_text())
    ]
    assert offenders == []


def test_no_package_inside_circcal_is_a_link():
    """circcal/validators and circcal/fixtures were links to top-level folders (broken on checkouts without
    symlinks, e.g. Windows without core.symlinks): every folder and module of the package is a real one."""
    links = [p.relative_to(REPO) for p in (REPO / "circcal").rglob("*") if p.is_symlink()]
    assert links == []
    for top in ("validators", "fixtures"):  # the top-level folders hold docs, no code
        assert not list((REPO / top).glob("*.py")), f"{top}/ holds Python modules: they belong in circcal/{top}/"
