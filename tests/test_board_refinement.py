"""Board refinement (the object-releasing method): against cv2.calibrateCameraRO, against a known warped board, and
its gauge, input and hold-out behaviour."""

import cv2
import numpy as np
import pytest

from circcal.board import Board
from circcal.fixtures.poses import sample_poses
from circcal.model import Camera, project
from circcal.solver import CalibrationOptions, calibrate, fit_pose, holdout_errors

BOARD = Board(8, 10, 25.0, 15.0)
CAM = Camera(1280, 960, 1000.0, 1002.0, 645.0, 478.0, np.array([-0.2, 0.08, 0.0005, -0.0003, -0.01]))
OPENCV_GAUGE = (0, BOARD.cols - 1, BOARD.rows * BOARD.cols - 1)  # first point, iFixedPoint = top right, last's z


def warped_board(bend_mm: float = 1.0, twist_mm: float = 0.3, scale_x: float = 1.002) -> np.ndarray:
    """(P, 3) mm: the nominal board bent (z = bend (1 - u^2)), twisted (z += twist u v) and printed 0.2 % too wide
    in x; u, v in [-1, 1] across the point grid. A clipboard-like board: 1 mm bend on a 225 x 175 mm grid."""
    bp = BOARD.object_points()
    lo, hi = bp.min(0), bp.max(0)
    u = (bp[:, 0] - 0.5 * (lo[0] + hi[0])) / (0.5 * (hi[0] - lo[0]))
    v = (bp[:, 1] - 0.5 * (lo[1] + hi[1])) / (0.5 * (hi[1] - lo[1]))
    out = bp.copy()
    out[:, 0] *= scale_x
    out[:, 2] = bend_mm * (1.0 - u * u) + twist_mm * u * v
    return out


def observations(truth_points: np.ndarray, n: int = 12, noise: float = 0.02, seed: int = 3):
    """Nominal object points and float32-rounded projections of ``truth_points`` (what cv2 takes) per view."""
    rng = np.random.default_rng(seed)
    img = [
        project(truth_points, r, t, CAM) + rng.normal(0.0, noise, (len(truth_points), 2))
        for r, t in sample_poses(CAM, BOARD, n, seed)
    ]
    img = [p.astype(np.float32).astype(np.float64) for p in img]
    return [BOARD.object_points()] * n, img


