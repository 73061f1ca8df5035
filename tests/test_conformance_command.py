"""``circcal conformance`` as a user runs it: installed with its test runner, isolated from the pytest set-up of the
folder it runs in, bad option values stopped in one line before any work; and the docs' numbers for the suite.

(What the suite does with a calibrator's answer: test_conformance_user.py.)
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from circcal.validators.case_matrix import observation_sets, suite_truth_sigmas

REPO = Path(__file__).resolve().parents[1]

#: The environment of a user's shell: none of this test run's pytest variables.
ENV = {
    k: v
    for k, v in os.environ.items()
    if k not in ("PYTEST_ADDOPTS", "PYTEST_PLUGINS", "PYTEST_CURRENT_TEST") and not k.startswith("PYTEST_XDIST")
}

CALIBRATOR = """
def calibrate(object_points, image_points, image_size):
    raise AssertionError("not called when only collecting")
"""


def _circcal(cwd: Path, *args: str, pre: str = "") -> subprocess.CompletedProcess:
    code = f"{pre}import sys; from circcal.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run(
        [sys.executable, "-c", code, "conformance", *args],
        cwd=cwd,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_pytest_installs_with_circcal():
    import tomllib  # Python 3.11+

    deps = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    bounds = {re.split(r"[<>=!~\[; ]", d, maxsplit=1)[0]: d for d in deps}
    assert re.fullmatch(r"pytest>=\d+(\.\d+)*", bounds.get("pytest", "")), deps
    assert re.fullmatch(r"pytest-xdist>=\d+(\.\d+)*", bounds.get("pytest-xdist", "")), deps  # `-n 2` in the docs


def test_without_pytest_the_command_says_how_to_install_it_in_one_line(tmp_path):
    out = _circcal(tmp_path, "--calibrator", "mycal:calibrate", pre="import sys; sys.modules['pytest'] = None; ")
    assert out.returncode == 2, out.stderr[-2000:]
    assert out.stderr.strip().splitlines() == [
        "circcal conformance: error: circcal conformance runs the suite with pytest, which is not installed in this "
        "environment: pip install pytest"
    ]


def test_the_command_ignores_the_pytest_setup_of_the_folder_it_runs_in(tmp_path):
    (tmp_path / "mycal.py").write_text(CALIBRATOR)
    (tmp_path / "pytest.ini").write_text("[pytest]\naddopts = --cov=mypkg -x\ntestpaths = tests\n")
    (tmp_path / "pyproject.toml").write_text('[tool.pytest.ini_options]\naddopts = "--no-such-option"\n')
    (tmp_path / "conftest.py").write_text('raise RuntimeError("the user\'s conftest.py was loaded")\n')
    out = _circcal(tmp_path, "--calibrator", "mycal:calibrate", "--", "--collect-only")
    text = out.stdout + out.stderr
    assert out.returncode == 0, text[-3000:]
    assert re.search(r"test_conformance\.py::test_conformance\[paper-normal-calibrate\]", text), text[-3000:]
    assert "PytestAssertRewriteWarning" not in text and "warning" not in text.lower(), text[-3000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["conftest.py", "mycal.py", "pyproject.toml", "pytest.ini"]


@pytest.mark.parametrize("option, value", [("--calibrator-tol", "abc"), ("--calibrator-tol", "-1"), ("--bias-t", "0")])
def test_a_bad_option_value_is_one_line_naming_the_option(tmp_path, option, value):
    (tmp_path / "mycal.py").write_text(CALIBRATOR)
    out = _circcal(tmp_path, "--calibrator", "mycal:calibrate", option, value)
    assert out.returncode == 2, (out.stdout + out.stderr)[-3000:]
    assert out.stderr.strip().splitlines() == [
        f"circcal conformance: error: {option}: expected a number > 0 ('inf': no bound), got '{value}'"
    ]
    assert out.stdout == ""  # stopped before pytest ran


def test_the_plugin_refuses_a_bound_that_is_not_positive(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "--pyargs", "circcal.conformance", "-p", "no:cacheprovider", "--co", "-q"]
        + ["--calibrator-tol", "-1"],
        cwd=tmp_path,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 4, (out.stdout + out.stderr)[-3000:]
    assert "--calibrator-tol: expected a number > 0 ('inf': no bound), got -1.0" in out.stdout + out.stderr


def test_the_docs_state_the_truth_bound_the_suite_uses():
    text = (REPO / "docs" / "validation.md").read_text()
    bound, sets = f"{suite_truth_sigmas():.2f}", observation_sets()
    assert f"fx, fy, cx, cy within {bound} of their stated standard deviations" in text
    assert f"over the suite's\n  {sets} observation sets" in text
    assert f"## Why the suite's truth bound is {bound}" in text


def test_the_docs_say_where_the_example_calibrator_lives():
    text = (REPO / "docs" / "validation.md").read_text()
    assert (REPO / "tests" / "conformance" / "example_calibrator.py").is_file()
    assert "`tests/conformance/example_calibrator.py`, not in the installed package" in text
    assert "def opencv_calibrate(object_points, image_points, image_size):" in text
