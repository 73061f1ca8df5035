"""circcal's conformance suite: every fixture scenario x variant x calibrator against ground truth and, on identical
observations, against circcal's solver (what each case asserts, and why each bound: validators/case_matrix.py).

The default run holds a fast slice (paper-normal and wide-clean, every calibrator; fisheye-clean and rational-wide-clean
with circcal, OpenCV, pycolmap and mrcal); `make conformance` runs the whole matrix (`-m 'slow or not slow'`). circcal's calibration of a scenario-variant is computed once per run and reused by
every reference case. With ``--calibrator MODULE:FN`` (the ``circcal`` pytest plug-in) the same cases test that
calibrator instead; the plug-in itself is tested at the end of this file.
The matrix's test is the installed suite's (``circcal/conformance/test_conformance.py``), collected here too.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import skip_unless_available

from circcal.board import Board
from circcal.conformance import test_conformance as _installed
from circcal.model import Camera, project
from circcal.rotation import rodrigues
from circcal.validators import scenario_observations
from circcal.validators.bias import bias_tests
from circcal.validators.case_matrix import CIRCCAL_UNSUPPORTED, Case, cases
from circcal.validators.case_run import failed_checks, predicted_truth_rms, run_reference_case
from circcal.validators.conformance_fixtures import ObservationCache
from circcal.validators.reference_result import ReferenceResult
from circcal.validators.scenario_observations import Observations
from circcal.validators.user_calibrator import FunctionCalibrator, load_calibrator
from circcal.validators.user_case import declared_model, restricted_solve, run_user_case, unrepresentable

# kornia's import triggers torch's own deprecation notice for torch.jit.script: not ours to fix
pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:DeprecationWarning")

REPO = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent


# The matrix: the installed suite's own test (python -m pytest --pyargs circcal.conformance), collected here as well
test_conformance = _installed.test_conformance


# --------------------------------------------------------------------------------------------------------------------
# The matrix itself
# --------------------------------------------------------------------------------------------------------------------


def test_matrix_covers_every_scenario_variant_with_readable_ids():
    from circcal.fixtures.scenarios import SCENARIOS

    refs = [("opencv", ("fair",)), ("mrcal", ("fair", "default")), ("kornia", ("fair",))]
    cs = cases(refs)
    ids = [c.id for c in cs]
    assert len(ids) == len(set(ids))
    for name, sc in SCENARIOS.items():
        for v in sc.variants:
            assert f"{name}-{v}-circcal" in ids
            if name in CIRCCAL_UNSUPPORTED:
                assert not any(i.startswith(f"{name}-{v}-") and not i.endswith("-circcal") for i in ids)
            else:
                for i in ("opencv", "mrcal_fair", "mrcal_default", "kornia"):
                    assert f"{name}-{v}-{i}" in ids
    fast = sorted(c.id for c in cs if not c.slow)
    assert fast == sorted(
        [
            f"{s}-{v}-{r}"
            for s, v in (("paper", "normal"), ("wide", "clean"))
            for r in ("circcal", "opencv", "mrcal_fair", "mrcal_default", "kornia")
        ]
        + [
            f"{s}-clean-{r}"
            for s in ("fisheye", "rational-wide")
            for r in ("circcal", "opencv", "mrcal_fair", "mrcal_default")
        ]
    )
    # scenario-variant major, circcal first: the expensive calibration is reused by the cases right after it
    assert ids.index("paper-uneven-circcal") < ids.index("paper-uneven-opencv") < ids.index("paper-strong-circcal")


def test_the_lens_model_is_a_dimension_of_the_matrix():
    refs = [("mrcal", ("fair", "default")), ("pycolmap", ("fair",))]
    cs = cases(refs, scenarios=["wide", "fisheye", "rational-wide"])
    ids = [c.id for c in cs]
    assert len(ids) == len(set(ids))
    by_id = {c.id: c for c in cs}
    # each scenario fits its own lens (ids unchanged), rational-wide also thin prism (named in the id)
    assert by_id["wide-clean-mrcal_fair"].lens == "opencv5"
    assert by_id["fisheye-clean-pycolmap"].lens == "fisheye"
    assert by_id["rational-wide-perturbed-circcal"].lens == "rational"
    assert by_id["rational-wide-clean-thin-prism-pycolmap"].lens == "thin-prism"
    assert not any(c.lens == "thin-prism" and not c.slow for c in cs)  # extra lenses are outside the fast slice


def test_a_lens_a_reference_does_not_fit_is_reported_unsupported():
    from circcal.validators.registry import get_for_lens

    obj, img, size, cam = _problem(n_views=4)
    obs = Observations(
        "wide",
        "clean",
        "",
        cam,
        Board(7, 7, 15.0, 7.0),
        [],
        "thin-prism",
        object_points=obj,
        image_points=img,
        solver_camera=cam,
    )
    # a built-in is set up for the lens and answers for itself, with its reason
    cal = get_for_lens("pycolmap", "thin-prism")
    skip_unless_available(cal)
    out = run_reference_case(Case("wide", "clean", "pycolmap", lens_model="thin-prism"), obs, cal)
    assert out.status == "unsupported" and out.result.status == "unsupported" and "s1-s4" in out.result.message
    assert out.checks and not failed_checks(out)

    # a plug-in that declares no such model is not called: its case reports why
    class Plain:
        name, version = "plain", "1"

        def available(self):
            return True, ""

        def calibrate_observations(self, *args, **kwargs):
            raise AssertionError("called for a lens it does not declare")

    out = run_reference_case(Case("wide", "clean", "plain", lens_model="thin-prism"), obs, Plain())
    assert out.status == "unsupported" and out.result is None and "opencv5" in out.checks[0].note
    assert not failed_checks(out)


def test_user_calibrators_replace_circcal_and_the_references():
    cs = cases(user=[("mine", ("fair",))])
    assert {c.reference for c in cs} == {"mine"} and all(c.user for c in cs)
    assert "paper-normal-mine" in [c.id for c in cs if not c.slow]


def test_observations_are_computed_once_across_workers(tmp_path, monkeypatch):
    calls = []

    def fake(scenario, variant, lens):
        calls.append((scenario, variant, lens))
        return {"scenario": scenario, "variant": variant, "lens": lens}

    monkeypatch.setattr(scenario_observations, "observe", fake)
    a, b = ObservationCache(tmp_path), ObservationCache(tmp_path)  # two workers sharing the run's folder
    assert a("wide", "clean") == b("wide", "clean") == a("wide", "clean", "opencv5")
    assert b("wide", "jpeg")["variant"] == "jpeg"
    assert b("rational-wide", "clean")["lens"] == "rational"  # the scenario's own lens by default
    assert a("rational-wide", "clean", "thin-prism")["lens"] == "thin-prism"
    assert calls == [
        ("wide", "clean", "opencv5"),
        ("wide", "jpeg", "opencv5"),
        ("rational-wide", "clean", "rational"),
        ("rational-wide", "clean", "thin-prism"),
    ]


# --------------------------------------------------------------------------------------------------------------------
# The plug-in: loading a user's calibrator
# --------------------------------------------------------------------------------------------------------------------


def _problem(n_views: int = 8, seed: int = 0) -> tuple[list, list, tuple[int, int], Camera]:
    cam = Camera(1280, 960, 1000.0, 1001.0, 641.0, 479.0, [-0.2, 0.05, 0.0, 0.0, 0.0])
    board = Board(7, 7, 15.0, 7.0)
    P = board.object_points()
    rng = np.random.default_rng(seed)
    obj, img = [], []
    for _ in range(n_views):
        r = np.array([*np.deg2rad(rng.uniform(-35, 35, 2)), rng.uniform(-0.3, 0.3)])
        t = (
            np.array([rng.uniform(-40, 40), rng.uniform(-30, 30), rng.uniform(250, 350)])
            - rodrigues(r) @ board.centre_mm()
        )
        obj.append(P.astype(np.float32).astype(np.float64))
        img.append((project(P, r, t, cam) + rng.normal(0, 0.02, (len(P), 2))).astype(np.float32).astype(np.float64))
    return obj, img, (cam.width, cam.height), cam


def test_load_calibrator_accepts_a_function_a_file_and_a_class():
    f = load_calibrator("tests.conformance.example_calibrator:opencv_calibrate")
    assert isinstance(f, FunctionCalibrator) and f.name == "opencv_calibrate"
    g = load_calibrator(f"mine={HERE / 'example_calibrator.py'}:opencv_biased")
    assert isinstance(g, FunctionCalibrator) and g.label == "mine"
    c = load_calibrator("circcal.validators.opencv:OpenCVCalibrator")
    assert c.name == "opencv" and hasattr(c, "calibrate_observations")
    obj, img, size, truth = _problem()
    res = f.calibrate_observations(obj, img, size)
    assert res.ok, res.message
    assert abs(res.camera.fx - truth.fx) < 5 * res.std["fx"]
    assert res.extra["poses"].startswith("cv2.solvePnP")
    assert 0.01 < res.errors["rms_per_coord_px"] < 0.03  # noise 0.02 px per coordinate, poses solved by PnP
    biased = g.calibrate_observations(obj, img, size)
    assert biased.ok and biased.camera.fx == pytest.approx(res.camera.fx * 1.0001, rel=1e-9)


@pytest.mark.parametrize(
    "spec, words",
    [
        ("no_colon_here", "expected [LABEL=]package.module:function"),
        ("circcal.validators.no_such_module:fn", "cannot import 'circcal.validators.no_such_module'"),
        ("circcal.validators.base:no_such_attr", "has no attribute 'no_such_attr'"),
        ("circcal.validators.base:MODES", "not a function or a ReferenceCalibrator"),
        ("missing/file.py:fn", "no such file"),
    ],
)
def test_load_calibrator_says_what_is_wrong(spec, words):
    with pytest.raises(ValueError, match=re.escape(words)):
        load_calibrator(spec)


@pytest.mark.parametrize(
    "returned, words",
    [
        ("text", "returned str; expected a ReferenceResult"),
        (("not a camera", None), "returned str as the camera"),
        ("raise", "ZeroDivisionError"),
    ],
)
def test_a_bad_user_function_becomes_a_failed_result(returned, words):
    def fn(obj, img, size):
        if returned == "raise":
            return 1 / 0
        return returned

    res = FunctionCalibrator(fn, "bad").calibrate_observations(*_problem(4)[:3])
    assert res.status == "failed" and words in res.message


def test_a_user_function_may_return_a_reference_result_or_refuse():
    def refuse(obj, img, size):
        raise NotImplementedError("only fisheye lenses")

    def result(obj, img, size):
        return ReferenceResult("mine", "1", "fair", "unsupported", "only asymmetric grids")

    args = _problem(4)[:3]
    assert FunctionCalibrator(refuse).calibrate_observations(*args).status == "unsupported"
    assert FunctionCalibrator(result).calibrate_observations(*args).message == "only asymmetric grids"


def test_option_selects_the_calibrator_under_test():
    """A pytest run with --calibrator tests exactly the given calibrators: the honest OpenCV wrapper passes, the one
    biased by 1e-4 in focal length fails the agreement check, and neither circcal nor a built-in reference runs."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_XDIST") and k != "PYTEST_ADDOPTS"}
    cmd = [
        sys.executable,
        "-m",
        "pytest",
        "tests/conformance/test_conformance.py::test_conformance",
        "-v",
        "-rA",
        "-p",
        "no:cacheprovider",
        "-k",
        "wide-clean",
        "--calibrator",
        "tests/conformance/example_calibrator.py:opencv_calibrate",
        "--calibrator",
        "biased=tests.conformance.example_calibrator:opencv_biased",
    ]
    out = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    text = out.stdout + out.stderr
    assert out.returncode == 1, text[-3000:]
    assert re.search(r"test_conformance\[wide-clean-opencv_calibrate\] PASSED", text), text[-3000:]
    assert re.search(r"test_conformance\[wide-clean-biased\] FAILED", text), text[-3000:]
    assert "1 failed, 1 passed" in text, text[-3000:]
    assert "circcal conformance: calibrator(s) under test: opencv_calibrate (FunctionCalibrator), biased" in text
    assert re.search(
        r"FAIL biased unknown \[opencv5\] vs circcal's solve \(opencv5\) on identical observations: max px: "
        r"0\.0\d+ \(bound 1e-06\) - f[xy] differs by \+0\.\d+ px \(\+1\d\.\d+ sigma\) from circcal's solve",
        text,
    ), text[-3000:]
    assert "-circcal" not in text.split("short test summary info")[-1]


