"""Cross-validation of a user's own views (circcal.analysis): both directions, on rendered fixtures where the truth
is known. A correct pipeline is "consistent" on every paper and wide variant whose centres are unbiased; a wrong
lens model (k1 only on `wide`), a biased pipeline (OpenCV's blob centres on `tilted-large-dots`) and biased centres
(circcal's own under `wide`'s uneven light) are flagged, and for every flag the ground truth confirms a real problem:
a half model, or the whole model, is off from the true camera by more than twice its own stated uncertainty over
most of the image. Fewer than 6 views: it says why and the calibration stands."""

from __future__ import annotations

import numpy as np
import pytest

from circcal.analysis import cross_validate_detections, cross_validate_observations, model_diff
from circcal.analysis.cross import MIN_VIEWS, split_views
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.scenarios import SCENARIOS
from circcal.fixtures.truth import load_truth
from circcal.pipeline import calibrate_images
from circcal.solver import CalibrationOptions
from circcal.solver.outliers import OutlierRule
from circcal.solver.uncertainty import result_projection_stdev

#: The ground truth confirms a flag when some model's difference to the true camera is within 2x of its own
#: uncertainty over less than this share of the image (a right model is, over ~all of it).
TRUTH_CONFIRMS_SHARE = 0.5
#: circcal's own centres under `wide`'s uneven illumination carry a bias (0.0145 px per coordinate against the
#: truth, twice the residual's 0.008 px): the cross-validation finds it, the truth confirms it.
BIASED_CENTRES = {("wide", "uneven")}


def _truth_share(truth_camera, res) -> float:
    """Share of the image where ``res``'s model is within 2x its own uncertainty of the true camera."""
    d = model_diff(
        truth_camera,
        res.camera,
        uncertainty_a=lambda uv: np.zeros(len(uv)),
        uncertainty_b=lambda uv: result_projection_stdev(res, uv),
    )
    return d.share_within


def _circcal(scenario: str, variant: str):
    t = load_truth(fixture_dir(scenario, variant))
    options = CalibrationOptions(outlier_rule=OutlierRule())
    cal = calibrate_images([v.image for v in t.views], t.board, options, progress=False)
    return t, cal.result, cross_validate_detections(cal, t.board, options)


def _k1_only(scenario: str, variant: str):
    t = load_truth(fixture_dir(scenario, variant))
    cal = calibrate_images([v.image for v in t.views], t.board, progress=False)
    obj, img = cal.observations(t.board)
    full, cv = cross_validate_observations(
        obj, img, (t.camera.width, t.camera.height), CalibrationOptions(fixed=("k2", "k3", "tangential"))
    )
    return t, full, cv


def _opencv(scenario: str, variant: str):
    from circcal.validators.opencv import OpenCVCalibrator

    t = load_truth(fixture_dir(scenario, variant))
    det = OpenCVCalibrator().detect([v.image for v in t.views], t.board)
    img = det["image_points"]
    full, cv = cross_validate_observations([t.board.object_points()] * len(img), img, (t.camera.width, t.camera.height))
    return t, full, cv


def _check(t, full, cv, *, expect_problem: bool, label: str) -> None:
    assert cv.status == "ok", cv.message
    shares = [_truth_share(t.camera, m) for m in (*cv.models, full)]
    print(
        f"\n{label}: {cv.message}\n  flagged views: {[(v.name, v.why) for v in cv.flagged_views]}\n  truth: "
        f"half A / half B / whole model within 2x of their uncertainty over {np.round(shares, 2)} of the image"
    )
    if expect_problem:
        assert cv.verdict == "model-or-data-problem"
        assert min(shares) < TRUTH_CONFIRMS_SHARE  # the truth confirms it
        assert cv.message.startswith("a model or data problem")
    else:
        assert cv.verdict == "consistent", cv.message
        assert cv.flagged_views == []
        assert cv.diff.share_within >= 0.95


CORRECT = [(s, v) for s in ("paper", "wide") for v in SCENARIOS[s].variants]
FAST_CORRECT = [("paper", "normal"), ("wide", "clean")]


@pytest.mark.parametrize(
    "scenario,variant",
    FAST_CORRECT + [pytest.param(s, v, marks=pytest.mark.slow) for s, v in CORRECT if (s, v) not in FAST_CORRECT],
)
def test_correct_pipeline(scenario, variant):
    t, full, cv = _circcal(scenario, variant)
    _check(t, full, cv, expect_problem=(scenario, variant) in BIASED_CENTRES, label=f"circcal {scenario}-{variant}")


