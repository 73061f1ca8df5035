"""`circcal validate`: every reference on circcal's observations, per-reference statuses, gating exit codes."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from circcal.cli import main
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.truth import load_truth
from circcal.validators import registry
from circcal.validators.base import BaseCalibrator
from circcal.validators.validate import run_validation


class Broken(BaseCalibrator):
    """A reference that crashes inside its solve."""

    name = "broken"
    modes = ("fair",)

    def _version(self) -> str:
        return "0"

    def _available(self):
        return True, ""

    def _calibrate(self, object_points, image_points, image_size, *, mode, initial):
        raise RuntimeError("solver exploded")


@pytest.fixture(scope="module")
def small():
    return load_truth(fixture_dir("small-noisy", "noisy"))


@pytest.fixture(scope="module")
def run_with_broken(small):
    mp = pytest.MonkeyPatch()
    mp.setitem(registry.BUILTINS, "broken", "tests.test_validate:Broken")
    try:
        yield run_validation(
            [v.image for v in small.views],
            small.board,
            truth=small.camera,
            against=["opencv", "broken", "pycolmap"],
            progress=False,
        )
    finally:
        mp.undo()


def test_crashing_reference_is_a_row_and_others_still_run(run_with_broken):
    run = run_with_broken
    by_name = {r.name: r for r in run.references}
    assert by_name["broken"].status == "failed" and "solver exploded" in by_name["broken"].message
    assert by_name["opencv"].ok and by_name["pycolmap"].ok
    assert not run.passed
    failed = [c.name for c in run.checks if not c.passed]
    assert failed == ["broken [fair] runs"]


def test_identical_observations_agree_and_truth_is_within_sigmas(run_with_broken):
    run = run_with_broken
    assert run.circcal["status"] == "ok"
    for row in run.comparisons[1:]:
        if row["name"] in ("opencv", "pycolmap"):
            assert row["vs_circcal"]["max_px"] <= 1e-6
    params = run.comparisons[0]["vs_truth"]["params"]
    assert all(abs(params[n]["diff_sigmas"]) <= 3 for n in ("fx", "fy", "cx", "cy"))
    # circcal's mean 2-D error on this noisy 640x480 set stays well below the paper's 0.12 px
    assert run.circcal["errors"]["mean_2d_px"] < 0.12


def test_cli_gates_and_writes_an_atomic_report(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("CIRCCAL_MRCAL_PYTHON", "/nonexistent/python")
    out = tmp_path / "rep"
    code = main(["validate", "small-noisy", "--against", "opencv,mrcal", "--report", str(out), "--no-progress"])
    text = capsys.readouterr().out
    # mrcal was asked for by name and is missing: reported with the install hint, and the gate fails
    assert code == 1
    assert "mrcal" in text and "apt-get install -y mrcal python3-mrcal" in text
    data = json.loads((out / "validation.json").read_text())
    assert data["passed"] is False
    statuses = {r["name"]: r["status"] for r in data["references"]}
    assert statuses == {"opencv": "ok", "mrcal": "unavailable"}
    assert (out / "validation.md").read_text().startswith("# circcal validation")
    assert not list(tmp_path.glob(".rep-*"))  # no temp folder left behind
    # with 'all', a missing reference is reported but does not fail the gate
    code = main(["validate", "small-noisy", "--against", "opencv", "--no-progress"])
    assert code == 0


def test_cli_rejects_unknown_reference(capsys):
    assert main(["validate", "small-noisy", "--against", "nosuch", "--no-progress"]) == 2
    assert "unknown reference calibrator 'nosuch'" in capsys.readouterr().err


def test_solver_agreement_rule():
    """Within the px bound: pass. Beyond it: pass only for a cost tie (a flat direction double precision cannot
    resolve); a reference with a higher cost, or a lower one (circcal missed the minimum), fails."""
    from circcal.validators.checks import COST_TIE_REL, solver_agreement
    from circcal.validators.reference_result import ReferenceResult

    def ref(ssr: float) -> ReferenceResult:
        r = np.full((50, 2), np.sqrt(ssr / 100.0))
        return ReferenceResult("x", "1", "fair", "ok", residuals=[r])

    base = 0.5
    assert solver_agreement("x", ref(base * 1.3), 5e-7, base, 1e-6).passed  # inside the bound: costs not consulted
    tie = solver_agreement("x", ref(base * (1 + 0.1 * COST_TIE_REL)), 4e-6, base, 1e-6)
    assert tie.passed and "flat direction" in tie.note
    higher = solver_agreement("x", ref(base * (1 + 1e-6)), 4e-6, base, 1e-6)
    assert not higher.passed and "did not reach the minimum" in higher.note
    lower = solver_agreement("x", ref(base * (1 - 1e-6)), 4e-6, base, 1e-6)
    assert not lower.passed and "circcal missed the minimum" in lower.note


def test_validate_cannot_pass_vacuously(tmp_path):
    """Zero checks is not "all checks passed", nor a failed check: own images (no truth) against no reference
    compare nothing; own detectors compare but gate nothing; each says why with the option that would check."""
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth
    from circcal.validators.validate import run_validation, verdict

    truth = load_truth(fixture_dir("small-noisy"))
    run = run_validation([v.image for v in truth.views], truth.board, against=[], progress=False)
    assert run.checks == [] and not run.passed and run.state == "nothing compared"
    lines, status = verdict(run)
    assert status == 1 and lines[0].startswith("NOTHING COMPARED")
    assert any("--against" in h for h in run.hints) and any("--fixtures" in h for h in run.hints)
    run = run_validation(
        [v.image for v in truth.views], truth.board, against=["opencv"], observations="own", progress=False
    )
    assert run.checks == [] and not run.passed and run.state == "not gated"
    lines, status = verdict(run)
    assert status == 0 and lines[0].startswith("nothing gated")
    assert any("--observations circcal" in h for h in run.hints)


def test_own_observations_are_compared_not_failed(small, capsys):
    """The issue's run: own images, --observations own, opencv and mrcal: no FAIL line, exit 0, and every hint names
    a command-line option, never a Python function."""
    from circcal.formats.mrcal_process import mrcal_python

    mrcal = mrcal_python()[0] is not None  # mrcal asked for by name and missing would fail the run (its own test)
    paths = [str(v.image) for v in small.views]
    code = main(
        ["validate", "--images", *paths, "--grid", "7x9", "--pitch", "10mm", "--diameter", "4mm"]
        + ["--observations", "own", "--against", "opencv,mrcal" if mrcal else "opencv", "--no-progress"]
    )
    out = capsys.readouterr().out
    assert code == 0, out
    if mrcal:  # mrcal has no circle detector: its reason points to the option that makes it fit circcal's centres
        assert "mrcal [fair]: unsupported" in out and "with --observations circcal it fits" in out
    assert "FAIL" not in out and "SOME CHECKS FAILED" not in out and "something was checked" not in out
    assert "nothing gated" in out and "--observations circcal" in out
    assert "calibrate_observations" not in out and not re.search(r"\b[a-z_]+\(\)", out)
    assert "images unusable" not in out  # every image gave a view


def test_unusable_images_are_counted_and_gated(small, tmp_path, capsys):
    """10 unreadable files beside 4 good images: the verdict counts them; below --min-images (default half) the run
    fails; with a lower count it passes, still saying how many were unusable."""
    paths = [str(v.image) for v in small.views[:4]]
    for i in range(10):
        bad = tmp_path / f"bad{i}.png"
        bad.write_bytes(f"not an image {i}".encode())
        paths.append(str(bad))
    common = ["--grid", "7x9", "--pitch", "10mm", "--diameter", "4mm", "--against", "opencv", "--no-progress"]
    assert main(["validate", "--images", *paths, *common]) == 1
    out = capsys.readouterr().out
    assert "FAIL images usable: 4 (bound 7)" in out and "10 of 14 images unusable" in out
    assert main(["validate", "--images", *paths, *common, "--min-images", "4"]) == 0
    out = capsys.readouterr().out
    assert "all checks passed" in out and "10 of 14 images unusable" in out
    assert main(["validate", "--images", *paths, *common, "--min-images", "25%"]) == 0  # 3.5 images: 4
    capsys.readouterr()


@pytest.mark.parametrize("text,value", [("4", 4), ("50%", 0.5), ("0.25", 0.25), ("100%", 1.0)])
def test_min_images_takes_a_count_or_a_share(text, value):
    from circcal.commands.validate import parse_min_images

    got = parse_min_images(text)
    assert got == value and type(got) is type(value)


@pytest.mark.parametrize("text", ["0", "-3", "150%", "1.5", "nan", "abc", "0%"])
def test_min_images_refuses_what_decides_nothing(text, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["validate", "small-noisy", "--against", "opencv", "--min-images", text, "--no-progress"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--min-images" in err and len(err.strip().splitlines()) <= 2


def test_mrcal_takes_asymmetric_boards_as_the_export_does():
    """One rule across validate and convert: the staggered grid maps onto mrcal's lattice with every other point
    missing, so mrcal solves it (fair mode agrees with circcal) as its tools read the exported file."""
    from circcal.formats.mrcal_process import board_lattice, mrcal_python

    truth = load_truth(fixture_dir("asymmetric"))
    lat = board_lattice([truth.board.object_points()])
    assert lat["width_n"] * lat["height_n"] == 2 * truth.board.n_points  # every other lattice point missing
    if mrcal_python()[0] is None:
        pytest.skip("mrcal not installed (apt-get install mrcal python3-mrcal)")
    run = run_validation(
        [v.image for v in truth.views], truth.board, truth=truth.camera, against=["mrcal"], mode="fair", progress=False
    )
    assert [r.status for r in run.references] == ["ok"], [r.message for r in run.references]
    assert run.passed and any(c.name.startswith("mrcal [fair]") for c in run.checks)


@pytest.mark.parametrize("tol", ["nan", "-1", "0", "inf", "abc"])
def test_validate_refuses_tolerances_that_decide_nothing(tol, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["validate", "small-noisy", "--against", "opencv", "--solver-tol", tol, "--no-progress"])
    assert exc.value.code == 2
    assert "--solver-tol" in capsys.readouterr().err


def test_validate_all_fails_when_a_built_in_reference_is_missing(monkeypatch):
    """Under --against all a built-in reference that is not installed fails the run (make setup installs them all);
    --allow-missing lists it as skipped instead."""
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth
    from circcal.validators import registry
    from circcal.validators.base import BaseCalibrator
    from circcal.validators.validate import run_validation

    class Missing(BaseCalibrator):
        name = "pycolmap"
        modes = ("fair",)

        def _available(self):
            return False, "pycolmap is not installed"

    real_get = registry.get
    monkeypatch.setattr(registry, "get", lambda n, **kw: Missing() if n == "pycolmap" else real_get(n, **kw))
    monkeypatch.setattr(registry, "names", lambda: ["opencv", "pycolmap"])
    truth = load_truth(fixture_dir("small-noisy"))
    paths = [v.image for v in truth.views]
    run = run_validation(paths, truth.board, truth=truth.camera, against=["all"], progress=False)
    bad = [c for c in run.checks if not c.passed]
    assert [c.name for c in bad] == ["pycolmap [fair] is available"] and not run.passed
    run = run_validation(paths, truth.board, truth=truth.camera, against=["all"], progress=False, allow_missing=True)
    assert run.passed and run.skipped == ["pycolmap [fair]: pycolmap is not installed"]


def test_suite_truth_bound_holds_the_family_wise_rate():
    """The conformance suite's truth bound: a correct estimator with honest Gaussian sigmas fails none of its
    observation_sets() x 4 independent parameter checks with probability >= 1 - SUITE_FAMILY_ALPHA (Bonferroni is
    conservative: the exact family-wise rate lies just below alpha), while the per-run 3 sigmas would fail it often."""
    from statistics import NormalDist

    from circcal.validators.case_matrix import SUITE_FAMILY_ALPHA, observation_sets, suite_truth_sigmas

    n = 4 * observation_sets()
    assert n >= 4 * 40  # every scenario-variant of the suite, not an empty count
    z = suite_truth_sigmas()
    per_check = 2 * (1 - NormalDist().cdf(z))
    family = 1 - (1 - per_check) ** n
    assert 0.9 * SUITE_FAMILY_ALPHA < family <= SUITE_FAMILY_ALPHA
    at_3 = 1 - (1 - 2 * (1 - NormalDist().cdf(3.0))) ** n
    assert at_3 > 0.3
