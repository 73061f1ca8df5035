"""The whole pipeline (detect -> calibrate -> re-correct) against ground truth and against OpenCV's pipeline."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from circcal.analysis.compare import match_views
from circcal.board import Board
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.truth import load_truth
from circcal.pipeline import calibrate_images
from circcal.solver import CalibrationOptions, calibrate, holdout_errors
from circcal.validators.opencv import OpenCVCalibrator


@pytest.fixture(scope="module", params=["normal", "uneven", "strong", "weak"])
def paper(request):
    truth = load_truth(fixture_dir("paper", request.param))
    cal = calibrate_images([v.image for v in truth.views], truth.board, progress=False)
    return request.param, truth, cal


def test_paper_reprojection_and_intrinsics(paper):
    """Mean 2-D reprojection error <= 0.05 px (the paper reports 0.10-0.12) with no image left out, and
    fx, fy, cx, cy within 2 of their own stated sigmas of the truth.

    Not asserted here: the issue's 0.02 px RMS projection difference to the true camera over the whole image. At
    fx 4900 the focal length is weakly observable (std(fx) 0.29 px even from exact centres with 0.003 px noise,
    which alone moves the image edge by ~0.05 px) and k3 extrapolates into never-observed corners; measured
    (rotation fitted): normal 0.028, uneven 0.046, strong 0.021, weak 0.206 px, all consistent with the stated
    sigmas checked below. The conformance suite reports it per scenario.
    """
    variant, truth, cal = paper
    assert not cal.failed and len(cal.used) == len(truth.views)
    assert cal.result.errors["mean_2d_px"] <= 0.05
    for k in ("fx", "fy", "cx", "cy"):
        err = getattr(cal.result.camera, k) - getattr(truth.camera, k)
        assert abs(err) <= 2.0 * cal.result.std[k], f"{variant}: {k} off by {err:+.4f} (sigma {cal.result.std[k]:.4f})"
    assert cal.rounds[-1]["max_centre_shift_px"] < 1e-4 and len(cal.rounds) <= 4


def test_paper_projection_difference_is_at_its_cramer_rao_level(paper):
    """The issue's 0.02 px bar on the projection difference to the true camera is below what these views determine:
    circcal's stated covariance (sigma^2 (J^T J)^-1, the Cramer-Rao bound for its centre noise, shown honest by the
    Monte-Carlo study) predicts a median of 0.023 px in normal light and 0.15 px in weak light for any unbiased
    calibrator. What can be asserted is that circcal's actual difference lies inside that predicted distribution
    (<= its 99th percentile), i.e. no bias on top of the noise. Measured (rotation fitted, whole image): normal
    0.028, uneven 0.046, strong 0.021, weak 0.20 px; predicted medians 0.023, 0.052, 0.071, 0.145 px."""
    from circcal.analysis.compare import projection_diff
    from circcal.validators.case_run import predicted_truth_rms

    variant, truth, cal = paper
    res = cal.result
    measured = projection_diff(truth.camera, res.camera, fit=True)["rms_px"]
    pred = predicted_truth_rms(res.camera, res.std, res.correlation, n=200)
    print(
        f"\n{variant}: projection difference to the truth {measured:.4f} px; predicted by the stated covariance: "
        f"median {pred['p50']:.4f}, p95 {pred['p95']:.4f}, p99 {pred['p99']:.4f} px"
    )
    assert measured <= pred["p99"]


def test_bias_removal_visible_in_calibration():
    """tilted-large-dots: circcal's fx and cx errors vs truth >= 5x smaller than OpenCV's findCirclesGrid +
    calibrateCamera on the same images (measured: fx 0.002 vs 0.59 px, cx 0.003 vs 0.075 px)."""
    truth = load_truth(fixture_dir("tilted-large-dots", "clean"))
    paths = [v.image for v in truth.views]
    cal = calibrate_images(paths, truth.board, progress=False)
    ref = OpenCVCalibrator().calibrate_images(paths, truth.board, (truth.camera.width, truth.camera.height))
    assert ref.ok and len(ref.views) == len(paths), ref.message
    for k in ("fx", "cx"):
        ours = abs(getattr(cal.result.camera, k) - getattr(truth.camera, k))
        theirs = abs(getattr(ref.camera, k) - getattr(truth.camera, k))
        print(f"\n{k}: circcal error {ours:.4f} px, OpenCV pipeline {theirs:.4f} px")
        assert 5.0 * ours <= theirs


REAL = {
    "boofcv_sony_hx5v_circle_asym_4x5": Board(5, 4, 30.0, 20.0, "asymmetric"),
    "boofcv_sony_hx5v_circle_regular_10x8": Board(8, 10, 25.0, 15.0),
}


def _rms(stats: list[dict]) -> float:
    return float(np.sqrt(np.mean([h["rms_per_point_px"] ** 2 for h in stats])))


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_photographs(realdata, name):
    """Real photographs, rigid board: every grid found; RMS and held-out-view prediction next to OpenCV's.

    Measured: RMS per point 0.1849 vs OpenCV's 0.183 (asym), 0.4764 vs 0.4755 (regular); held-out prediction
    0.2029 vs 0.2017 and 0.5097 vs 0.5103. With a rigid board the residual on these sets is the board's shape
    (a printed sheet on a clipboard; see test_real_photographs_board_refined), so circcal ties OpenCV here; the
    bound pins that tie (2 %) so a regression in either shows.
    """
    board = REAL[name]
    folder = realdata / name
    paths = sorted(folder.glob("*.jpg"))
    baseline = json.loads((folder / "opencv_baseline.json").read_text())
    cal = calibrate_images(paths, board, progress=False)
    assert not cal.failed and len(cal.used) == len(paths) == baseline["used_for_calibration"]
    rms = cal.result.errors["rms_per_point_px"]
    obj, img = cal.observations(board)
    ours = holdout_errors(obj, img, (cal.result.camera.width, cal.result.camera.height))
    det = OpenCVCalibrator().detect(paths, board)
    theirs = holdout_errors([board.object_points()] * len(det["image_points"]), det["image_points"], det["image_size"])
    h_ours, h_theirs = _rms(ours), _rms(theirs)
    print(
        f"\n{name}: RMS per point {rms:.4f} px (OpenCV baseline {baseline['rms_px']:.4f}); held-out "
        f"{h_ours:.4f} px (OpenCV {h_theirs:.4f})"
    )
    assert rms <= 1.02 * baseline["rms_px"]
    assert h_ours <= 1.02 * h_theirs


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_photographs_board_refined(realdata, name):
    """Real photographs with the board's shape estimated (``refine_board``): beats OpenCV's baseline RMS (rigid
    board, SOURCE.txt) several times over, and the gain is real: held-out views are predicted 1.5-5x better than
    with the rigid model (a shape fitted to noise would predict them worse).

    Measured: RMS per point 0.0709 px (baseline 0.183, asym) and 0.0589 px (baseline 0.4755, regular); held-out
    0.1316 vs rigid 0.2029, 0.1080 vs 0.5097. The same solver on OpenCV's centres, put in circcal's point order,
    gives 0.0711 / 0.0590 px and held-out 0.1309 / 0.1083: on these 640x480 JPEGs the two detectors' centres tie once the board is modelled
    (asserted within 3 %). In the order our OpenCV adapter returns they do not (0.227 px): findCirclesGrid numbers
    the 10x8 grid in opposite directions in its plain and clustering modes, and the adapter falls back to clustering
    in the 2 views the plain mode misses. The
    sheets deviate from the nominal board by up to 0.29 mm (asym) and 1.29 mm (regular), 15x and 28x their median
    sigma (0.020, 0.046 mm).
    """
    board = REAL[name]
    folder = realdata / name
    paths = sorted(folder.glob("*.jpg"))
    baseline = json.loads((folder / "opencv_baseline.json").read_text())
    rigid = calibrate_images(paths, board, progress=False)
    cal = calibrate_images(paths, board, CalibrationOptions(refine_board=True), progress=False)
    assert not cal.failed and len(cal.used) == len(paths)
    rms = cal.result.errors["rms_per_point_px"]
    obj, img = cal.observations(board)
    size = (cal.result.camera.width, cal.result.camera.height)
    h_refined = _rms(holdout_errors(obj, img, size, CalibrationOptions(refine_board=True)))
    h_rigid = _rms(holdout_errors(*rigid.observations(board), size))
    # OpenCV's centres in circcal's point order (the adapter's plain and clustering findCirclesGrid runs number the
    # symmetric grid in opposite directions)
    theirs_img, _ = match_views(OpenCVCalibrator().detect(paths, board)["image_points"], cal.centres, board)
    theirs_obj = [board.object_points()] * len(theirs_img)
    theirs = calibrate(theirs_obj, theirs_img, size, CalibrationOptions(refine_board=True))
    h_theirs = _rms(holdout_errors(theirs_obj, theirs_img, size, CalibrationOptions(refine_board=True)))
    dev = np.abs(cal.result.board_points - cal.result.board_nominal)
    print(
        f"\n{name}: board refined: RMS per point {rms:.4f} px (OpenCV baseline, rigid: {baseline['rms_px']:.4f}; "
        f"OpenCV centres, refined: {theirs.errors['rms_per_point_px']:.4f}); held-out {h_refined:.4f} px (rigid "
        f"{h_rigid:.4f}, OpenCV centres refined {h_theirs:.4f}); board deviates up to {dev.max():.2f} mm "
        f"(median sigma {np.median(cal.result.board_std[cal.result.board_std > 0]):.3f} mm)"
    )
    assert rms <= 0.5 * baseline["rms_px"]
    assert h_refined <= 0.7 * h_rigid
    assert rms <= 1.03 * theirs.errors["rms_per_point_px"] and h_refined <= 1.03 * h_theirs
    std = cal.result.board_std
    assert 5.0 * np.median(std[std > 0]) <= dev.max() <= 3.0  # a significant deformation, of printed-sheet size


def test_duplicate_images_are_counted_once(tmp_path):
    """The same image given twice, or a copy under another name, would shrink the stated sigmas without adding
    information: it is reported (reason code "duplicate", naming the first) and the model is the one of the unique
    images."""
    from circcal.detector import Reason

    truth = load_truth(fixture_dir("small-noisy"))
    paths = [str(v.image) for v in truth.views]
    copy = tmp_path / "copy_of_first.png"
    shutil.copy(paths[0], copy)
    cal = calibrate_images(paths + [paths[1], str(copy)], truth.board, progress=False, image_size=(640, 480))
    once = calibrate_images(paths, truth.board, progress=False, image_size=(640, 480))
    assert len(cal.used) == len(paths)
    assert [(r.path, r.code) for r in cal.failed] == [(paths[1], Reason.DUPLICATE), (str(copy), Reason.DUPLICATE)]
    assert "same file as" in cal.failed[0].reason and paths[1] in cal.failed[0].reason
    assert "identical content to" in cal.failed[1].reason and paths[0] in cal.failed[1].reason
    np.testing.assert_array_equal(cal.result.camera.intrinsics, once.result.camera.intrinsics)
    assert cal.result.std == once.result.std


def test_duplicates_of_tells_same_files_and_same_bytes(tmp_path):
    """The same path twice, a byte copy, a same-size file with other bytes, another size and a missing file: only
    the second path and the copy are duplicates, each of its earliest twin."""
    from circcal.pipeline import duplicates_of

    a, copy, same_size, other, missing = (tmp_path / n for n in ("a", "copy", "same", "other", "missing"))
    a.write_bytes(b"x" * 1000)
    copy.write_bytes(b"x" * 1000)
    same_size.write_bytes(b"y" * 1000)
    other.write_bytes(b"x" * 999)
    paths = [str(p) for p in (a, same_size, a, other, copy, missing)]
    assert duplicates_of(paths) == {2: (0, "same file as"), 4: (0, "identical content to")}


def test_a_photograph_given_twice_re_saved_is_one_view(tmp_path):
    # found by an outside test: a JPEG re-save of one real photograph (not byte-identical) was a view of its own;
    # it shrank the stated sigmas and put one copy in each cross-validation half (the verdict flipped)
    import cv2

    from circcal.detector import Reason

    t = load_truth(fixture_dir("paper", "normal"))
    paths = [shutil.copy(v.image, tmp_path) for v in t.views]
    once = calibrate_images(paths, t.board, progress=False)
    copy = str(tmp_path / "copy.jpg")
    cv2.imwrite(copy, cv2.imread(paths[2], cv2.IMREAD_UNCHANGED), [cv2.IMWRITE_JPEG_QUALITY, 90])
    twice = calibrate_images([*paths, copy], t.board, progress=False)
    assert [r.code for r in twice.failed if r.path == copy] == [Reason.DUPLICATE]
    assert "the same view as" in next(r.reason for r in twice.failed if r.path == copy)
    assert np.array_equal(twice.result.camera.intrinsics, once.result.camera.intrinsics)