def similarity_residual(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P,) mm: |s R a + t - b| after the least-squares similarity (Umeyama) that maps ``a`` onto ``b``."""
    ma, mb = a.mean(0), b.mean(0)
    A, B = a - ma, b - mb
    U, S, Vt = np.linalg.svd(B.T @ A)
    d = np.sign(np.linalg.det(U @ Vt))
    R = U @ np.diag([1.0, 1.0, d]) @ Vt
    s = (S * [1.0, 1.0, d]).sum() / (A * A).sum()
    return np.linalg.norm(s * A @ R.T + mb - b, axis=1)


def test_equals_calibrate_camera_ro():
    """Same observations, same gauge (calibrateCameraRO holds the first point, iFixedPoint and the last point's z):
    the same minimum. Measured: parameters 1e-12 relative, board points 7e-6 mm (cv2 returns them as float32),
    RMS 1e-15 relative; cv2 takes ~20x longer."""
    obj, img = observations(warped_board())
    ours = calibrate(obj, img, (CAM.width, CAM.height), CalibrationOptions(refine_board=True, board_gauge=OPENCV_GAUGE))
    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        rms, K, d, _, _, new_obj = cv2.calibrateCameraRO(
            [o.astype(np.float32) for o in obj],
            [p.astype(np.float32).reshape(-1, 1, 2) for p in img],
            (CAM.width, CAM.height),
            OPENCV_GAUGE[1],
            None,
            None,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15),
        )
    finally:
        cv2.setNumThreads(n)
    theirs = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *np.ravel(d)[:5]])
    rel = np.abs(theirs - ours.camera.intrinsics) / np.abs(ours.camera.intrinsics)
    assert np.max(rel) <= 1e-8, rel
    assert np.max(np.abs(new_obj.reshape(-1, 3) - ours.board_points)) <= 1e-4  # float32 rounding of ~200 mm
    assert ours.errors["rms_per_point_px"] == pytest.approx(rms, rel=1e-9)
    assert ours.board_gauge == OPENCV_GAUGE
    held = ours.board_std == 0
    assert held[0].all() and held[OPENCV_GAUGE[1]].all() and held[OPENCV_GAUGE[2], 2] and held.sum() == 7


def test_recovers_a_warped_board():
    """A bent, twisted, mis-scaled board: the rigid model is biased by many sigmas; with the board refined the
    intrinsics are back within 3 of their stated sigmas and the board's shape is recovered (up to the similarity the
    gauge leaves free) to within 4 of its stated sigmas. Measured: rigid fx error +20 px (its sigma, inflated by the misfit, 1.3), refined
    -0.13 px (sigma 0.17)."""
    truth = warped_board()
    obj, img = observations(truth)
    rigid = calibrate(obj, img, (CAM.width, CAM.height))
    ro = calibrate(obj, img, (CAM.width, CAM.height), CalibrationOptions(refine_board=True))
    assert abs(rigid.camera.fx - CAM.fx) > 10 * rigid.std["fx"]
    for k in ("fx", "fy", "cx", "cy"):
        err = getattr(ro.camera, k) - getattr(CAM, k)
        assert abs(err) <= 3.0 * ro.std[k], f"{k} off by {err:+.4f} (sigma {ro.std[k]:.4f})"
    for j, k in enumerate(("k1", "k2", "p1", "p2", "k3")):
        assert abs(ro.camera.dist[j] - CAM.dist[j]) <= 3.0 * ro.std[k], k
    assert ro.errors["rms_per_coord_px"] == pytest.approx(0.02, rel=0.1)  # the noise level, nothing left over
    resid = similarity_residual(ro.board_points, truth)
    assert np.max(resid) <= 4.0 * np.max(ro.board_std)
    assert np.max(np.abs(ro.board_points[:, 2] - ro.board_nominal[:, 2])) > 0.5  # the bend was found


def test_flat_board_changes_nothing_beyond_noise():
    """On a truly flat board the refined points stay flat within their sigmas and the intrinsics move by less
    than their own sigma."""
    obj, img = observations(BOARD.object_points(), seed=5)
    rigid = calibrate(obj, img, (CAM.width, CAM.height))
    ro = calibrate(obj, img, (CAM.width, CAM.height), CalibrationOptions(refine_board=True))
    dev = np.abs(ro.board_points - ro.board_nominal)
    std = ro.board_std
    assert np.all(dev[std > 0] <= 5.0 * std[std > 0])
    for k in ("fx", "fy", "cx", "cy"):
        assert abs(getattr(ro.camera, k) - getattr(rigid.camera, k)) <= ro.std[k]


def test_gauge_choice_does_not_change_the_camera():
    """Any three non-collinear gauge points give the same intrinsics and residuals (only the board frame moves)."""
    obj, img = observations(warped_board(), n=8)
    a = calibrate(obj, img, (CAM.width, CAM.height), CalibrationOptions(refine_board=True))
    b = calibrate(obj, img, (CAM.width, CAM.height), CalibrationOptions(refine_board=True, board_gauge=(5, 40, 77)))
    assert np.allclose(a.camera.intrinsics, b.camera.intrinsics, rtol=1e-8, atol=1e-10)
    assert a.errors["rms_per_point_px"] == pytest.approx(b.errors["rms_per_point_px"], rel=1e-9)
    assert np.max(similarity_residual(a.board_points, b.board_points)) <= 1e-6


def test_bad_gauge_and_rarely_seen_points():
    obj, img = observations(warped_board(), n=6)
    with pytest.raises(ValueError, match="collinear"):
        calibrate(obj, img, (CAM.width, CAM.height), CalibrationOptions(refine_board=True, board_gauge=(0, 1, 2)))
    with pytest.raises(ValueError, match="distinct"):
        calibrate(obj, img, (CAM.width, CAM.height), CalibrationOptions(refine_board=True, board_gauge=(0, 0, 9)))
    # point 45 seen in only two views: held at its nominal position, with a warning naming it
    keep = [np.ones(len(o), bool) for o in obj]
    for v in range(2, 6):
        keep[v][45] = False
    obj2 = [o[k] for o, k in zip(obj, keep)]
    img2 = [p[k] for p, k in zip(img, keep)]
    with pytest.warns(RuntimeWarning, match=r"fewer than 3 views.*\[45\]"):
        res = calibrate(obj2, img2, (CAM.width, CAM.height), CalibrationOptions(refine_board=True))
    assert np.all(res.board_std[45] == 0) and np.allclose(res.board_points[45], BOARD.object_points()[45])


def test_holdout_uses_the_refined_board():
    """Leave-one-view-out prediction with the refined board shape: at the noise level, where the rigid model
    predicts held-out views ~10x worse."""
    obj, img = observations(warped_board(), n=8)
    rigid = holdout_errors(obj, img, (CAM.width, CAM.height))
    ro = holdout_errors(obj, img, (CAM.width, CAM.height), CalibrationOptions(refine_board=True))
    h_rigid = np.sqrt(np.mean([h["rms_per_coord_px"] ** 2 for h in rigid]))
    h_ro = np.sqrt(np.mean([h["rms_per_coord_px"] ** 2 for h in ro]))
    assert h_ro <= 0.03 < 5 * h_ro <= h_rigid


def test_fit_pose_on_a_non_planar_board():
    truth = warped_board(bend_mm=3.0)
    r, t = sample_poses(CAM, BOARD, 3, 1)[2]
    uv = project(truth, r, t, CAM)
    rv, tv = fit_pose(truth, uv, CAM)
    assert np.max(np.abs(project(truth, rv, tv, CAM) - uv)) <= 1e-8


def test_pose_start_is_exact_on_a_flat_board_and_fit_pose_refines_it():
    """pose_start (IPPE) on noise-free points of a flat board: exact through circcal's rays (the fisheye), within
    OpenCV's undistortion's own convergence for an OpenCV lens (its fixed iteration count: ~1e-3 px here); fit_pose
    then lands on the pose to rounding, on a flat board and on a bent one (the IPPE start sees it flattened)."""
    from circcal.model import Camera
    from circcal.solver import pose_start

    fisheye = Camera(640, 480, 260.0, 260.5, 322.0, 241.0, [0.02, -0.01, 0.004, -0.001], "fisheye")
    flat = BOARD.object_points()
    for cam, px in ((CAM, 2e-3), (fisheye, 1e-11)):
        for r, t in sample_poses(cam, BOARD, 3, 1):
            uv = project(flat, r, t, cam)
            assert np.max(np.abs(project(flat, *pose_start(flat, uv, cam), cam) - uv)) <= px, cam.lens
            rv, tv = fit_pose(flat, uv, cam)
            assert np.allclose(rv, r, rtol=0, atol=1e-12) and np.allclose(tv, t, rtol=0, atol=1e-9), cam.lens
    bent = warped_board(bend_mm=3.0)
    r, t = sample_poses(CAM, BOARD, 3, 1)[2]
    uv = project(bent, r, t, CAM)
    start = np.max(np.abs(project(bent, *pose_start(bent, uv, CAM), CAM) - uv))
    assert start > 0.05 and np.max(np.abs(project(bent, *fit_pose(bent, uv, CAM), CAM) - uv)) <= 1e-8


def test_model_json_carries_the_board():
    obj, img = observations(warped_board(), n=6)
    res = calibrate(obj, img, (CAM.width, CAM.height), CalibrationOptions(refine_board=True))
    m = res.to_model_json()["board_refinement"]
    assert np.allclose(m["points_mm"], res.board_points) and m["gauge"] == list(res.board_gauge)
    assert np.allclose(res.board_lookup(BOARD.object_points()[[3, 7]]), res.board_points[[3, 7]])
    with pytest.raises(ValueError, match="not part of"):
        res.board_lookup(np.array([[1.0, 2.0, 0.0]]))


def test_cli_refine_board_on_real_photographs(realdata, tmp_path, capsys):
    """`circcal calibrate --refine-board` on the real 10x8 set: the summary states the board's deviation, model.json
    carries the refined board, and the fit reaches the JPEG noise level (0.059 px RMS per point; 0.476 rigid)."""
    import json

    from circcal.cli import main

    images = sorted(str(p) for p in (realdata / "boofcv_sony_hx5v_circle_regular_10x8").glob("*.jpg"))
    out = tmp_path / "model.json"
    rc = main(
        [
            "calibrate",
            *images,
            "--grid",
            "8x10",
            "--pitch",
            "25mm",
            "--diameter",
            "15mm",
            "--refine-board",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    text = capsys.readouterr().out
    assert rc == 0 and "board shape (refined" in text
    model = json.loads(out.read_text())
    assert model["errors"]["rms_per_point_px"] <= 0.08
    pts, nominal = np.array(model["board_refinement"]["points_mm"]), np.array(model["board_refinement"]["nominal_mm"])
    assert pts.shape == (80, 3) and 0.5 <= np.abs(pts - nominal)[:, 2].max() <= 3.0
