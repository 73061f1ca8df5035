"""`circcal demo` after a plain `pip install circcal` (no kornia, pycolmap or lensboy) exited 1 with "SOME CHECKS
FAILED: kornia [fair] is available, ...": a reference that is not installed is now listed with its pip line and does
not fail the demo, except with --require-all (`make demo` gives it: `make setup` installs every reference); `circcal
validate --against all` still fails on one and names --allow-missing."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from circcal.cli import main

REPO = Path(__file__).resolve().parents[1]
PIP = "pip install pycolmap pyceres"


@pytest.fixture
def pycolmap_missing(monkeypatch):
    """The references: opencv, and pycolmap as a plain `pip install circcal` has it (not importable)."""
    from circcal.validators import registry
    from circcal.validators.base import BaseCalibrator

    class Missing(BaseCalibrator):
        name = "pycolmap"
        modes = ("fair",)

        def _available(self):
            return False, f"pycolmap not importable (No module named 'pycolmap'); {PIP}"

    real_get = registry.get
    monkeypatch.setattr(registry, "get", lambda n, **kw: Missing() if n == "pycolmap" else real_get(n, **kw))
    monkeypatch.setattr(registry, "names", lambda: ["opencv", "pycolmap"])


def _verdict(out: str) -> str:
    """The lines after the checks: the verdict and what follows it."""
    return out.rsplit("\nchecks:\n", 1)[1].split("\n\n", 1)[1]


def test_demo_lists_a_reference_not_installed_and_passes(pycolmap_missing, capsys):
    assert main(["demo", "--scenario", "small-noisy"]) == 0
    out = capsys.readouterr().out
    assert "circcal validate small-noisy --against all --allow-missing" in out
    assert PIP in out
    verdict = _verdict(out)
    assert verdict.startswith("all checks passed"), verdict
    assert "not installed, so not checked: pycolmap" in verdict


def test_demo_requires_every_reference_where_asked(pycolmap_missing, capsys):
    assert main(["demo", "--scenario", "small-noisy", "--require-all"]) == 1
    verdict = _verdict(capsys.readouterr().out)
    assert verdict.startswith("SOME CHECKS FAILED: pycolmap [fair] is available"), verdict
    assert "--allow-missing" in verdict


def test_validate_all_names_allow_missing_when_a_reference_is_not_installed(pycolmap_missing, capsys):
    assert main(["validate", "small-noisy", "--against", "all", "--no-progress"]) == 1
    verdict = _verdict(capsys.readouterr().out)
    assert "not installed: pycolmap" in verdict and "--allow-missing" in verdict, verdict
    assert main(["validate", "small-noisy", "--against", "all", "--no-progress", "--allow-missing"]) == 0


def test_make_demo_requires_every_reference():
    """`make setup` installs every reference, so `make demo` checks them all."""
    text = (REPO / "Makefile").read_text()
    recipe = re.search(r"^demo:.*\n((?:\t.*\n)+)", text, re.M).group(1)
    assert "$(VENV)/bin/circcal demo --require-all" in recipe