def test_bad_calibrator_option_is_a_usage_error():
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_XDIST") and k != "PYTEST_ADDOPTS"}
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "tests/conformance",
            "--collect-only",
            "-q",
            "-p",
            "no:cacheprovider",
            "--calibrator",
            "circcal.validators.base:nothing",
        ],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 4 and "has no attribute 'nothing'" in out.stdout + out.stderr


def test_predicted_truth_rms_scales_with_the_stated_sigmas():
    cam = Camera(1280, 960, 1000.0, 1000.0, 640.0, 480.0, [-0.2, 0.05, 0.0, 0.0, 0.0])
    std = {"fx": 0.1, "fy": 0.1, "cx": 0.1, "cy": 0.1, "k1": 1e-4, "k2": 1e-4, "p1": 1e-6, "p2": 1e-6, "k3": 0.0}
    one = predicted_truth_rms(cam, std, None, n=50)
    two = predicted_truth_rms(cam, {k: 2 * v for k, v in std.items()}, None, n=50)
    assert 0 < one["p50"] < one["p99"] < 1.0
    assert two["p99"] == pytest.approx(2 * one["p99"], rel=1e-3)  # same draws, linear regime


# --------------------------------------------------------------------------------------------------------------------
# Calibrators under test: declared models, verdicts that name the parameter, no vacuous pass
# --------------------------------------------------------------------------------------------------------------------