@pytest.mark.parametrize("variant", ["clean", pytest.param("noise", marks=pytest.mark.slow)])
def test_wrong_lens_model_is_flagged(variant):
    """k1 alone for `wide`'s lens (k1 -0.3, k2 0.1, k3 -0.01): the halves differ far beyond their uncertainty,
    everywhere but near the centre."""
    t, full, cv = _k1_only("wide", variant)
    _check(t, full, cv, expect_problem=True, label=f"k1 only, wide-{variant}")
    assert cv.diff.share_within < 0.5 and cv.diff.where


@pytest.mark.parametrize("variant", ["noise", pytest.param("clean", marks=pytest.mark.slow)])
def test_biased_pipeline_is_flagged(variant):
    """OpenCV's blob centroids on 45+ px dots tilted 40-55 degrees: the bias circcal removes."""
    t, full, cv = _opencv("tilted-large-dots", variant)
    _check(t, full, cv, expect_problem=True, label=f"OpenCV centres, tilted-large-dots-{variant}")


def test_fewer_than_six_views_says_why_and_the_calibration_stands(tmp_path):
    from circcal.cli import main

    t = load_truth(fixture_dir("wide", "clean"))
    out = tmp_path / "m.json"
    args = [
        "calibrate",
        *[str(v.image) for v in t.views[: MIN_VIEWS - 1]],
        "--grid",
        "6x8",
        "--pitch",
        "25mm",
        "--diameter",
        "12mm",
        "--no-progress",
        "--cross-validate",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    assert out.is_file()
    cal = calibrate_images([v.image for v in t.views[: MIN_VIEWS - 1]], t.board, progress=False)
    cv = cross_validate_detections(cal, t.board)
    assert cv.status == "too-few-views" and cv.verdict is None
    assert f"need at least {MIN_VIEWS}" in cv.message and "calibration above stands" in cv.message


def test_splits_are_disjoint_and_seeded():
    a, b = split_views(13)
    assert a == list(range(0, 13, 2)) and b == list(range(1, 13, 2))
    r1, r2 = split_views(13, "random", 3), split_views(13, "random", 3)
    assert r1 == r2 and not set(r1[0]) & set(r1[1]) and sorted(r1[0] + r1[1]) == list(range(13))
    assert split_views(13, "random", 4) != r1
    with pytest.raises(ValueError):
        split_views(13, "halves")


def test_the_checks_own_fits_speak_through_the_check():
    # halves held to 3 Jacobian evaluations stop short and warn; their words belong to the check (named by whose fit
    # it was), not to the console as if the user's calibration had not converged
    import warnings

    from circcal.board import Board
    from circcal.fixtures.poses import off_axis_observations
    from circcal.model import Camera
    from circcal.solver import calibrate

    cam = Camera(640, 480, 560.0, 561.0, 320.5, 240.5, [-0.1, 0.05, 0.0, 0.0, 0.0])
    obj, img = off_axis_observations(cam, Board(7, 9, 10.0, 4.0), 12, 3, 25.0)
    full = calibrate(obj, img, (640, 480))
    assert full.converged
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, cv = cross_validate_observations(obj, img, (640, 480), CalibrationOptions(max_iterations=3), full=full)
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)]
    whose = ("the half of 6 views (view 0, view 2", "the half of 6 views (view 1, view 3", "the fit without view ")
    assert cv.notes and all(n.startswith(whose) for n in cv.notes), cv.notes
    assert any("did not converge" in n for n in cv.notes)
    assert "notes" in cv.to_dict() and cv.to_dict()["notes"] == cv.notes


def test_the_halves_follow_the_views_names_not_the_order_given():
    # found by an outside test: the real asymmetric set gave "a model or data problem" (3.31 px) given in name order
    # and "consistent" (0.502 px) given shuffled, the model the same
    t = load_truth(fixture_dir("paper", "normal"))
    cal = calibrate_images([v.image for v in t.views], t.board, progress=False)
    obj, img = cal.observations(t.board)
    names = [f"image{i:02d}.png" for i in range(len(obj))]
    size = (t.camera.width, t.camera.height)
    _, a = cross_validate_observations(obj, img, size, names=names)
    perm = np.random.default_rng(3).permutation(len(obj))
    _, b = cross_validate_observations(
        [obj[i] for i in perm], [img[i] for i in perm], size, names=[names[i] for i in perm]
    )
    named = [sorted(names[i] for i in h) for h in a.halves]
    assert [sorted(names[perm[i]] for i in h) for h in b.halves] == named
    assert named[0][:2] == ["image00.png", "image02.png"]  # alternate in name order
    assert b.diff.rms_px == pytest.approx(a.diff.rms_px, rel=1e-6) and b.verdict == a.verdict
