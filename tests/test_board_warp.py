"""The board's shape decided with evidence (issue 34): mrcal's 2-parameter board warp in the solver, the board-shape
check every calibration runs (circcal.analysis.boardshape), the warped-board renders, and (``make study``) the
Monte-Carlo study of the recommended model's intrinsics against the truth."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from circcal import jsonio
from circcal.analysis.boardshape import FLAT_CHI2, board_shape, folds
from circcal.analysis.calibration import calibrate as calibrate_and_assess
from circcal.board import Board
from circcal.commands.args import calibration_options
from circcal.errors import InputError
from circcal.fixtures.poses import pose_looking_at, sample_poses
from circcal.fixtures.render import area_centroids, render_coverage, warped_points
from circcal.formats.modeljson import MODEL_SECTIONS
from circcal.model import Camera, project
from circcal.solver import CalibrationOptions, calibrate
from circcal.solver.problem import Problem, warp_basis, warp_box

BOARD = Board(8, 10, 25.0, 15.0)
CAM = Camera(1280, 960, 1000.0, 1002.0, 645.0, 478.0, np.array([-0.2, 0.08, 0.0005, -0.0003, -0.01]))
SIZE = (CAM.width, CAM.height)
WARP = (1.2, -0.7)  # mm: a board sagging 1.2 mm along x and bulging 0.7 mm along y (225 x 175 mm grid)
NOISE_PX = 0.05
INTRINSICS = ("fx", "fy", "cx", "cy")


def observations(warp, *, low_tilt: bool, seed: int, n: int = 12, pose_seed: int = 5):
    """Nominal object points and noisy projections of the board warped by ``warp`` (mm; None: flat), per view: at
    low tilt (5-15 deg, the refinement's trap) or well spread (10-50 deg)."""
    tilt = dict(min_tilt_deg=5.0, max_tilt_deg=15.0) if low_tilt else dict(min_tilt_deg=10.0, max_tilt_deg=50.0)
    truth = warped_points(BOARD, warp)
    rng = np.random.default_rng(seed)
    img = [
        project(truth, r, t, CAM) + rng.normal(0.0, NOISE_PX, (len(truth), 2))
        for r, t in sample_poses(CAM, BOARD, n, pose_seed, **tilt)
    ]
    return [BOARD.object_points()] * n, img


def within_sigmas(res, k: float = 3.0) -> dict[str, float]:
    """Each intrinsic's error against the truth, in the result's stated sigmas."""
    names = CAM.model.param_names
    return {
        n: abs(res.camera.intrinsics[names.index(n)] - CAM.intrinsics[names.index(n)]) / res.std[n] for n in INTRINSICS
    }


def test_the_warp_is_mrcals_calobject_warp():
    """mrcal.ref_calibration_object's form: zero on the box's edges, the parameter at its centre, a parabola between
    (z = 4 k xr (1 - xr)); the box is the points' bounding box (mrcal's lattice of the same points)."""
    pts = BOARD.object_points()
    box = warp_box([pts[:40], pts[40:]])
    assert box == (0.0, 225.0, 0.0, 175.0)
    B = warp_basis(np.array([[0.0, 0.0, 0.0], [112.5, 87.5, 0.0], [225.0, 43.75, 0.0], [56.25, 175.0, 0.0]]), box)
    assert np.allclose(B, [[0.0, 0.0], [1.0, 1.0], [0.0, 0.75], [0.75, 0.0]])
    z = warped_points(BOARD, WARP)[:, 2]
    xr, yr = pts[:, 0] / 225.0, pts[:, 1] / 175.0
    assert np.allclose(z, WARP[0] * 4 * xr * (1 - xr) + WARP[1] * 4 * yr * (1 - yr))


def test_the_warps_jacobian_matches_finite_differences():
    obj, img = observations(WARP, low_tilt=False, seed=1)
    poses = sample_poses(CAM, BOARD, 12, 5, min_tilt_deg=10.0, max_tilt_deg=50.0)
    prob = Problem(obj, img, CAM.intrinsics, list(range(9)), None, None, "opencv5", warp_box(obj))
    x = prob.pack(CAM.intrinsics, np.array([p[0] for p in poses]), np.array([p[1] for p in poses]))
    x[9:11] = (0.7, -0.3)
    _, _, Jg, _ = prob.evaluate(x)
    for k in (9, 10):
        e = np.zeros_like(x)
        e[k] = 1e-5
        fd = (prob.fun(x + e) - prob.fun(x - e)) / 2e-5
        assert np.max(np.abs(fd - Jg[:, :, k].ravel())) <= 1e-6 * np.max(np.abs(fd))


@pytest.mark.parametrize("low_tilt", [True, False], ids=["low-tilt", "spread-tilts"])
def test_a_warped_board_is_detected_and_its_warp_is_within_its_sigmas(low_tilt):
    """The flat calibration's board-shape check: not flat, the warp within 3 stated sigmas of the truth, the warped
    board predicts held-out views better and is recommended; the warped solve's intrinsics are within 3 stated
    sigmas of the truth, the flat one's are not at low tilt (the trap)."""
    obj, img = observations(WARP, low_tilt=low_tilt, seed=2)
    flat = calibrate(obj, img, SIZE)
    shape = board_shape(flat, CalibrationOptions())
    assert shape.fitted == "flat" and shape.flat is False and shape.chi2 > FLAT_CHI2
    err = np.abs(np.array(shape.warp_mm) - WARP) / np.array(shape.warp_std_mm)
    assert np.all(err <= 3.0), (shape.warp_mm, shape.warp_std_mm)
    assert shape.held_out is not None and shape.held_out.better == "warped"
    assert shape.held_out.warped_px < 0.8 * shape.held_out.flat_px
    assert shape.recommended == "warped" and shape.add == ("--board-warp",) and shape.remove == ()
    assert "NOT flat" in shape.line() and shape.recommendation().startswith("recommended: the warped board")
    assert shape.notable
    warped = calibrate(obj, img, SIZE, CalibrationOptions(board_warp=True))
    assert max(within_sigmas(warped).values()) <= 3.0
    assert np.allclose(warped.board_warp, shape.warp_mm, atol=1e-6)  # the check's warp is the warped solve's
    if low_tilt:
        assert max(within_sigmas(flat).values()) > 3.0  # the flat board's answer is sure of itself and wrong
        assert max(abs(s) for _, s in shape.shift.values()) > 3.0


def test_a_flat_board_reports_flat_and_changes_nothing():
    obj, img = observations(None, low_tilt=True, seed=3)
    cal = calibrate_and_assess(None, BOARD, observations=(obj, img), image_size=SIZE)
    shape = cal.board_shape
    assert shape is not None and shape.flat is True and shape.chi2 <= FLAT_CHI2
    assert shape.recommended == "flat" and not shape.changes and shape.recommendation() is None
    assert all(abs(s) < 1.0 for _, s in shape.shift.values()), shape.shift
    assert cal.result.board_warp is None  # the calibration itself is the flat one
    assert not any(line.startswith("board shape") for line in cal.verdict)  # the verdict is unchanged
    assert any(line.startswith("board shape: flat within the data's noise") for line in cal.lines())
    assert not any("--board-warp" in line for line in cal.assessment.next_lines())
    assert cal.assessment.to_dict()["board_shape"]["flat"] is True


def test_a_warped_run_on_a_flat_board_recommends_the_flat_board():
    obj, img = observations(None, low_tilt=False, seed=4)
    res = calibrate(obj, img, SIZE, CalibrationOptions(board_warp=True))
    shape = board_shape(res, CalibrationOptions(board_warp=True))
    assert shape.fitted == "warped" and shape.flat is True
    assert shape.recommended == "flat" and shape.remove == ("--board-warp",) and shape.add == ()


def test_the_refined_board_states_its_shift_from_the_flat_board():
    obj, img = observations(WARP, low_tilt=True, seed=5)
    res = calibrate(obj, img, SIZE, CalibrationOptions(refine_board=True))
    shape = board_shape(res, CalibrationOptions(refine_board=True))
    flat = calibrate(obj, img, SIZE)
    names = CAM.model.param_names
    for n in INTRINSICS:
        d, s = shape.shift[n]
        i = names.index(n)
        assert d == pytest.approx(flat.camera.intrinsics[i] - res.camera.intrinsics[i], abs=1e-6)
        assert s == pytest.approx(d / res.std[n])
    line = shape.line()
    assert line.startswith("board shape: refined") and "sigma" in line and not shape.changes


def test_the_result_carries_the_warp_into_lookup_and_model_json():
    obj, img = observations(WARP, low_tilt=False, seed=6)
    res = calibrate(obj, img, SIZE, CalibrationOptions(board_warp=True))
    assert np.allclose(res.board_lookup(BOARD.object_points()), warped_points(BOARD, tuple(res.board_warp)))
    assert res.board_warp_cov.shape == (2, 2) and np.all(res.board_warp_std > 0)
    doc = json.loads(jsonio.dumps(res.to_model_json()))
    if "board_warp" in MODEL_SECTIONS:  # model.json's sections are listed in circcal.formats.modeljson
        section = doc["board_warp"]
        assert np.allclose(section["warp_mm"], res.board_warp) and section["box_mm"] == [0.0, 225.0, 0.0, 175.0]
    plain = calibrate(obj, img, SIZE)
    assert plain.board_warp is None and "board_warp" not in plain.to_model_json()
    assert plain.n_params + 2 == res.n_params


def test_the_warp_and_the_refined_board_are_refused_together():
    with pytest.raises(InputError, match="board_warp and refine_board"):
        CalibrationOptions(board_warp=True, refine_board=True)
    with pytest.raises(InputError, match="--board-warp and --refine-board"):
        calibration_options(argparse.Namespace(board_warp=True, refine_board=True, lens="opencv5"))
    assert calibration_options(argparse.Namespace(board_warp=True, lens="opencv5")).board_warp


def test_folds_keep_enough_views():
    assert folds(5) == []
    assert folds(6) == [[0, 4], [1, 5], [2], [3]]  # every training set keeps 4 views
    assert folds(7) == [[0, 4], [1, 5], [2, 6], [3]]
    assert len(folds(12)) == 4 and sorted(sum(folds(12), [])) == list(range(12))


def test_a_warped_render_is_exact():
    """The warped board's render: darkness-weighted centroids within 0.002 px of the exact area centroids of the rims
    on the surface, which differ from the flat board's by pixels."""
    board = Board(4, 5, 10.0, 5.0)
    cam = Camera(640, 480, 600.0, 600.0, 319.5, 239.5, [-0.1, 0.0, 0.0, 0.0, 0.0])
    rvec, tvec = pose_looking_at(cam, board, distance_mm=120.0, tilt_deg=35.0, tilt_axis_deg=30.0, target_px=(330, 250))
    w = (1.5, -1.0)
    _, dark = render_coverage(cam, board, rvec, tvec, warp=w)
    exact = area_centroids(cam, board, rvec, tvec, warp=w)
    from scipy import ndimage

    labels, n = ndimage.label(dark > 0)
    assert n == board.n_points
    idx = np.arange(1, n + 1)
    vv, uu = np.mgrid[0 : dark.shape[0], 0 : dark.shape[1]]
    s = ndimage.sum(dark, labels, idx)
    found = np.stack([ndimage.sum(dark * uu, labels, idx) / s, ndimage.sum(dark * vv, labels, idx) / s], -1)
    found = found[np.argmin(np.linalg.norm(exact[:, None] - found[None], axis=-1), axis=1)]
    assert float(np.sqrt(np.mean(np.sum((found - exact) ** 2, axis=1)))) <= 0.002
    assert np.max(np.linalg.norm(exact - area_centroids(cam, board, rvec, tvec), axis=1)) > 1.0
    centres = project(warped_points(board, w), rvec, tvec, cam)  # the truth: the 3-D centres' projections
    assert np.max(np.linalg.norm(exact - centres, axis=1)) < 0.2  # the perspective bias only


MC_RUNS = 100


@pytest.mark.slow
@pytest.mark.parametrize("low_tilt", [True, False], ids=["low-tilt", "spread-tilts"])
def test_monte_carlo_the_recommended_model_is_within_3_sigmas(low_tilt):
    """100 noise draws on fixed poses of the warped board: the default calibration's board-shape check recommends
    the warped board in >= 95 % and the recommended model's fx, fy, cx, cy are all within 3 stated sigmas of the
    truth in >= 95 % (reports/board-warp.md)."""
    ok = recommended_warped = 0
    worst = []
    for seed in range(MC_RUNS):
        obj, img = observations(WARP, low_tilt=low_tilt, seed=1000 + seed)
        flat = calibrate(obj, img, SIZE)
        shape = board_shape(flat, CalibrationOptions())
        model = calibrate(obj, img, SIZE, CalibrationOptions(board_warp=True)) if shape.add else flat
        recommended_warped += shape.recommended == "warped"
        z = max(within_sigmas(model).values())
        worst.append(z)
        ok += z <= 3.0
    print(f"low_tilt={low_tilt}: warped recommended {recommended_warped}/{MC_RUNS}, within 3 sigma {ok}/{MC_RUNS}")
    assert recommended_warped >= 0.95 * MC_RUNS
    assert ok >= 0.95 * MC_RUNS, sorted(worst)[-10:]


def test_the_mrcal_export_sends_the_fitted_warp_in_metres(monkeypatch):
    """cameramodel_export hands the worker circcal's warp as mrcal's calobject_warp (m), on the lattice whose edges
    are the warp's; a flat calibration sends none (the worker writes a held flat board)."""
    from circcal.formats import cameramodel_export as ce

    sent = []
    monkeypatch.setattr(ce, "_run_worker", lambda req, python: sent.append(req) or {"cameramodel": "x"})
    obj, img = observations(WARP, low_tilt=False, seed=7)
    res = calibrate(obj, img, SIZE, CalibrationOptions(board_warp=True))
    ce.cameramodel_text(res.camera, ce.result_views(res))
    assert np.allclose(sent[-1]["calobject_warp"], res.board_warp * 1e-3)
    assert "as calobject_warp (estimated)" in sent[-1]["note"]
    assert (sent[-1]["width_n"] - 1) * sent[-1]["spacing"] == pytest.approx(225.0e-3)  # the warp box's x span
    flat = calibrate(obj, img, SIZE)
    ce.cameramodel_text(flat.camera, ce.result_views(flat))
    assert "calobject_warp" not in sent[-1] and "(no warp," in sent[-1]["note"]
    doc = {"views": [{"rvec": [0, 0, 0], "tvec_mm": [0, 0, 1], "object_mm": [], "image_px": []}]}
    assert ce.document_views({**doc, "board_warp": {"warp_mm": [1.0, 2.0]}})["board_warp"].tolist() == [1.0, 2.0]
    with pytest.raises(InputError, match="board_warp"):
        ce.document_views({**doc, "board_warp": {"warp_mm": "sag"}})


def test_the_exported_cameramodel_carries_the_warp_into_mrcal():
    """The real worker writes the fitted warp into the .cameramodel's optimisation inputs, and mrcal reads it back
    (metres, mrcal's calobject_warp); its own residuals at circcal's solution match circcal's (the same model)."""
    import json
    import subprocess

    from circcal.formats import cameramodel_export as ce
    from circcal.formats.mrcal_process import mrcal_python

    python, why, _ = mrcal_python()
    if python is None:
        pytest.skip(why)
    obj, img = observations(WARP, low_tilt=False, seed=7)
    res = calibrate(obj, img, SIZE, CalibrationOptions(board_warp=True))
    text, info = ce.cameramodel_text(res.camera, ce.result_views(res))
    assert info["optimization_inputs"], info
    script = (
        "import sys, json, io, mrcal, numpy as np\n"
        "m = mrcal.cameramodel(io.StringIO(sys.stdin.read()))\n"
        "o = m.optimization_inputs()\n"
        "x = mrcal.optimizer_callback(**o)[1]\n"
        "n = int(np.sum(o['observations_board'][..., 2] > 0))\n"
        "print(json.dumps({'warp': o['calobject_warp'].tolist(), 'rms': float(np.sqrt(np.sum(x[: 2 * o['observations_board'][..., 0].size] ** 2) / (2 * n)))}))\n"
    )
    out = subprocess.run([python, "-c", script], input=text, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-800:]
    got = json.loads(out.stdout)
    assert np.allclose(got["warp"], res.board_warp * 1e-3, rtol=1e-9, atol=1e-15)
    assert got["rms"] == pytest.approx(res.errors["rms_per_coord_px"], rel=1e-3)


def test_the_refined_board_states_how_its_shape_trades_with_the_intrinsics():
    """Refining the board spends some of the views' information on its shape: per unit of pixel noise the refined
    solve's sigmas exceed the flat board's. Measured at 5-15 deg tilt: cx, cy x3.3-3.5 with 12 views, fx x1.1 with
    12 views and x4.2 with 4; the verdict's line names the parameters past TRADE_OFF."""
    from circcal.analysis.boardshape import TRADE_OFF

    def shape_of(n):
        obj, img = observations(WARP, low_tilt=True, seed=5, n=n)
        res = calibrate(obj, img, SIZE, CalibrationOptions(refine_board=True))
        return obj, img, res, board_shape(res, CalibrationOptions(refine_board=True))

    obj, img, res, shape = shape_of(12)
    flat = calibrate(obj, img, SIZE)
    for n in INTRINSICS:
        assert shape.inflation[n] == pytest.approx((res.std[n] / res.sigma_px) / (flat.std[n] / flat.sigma_px))
        assert shape.inflation[n] > 1.0
    worst = max(shape.inflation, key=shape.inflation.get)
    assert shape.inflation[worst] >= TRADE_OFF and worst in ("cx", "cy")
    assert "trade off" in shape.line() and f"{worst} x" in shape.line()
    assert shape_of(4)[3].inflation["fx"] > 2.0 * shape.inflation["fx"]


@pytest.mark.slow  # 40 refined solves: about a minute on a quiet machine (make study)
def test_the_refined_boards_stated_sigmas_match_monte_carlo_at_low_tilt():
    """The refined board's covariance counts the board's coordinates (the trap of low tilt is a large, honest sigma,
    not a small, wrong one): over 40 noise draws the spread of fx, fy, cx, cy is within 0.65-1.5x of the median
    stated sigma, and the truth within 3 stated sigmas in >= 90 % of the draws."""
    est, stated, inside = [], [], 0
    for seed in range(40):
        obj, img = observations(WARP, low_tilt=True, seed=100 + seed, n=10)
        res = calibrate(obj, img, SIZE, CalibrationOptions(refine_board=True))
        est.append([res.camera.intrinsics[CAM.model.param_names.index(n)] for n in INTRINSICS])
        stated.append([res.std[n] for n in INTRINSICS])
        inside += all(z <= 3.0 for z in within_sigmas(res).values())
    ratio = np.std(est, axis=0, ddof=1) / np.median(stated, axis=0)
    assert np.all((ratio > 0.65) & (ratio < 1.5)), dict(zip(INTRINSICS, ratio.round(2)))
    assert inside >= 36