def test_a_calibrator_declares_its_model_and_a_bad_declaration_is_named():
    def fn(obj, img, size):
        raise AssertionError("not called")

    fn.lens, fn.fixes = "rational", ("k3", "tangential")
    assert declared_model(FunctionCalibrator(fn)) == ("rational", ("p1", "p2", "k3"))
    assert declared_model(FunctionCalibrator(lambda o, i, s: None)) == ("opencv5", ())
    for lens, fixes, words in [
        ("opencv5", ("k4",), "k4"),
        ("opencv5", ("fx",), "fx cannot be held"),
        ("opencv5", "k3", "expected a tuple"),
        ("pinhole9", (), "pinhole9"),
    ]:
        fn.lens, fn.fixes = lens, fixes
        with pytest.raises(ValueError, match=re.escape(words)):
            declared_model(FunctionCalibrator(fn))


def test_a_truth_the_declared_model_cannot_represent_is_named():
    wide = Camera(1280, 960, 1000.0, 998.0, 641.5, 478.3, [-0.3, 0.1, 0.0006, -0.0004, -0.01])
    assert unrepresentable(wide, "opencv5", ()) == ""
    assert unrepresentable(wide, "rational", ()) == ""  # k4-k6 = 0 in the truth
    assert "the true k3 is -0.01" in unrepresentable(wide, "opencv5", ("k3",))
    assert "the true cx is 641.5; the calibrator holds it at 639.5" in unrepresentable(
        wide, "opencv5", ("principal_point",)
    )
    assert "fx / fy" in unrepresentable(wide, "opencv5", ("aspect_ratio",))
    assert "fisheye" in unrepresentable(wide, "fisheye", ())
    rational = Camera(1280, 960, 660.0, 660.0, 640.0, 480.0, [-0.3, 0.1, 0, 0, 0, 0.5, 0, 0], lens="rational")
    assert "k4 = 0.5" in unrepresentable(rational, "opencv5", ())


def test_circcal_solves_under_the_same_holds():
    obj, img, size, cam = _problem(n_views=8)
    obs = Observations(
        "wide", "clean", "", cam, Board(7, 7, 15.0, 7.0), [], "opencv5", object_points=obj, image_points=img
    )
    from circcal.solver import calibrate

    obs.solver_camera = calibrate(obj, img, size).camera
    held, std, _ = restricted_solve(obs, "opencv5", ("k3", "principal_point"))
    assert held.dist[4] == 0.0 and (held.cx, held.cy) == ((size[0] - 1) / 2, (size[1] - 1) / 2)
    assert std["k3"] == 0.0 and std["fx"] > 0
    wider, _, _ = restricted_solve(obs, "rational", ())
    assert wider.lens == "rational"


def _records(label, cx_offsets_px, sigma=0.34, shared=0.0):
    """Records of a calibrator whose cx differs from circcal's solve by the offsets, circcal's solve off the truth by
    ``shared`` (the observations' own bias) plus noise; fx, fy, cy exact."""
    rng = np.random.default_rng(1)
    out = []
    for off in cx_offsets_px:
        circ = shared + rng.normal(0, sigma)
        row = {"value": 0.0, "sigma": sigma, "vs_circcal": off, "vs_circcal_sigmas": off / sigma}
        row |= {"vs_truth": circ + off, "vs_truth_sigmas": (circ + off) / sigma}
        zero = {"value": 0.0, "sigma": 1.0, "vs_circcal": 0.0, "vs_circcal_sigmas": 0.0}
        zero |= {"vs_truth": 0.0, "vs_truth_sigmas": 0.0}
        out.append({"label": label, "status": "checked", "params": {"cx": row, "fx": zero, "fy": zero, "cy": zero}})
    return out


def test_a_consistent_offset_is_named_across_cases_where_each_case_alone_is_within_its_sigmas():
    from circcal.validators.bounds import BIAS_T

    recs = _records("shifted", [0.5] * 12) + _records("honest", [0.0] * 12, shared=0.3)
    recs.append({"label": "shifted", "status": "unsupported", "params": {}})  # not counted
    by = {(b.label, b.param): b for b in bias_tests(recs, BIAS_T)}
    cx = by[("shifted", "cx")]
    assert cx.n == 12 and cx.biased and cx.vs_circcal == pytest.approx(0.5)
    assert cx.excess_t == pytest.approx(0.5 / 0.34 * np.sqrt(12))  # SD 0 < 1: the honest-sigma SE, 1/sqrt(n)
    assert cx.words().startswith("cx biased by +0.5 px from circcal's solve")
    # the observations' own bias shows against the truth in circcal's solve too: not held against the calibrator
    honest = by[("honest", "cx")]
    assert abs(honest.t) > BIAS_T and honest.circcal_t == honest.t and not honest.biased
    one = bias_tests(_records("once", [0.5]), BIAS_T)
    assert not [b for b in one if b.biased]  # one case at 1.5 sigma is no evidence of a bias


def test_an_unavailable_or_raising_calibrator_is_not_a_pass():
    obj, img, size, cam = _problem(n_views=4)
    obs = Observations(
        "paper", "normal", "", cam, Board(7, 7, 15.0, 7.0), [], "opencv5", object_points=obj, image_points=img
    )
    obs.solver_camera = cam
    case = Case("paper", "normal", "mine", user=True)

    class Missing(FunctionCalibrator):
        def available(self):
            return False, "libfoo not installed"

    out = run_user_case(case, obs, Missing(lambda o, i, s: None, "mine"))
    assert out.status == "unavailable" and "libfoo not installed" in failed_checks(out)[0].note
    out = run_user_case(case, obs, Missing(lambda o, i, s: None, "mine"), allow_unavailable=True)
    assert out.skip_reason and not out.checks

    def raises(o, i, s):
        raise ValueError("singular matrix")

    out = run_user_case(case, obs, FunctionCalibrator(raises, "mine"))
    (bad,) = failed_checks(out)
    assert out.status == "failed" and "Traceback" in bad.note and 'raise ValueError("singular matrix")' in bad.note

    def refuses(o, i, s):
        raise NotImplementedError("asymmetric grids only")

    out = run_user_case(case, obs, FunctionCalibrator(refuses, "mine"))
    assert out.status == "unsupported" and "asymmetric grids only" in out.skip_reason
