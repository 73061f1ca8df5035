"""The published comparison report: circcal against OpenCV, mrcal, kornia, pycolmap and a checkerboard, on rendered
fixtures with ground truth and on real photographs.

:func:`compute` gathers every number (deterministic: fixed fixtures, fixed seeds, no clocks in the numbers; run times
are kept apart in ``timings``); :func:`write_report` turns them into ``index.md``, a self-contained ``index.html``
(figures embedded as base64 PNG), the PNG figures and ``report.json``, written atomically (a temporary folder beside
the target, renamed into place: a failure leaves the previous report untouched); :func:`generate` does both and
updates the index ``reports/README.md``.

Error conventions (every key names its own): ``mean_2d_px`` = mean of the 2-D error norm (the paper's eq. 22 and its
tables), ``rms_per_point_px`` = OpenCV's RMS, ``rms_per_coord_px`` = mrcal's. "vs truth" = RMS over a 60-wide pixel
grid of the projection difference between the true camera and the calibrated one, the implied rotation fitted
(:func:`circcal.validators.compare.projection_diff`); "centre error" = detected centres against the exact projections of the
true centres (:func:`circcal.validators.compare.centre_errors`).
"""
from __future__ import annotations

import base64
import html
import json
import os
import platform
import re
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from circcal import atomic
from circcal.board import Board
from circcal.jsonio import jsonable
from circcal.metrics import error_stats
from circcal.model import PARAM_NAMES, Camera, project

__all__ = ["ReportConfig", "FULL", "QUICK", "PAPER_PUBLISHED", "compute", "write_report", "generate",
           "paper_conditions", "checkerboard_conditions", "bias_study", "realdata_study", "FIGURES"]

REPO = Path(__file__).resolve().parents[2]
REALDATA = REPO / ".." / "shared" / "data" / "realdata"

#: Chen et al. 2023, Table 7: mean reprojection error (px) per illumination condition (no "normal" column there).
PAPER_PUBLISHED: dict[str, dict[str, float]] = {
    "circles": {"uneven": 0.1087, "strong": 0.1016, "weak": 0.1199},
    "checkerboard": {"uneven": 0.135, "strong": 0.157, "weak": 0.160},
}

CONDITIONS = ("normal", "uneven", "strong", "weak")


@dataclass(frozen=True)
class ReportConfig:
    """What a report run covers. ``n_views``: first N views of each fixture (None: all 14); ``references``: names for
    :func:`circcal.validators.validate.run_validation`; ``bias_*``: the clean-render grid of the bias study (tilt in degrees,
    dot diameter in px at the board centre); ``realdata``: folder names under ``../shared/data/realdata``."""

    name: str = "full"
    conditions: tuple[str, ...] = CONDITIONS
    checkerboard_conditions: tuple[str, ...] = CONDITIONS
    n_views: int | None = None
    references: tuple[str, ...] = ("all",)
    bias_tilts_deg: tuple[float, ...] = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0)
    bias_diameters_px: tuple[float, ...] = (14.0, 20.0, 30.0, 45.0, 60.0)
    realdata: tuple[str, ...] = ("boofcv_sony_hx5v_circle_asym_4x5", "boofcv_sony_hx5v_circle_regular_10x8")
    heldout: bool = True


FULL = ReportConfig()
QUICK = ReportConfig(name="quick", conditions=("normal",), checkerboard_conditions=("normal",), n_views=8,
                     bias_tilts_deg=(0.0, 30.0, 60.0), bias_diameters_px=(20.0, 45.0),
                     realdata=("boofcv_sony_hx5v_circle_asym_4x5",))


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------

def _errors3(stats: dict | None) -> dict[str, float] | None:
    if not stats:
        return None
    return {k: stats.get(k) for k in ("n_points", "mean_2d_px", "rms_per_point_px", "rms_per_coord_px", "max_2d_px")}


def _vs_truth(truth: Camera, cam: Camera | None) -> dict[str, float] | None:
    from circcal.validators.compare import projection_diff

    if cam is None:
        return None
    fit = projection_diff(truth, cam, fit=True)
    raw = projection_diff(truth, cam, fit=False)
    return {"rms_px": fit["rms_px"], "max_px": fit["max_px"], "nofit_rms_px": raw["rms_px"],
            "nofit_max_px": raw["max_px"]}


def _camera_or_none(d: dict | None) -> Camera | None:
    return None if not d else Camera.from_dict(d)


def _fixture(scenario: str, variant: str, n_views: int | None, progress: bool):
    from circcal.fixtures.scenarios import fixture_dir, load_truth

    truth = load_truth(fixture_dir(scenario, variant, progress=progress))
    views = truth.views if n_views is None else truth.views[:n_views]
    return truth, views


# ----------------------------------------------------------------------------------------------------------------
# 1-2. the paper's Table 7 and per-image errors (circle conditions)
# ----------------------------------------------------------------------------------------------------------------

def _row(label: str, status: str, message: str, camera: Camera | None, std: dict | None, errors: dict | None,
         truth: Camera, *, centre: dict | None = None, centre_note: str = "", per_view: list | None = None,
         views: list | None = None, detector: str = "", observations: str = "") -> dict[str, Any]:
    return {"label": label, "status": status, "message": message, "detector": detector,
            "observations": observations, "camera": camera, "std": std, "errors": _errors3(errors),
            "vs_truth": _vs_truth(truth, camera) if status == "ok" else None,
            "centre_error": _errors3(centre), "centre_note": centre_note,
            "per_view_mean_2d_px": per_view, "views": views}


def paper_condition(variant: str, cfg: ReportConfig, *, progress: bool = True) -> tuple[dict, dict]:
    """One illumination condition of the ``paper`` scenario. Returns (numbers, timings).

    circcal and the references on circcal's centres come from :func:`circcal.validators.validate.run_validation`; the OpenCV
    circle pipeline (findCirclesGrid with its own blob detector, then calibrateCamera) runs on the same images.
    """
    from circcal.solver import calibrate
    from circcal.validators.compare import centre_errors
    from circcal.validators.opencv import OpenCVCalibrator
    from circcal.validators.validate import run_validation

    truth, views = _fixture("paper", variant, cfg.n_views, progress)
    paths = [str(v.image) for v in views]
    board, cam_t = truth.board, truth.camera
    run = run_validation(paths, board, truth=cam_t, against=cfg.references, mode="both", progress=progress,
                         source={"scenario": "paper", "variant": variant})
    timings: dict[str, float] = {"circcal": run.circcal["time_s"]}
    rows: dict[str, dict] = {}
    cc = run.circcal
    # circcal's final centres as every reference received them (float32-rounded, <= 6e-5 px from circcal's own)
    shared = next((r for r in run.references if r.ok and r.image_points is not None), None)
    failed_paths = {r.path for r in cc.get("failed") or []}
    used = [i for i, p in enumerate(paths) if p not in failed_paths]
    if cc["status"] == "ok" and shared is not None:
        again = calibrate(shared.object_points, shared.image_points, run.image_size, initial=cc["solver_camera"])
        per_view = [e["mean_2d_px"] for e in again.per_view_errors]
        ce = centre_errors(shared.image_points, [views[i].centres for i in used], board=board)
        rows["circcal"] = _row("circcal", "ok", "", cc["camera"], cc["std"], cc["errors"], cam_t,
                               centre=ce["overall"], per_view=per_view, views=used, detector="circcal",
                               observations="own", centre_note="circcal's final centres")
    else:
        rows["circcal"] = _row("circcal", cc["status"], cc.get("message", "no shared observations"), None, None,
                               None, cam_t, detector="circcal", observations="own")

    # the OpenCV circle pipeline: findCirclesGrid (own blob detector) + calibrateCamera
    t0 = time.perf_counter()
    ocv = OpenCVCalibrator().calibrate_images(paths, board, run.image_size)
    timings["opencv-pipeline"] = time.perf_counter() - t0
    if ocv.ok:
        ce = centre_errors(ocv.image_points, [views[i].centres for i in ocv.views], board=board)
        per_view = [error_stats(r)["mean_2d_px"] for r in ocv.residuals]
        rows["opencv-pipeline"] = _row(f"OpenCV {ocv.version} circle pipeline", "ok", ocv.message, ocv.camera,
                                       ocv.std, ocv.errors, cam_t, centre=ce["overall"], per_view=per_view,
                                       views=list(ocv.views), detector="findCirclesGrid (SimpleBlobDetector)",
                                       observations="own", centre_note="blob centroids")
    else:
        rows["opencv-pipeline"] = _row(f"OpenCV {ocv.version} circle pipeline", ocv.status, ocv.message, None, None,
                                       None, cam_t, detector="findCirclesGrid", observations="own")

    for r in run.references:
        key = f"{r.name}-{r.mode}"
        timings[key] = r.time_s
        label = f"{r.name} {r.version} [{r.mode}]"
        rows[key] = _row(label, r.status, r.message, r.camera, r.std, r.errors, cam_t, detector="circcal",
                         observations="circcal's centres",
                         centre=rows["circcal"]["centre_error"] if r.ok else None,
                         centre_note="circcal's centres (same observations)")
    checks = [{"name": c.name, "value": c.value, "bound": c.bound, "passed": c.passed, "note": c.note}
              for c in run.checks]
    return {"n_views": len(paths), "rows": rows, "checks": checks, "validation_passed": run.passed,
            "failed_images": [[Path(r.path).name, r.reason] for r in cc.get("failed") or []]}, timings


def paper_conditions(cfg: ReportConfig, *, progress: bool = True) -> tuple[dict, dict]:
    from tqdm import tqdm

    out, times = {}, {}
    for v in tqdm(cfg.conditions, desc="report: paper conditions", unit="condition", disable=not progress):
        out[v], times[v] = paper_condition(v, cfg, progress=False)
    return out, times


# ----------------------------------------------------------------------------------------------------------------
# 1b. the rendered 12x9 checkerboard through OpenCV's chessboard detector
# ----------------------------------------------------------------------------------------------------------------

def find_chessboard(gray: np.ndarray, board: Board) -> tuple[np.ndarray | None, str]:
    """Inner corners of ``board`` (checkerboard) in a grey uint8 image: ``cv2.findChessboardCorners`` (adaptive
    threshold, normalised) refined by ``cv2.cornerSubPix`` (11x11 window), as OpenCV's tutorial and the paper's era
    do; ``cv2.findChessboardCornersSB`` (accuracy flag) if that fails. Returns ((N, 2) px or None, how)."""
    import cv2

    ok, c = cv2.findChessboardCorners(gray, board.pattern_size,
                                      flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if ok:
        c = cv2.cornerSubPix(gray, c, (11, 11), (-1, -1),
                             (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4))
        return c.reshape(-1, 2).astype(np.float64), "findChessboardCorners+cornerSubPix"
    ok, c = cv2.findChessboardCornersSB(gray, board.pattern_size, flags=cv2.CALIB_CB_ACCURACY)
    if ok:
        return c.reshape(-1, 2).astype(np.float64), "findChessboardCornersSB"
    return None, "checkerboard not found (findChessboardCorners and findChessboardCornersSB)"


def checkerboard_condition(variant: str, cfg: ReportConfig, *, progress: bool = True) -> tuple[dict, float]:
    import cv2

    from circcal.validators.compare import centre_errors
    from circcal.validators.opencv import OpenCVCalibrator

    t0 = time.perf_counter()
    truth, views = _fixture("paper-checkerboard", variant, cfg.n_views, progress)
    board, cam_t = truth.board, truth.camera
    obj, img, used, missed, hows = [], [], [], {}, set()
    for i, v in enumerate(views):
        gray = cv2.imread(str(v.image), cv2.IMREAD_GRAYSCALE)
        c, how = find_chessboard(gray, board)
        if c is None:
            missed[v.image.name] = how
            continue
        obj.append(board.object_points())
        img.append(c)
        used.append(i)
        hows.add(how)
    label = f"OpenCV {cv2.__version__} checkerboard 11x8 corners (12x9 squares)"
    if len(used) < 3:
        return _row(label, "failed", f"board found in {len(used)} of {len(views)} images: {missed}", None, None,
                    None, cam_t, detector="findChessboardCorners"), time.perf_counter() - t0
    res = OpenCVCalibrator().calibrate_observations(obj, img, (cam_t.width, cam_t.height))
    if not res.ok:
        return _row(label, res.status, res.message, None, None, None, cam_t), time.perf_counter() - t0
    ce = centre_errors(img, [views[i].centres for i in used], board=board)
    msg = f"missed {len(missed)} of {len(views)} views: {missed}" if missed else ""
    row = _row(label, "ok", msg, res.camera, res.std, res.errors, cam_t, centre=ce["overall"],
               per_view=[error_stats(r)["mean_2d_px"] for r in res.residuals], views=used,
               detector=" / ".join(sorted(hows)), observations="own", centre_note="corner error vs true corners")
    return row, time.perf_counter() - t0


def checkerboard_conditions(cfg: ReportConfig, *, progress: bool = True) -> tuple[dict, dict]:
    from tqdm import tqdm

    out, times = {}, {}
    for v in tqdm(cfg.checkerboard_conditions, desc="report: checkerboard", unit="condition",
                  disable=not progress):
        out[v], times[v] = checkerboard_condition(v, cfg, progress=False)
    return out, times


# ----------------------------------------------------------------------------------------------------------------
# 3. the bias study on clean renders
# ----------------------------------------------------------------------------------------------------------------

#: Camera of the bias study: 1280x960, f 1500 px, mild barrel distortion.
BIAS_CAMERA = Camera(1280, 960, 1500.0, 1500.0, 639.5, 479.5, np.array([-0.1, 0.05, 0.0, 0.0, 0.0]))
BIAS_PITCH_MM = 20.0
BIAS_GRID = 7
BIAS_SPAN_PX = 528.0          # the 7x7 point grid spans 528 px at tilt 0 (55% of the image height)
BIAS_TILT_AXIS_DEG = 30.0
BIAS_BLUR = [{"kind": "gaussian_blur", "sigma_px": 0.7}]


def bias_study(cfg: ReportConfig, *, progress: bool = True) -> tuple[dict, float]:
    """Centre error against tilt and dot size on clean renders (blur 0.7 px, 8-bit, no noise).

    The board (7x7 dots, 20 mm pitch) is centred on the principal point at a fixed distance; the dot diameter (mm) is
    set so that a dot at the board centre spans ``d`` px at tilt 0. Per (tilt, diameter): circcal's detector given
    the true model (what :func:`circcal.solver.calibrate_images` converges to), circcal's detector without a
    model (perspective correction only), OpenCV's ``findCirclesGrid`` with a SimpleBlobDetector whose area window is
    fitted to the dot size, and the exact area centroid of each projected dot (a perfect blob detector,
    :func:`circcal.fixtures.render.area_centroids`). Errors against the exact projections of the true centres.
    """
    import cv2
    from tqdm import tqdm

    from circcal.detector import detect, recorrect
    from circcal.fixtures.perturb import apply_perturbations
    from circcal.fixtures.poses import pose_looking_at
    from circcal.fixtures.render import Levels, area_centroids, render_coverage
    from circcal.validators.compare import match_grid_order
    from circcal.validators.opencv import find_circles_grid

    t0 = time.perf_counter()
    cam = BIAS_CAMERA
    f = 0.5 * (cam.fx + cam.fy)
    span_mm = (BIAS_GRID - 1) * BIAS_PITCH_MM
    distance = f * span_mm / BIAS_SPAN_PX
    px_per_mm = f / distance
    tilts, diams = list(cfg.bias_tilts_deg), list(cfg.bias_diameters_px)
    keys = ("circcal", "circcal_nomodel", "opencv", "perfect_centroid")
    mean = {k: np.full((len(tilts), len(diams)), np.nan) for k in keys}
    mx = {k: np.full((len(tilts), len(diams)), np.nan) for k in keys}
    notes: list[str] = []
    lv = Levels()
    cells = [(i, j) for i in range(len(tilts)) for j in range(len(diams))]
    for i, j in tqdm(cells, desc="report: bias renders", unit="render", disable=not progress):
        tilt, d_px = tilts[i], diams[j]
        board = Board(BIAS_GRID, BIAS_GRID, BIAS_PITCH_MM, d_px / px_per_mm, "symmetric")
        rvec, tvec = pose_looking_at(cam, board, distance_mm=distance, tilt_deg=tilt,
                                     tilt_axis_deg=BIAS_TILT_AXIS_DEG)
        true_c = project(board.object_points(), rvec, tvec, cam)
        bc, dc = render_coverage(cam, board, rvec, tvec, supersample=6)
        clean = lv.background + bc * (lv.board - lv.background) - dc * (lv.board - lv.dark)
        image, _, _ = apply_perturbations(clean, BIAS_BLUR, 0, board_mask=bc > 0.5, bits=8)
        found: dict[str, np.ndarray | None] = {}
        det = detect(image, board, camera=None)
        if det.found:
            found["circcal_nomodel"] = det.centres
            found["circcal"] = recorrect(det, board, cam)
        else:
            notes.append(f"tilt {tilt:g} deg, {d_px:g} px: circcal: {det.reason}")
        area = np.pi / 4.0 * d_px ** 2
        p = cv2.SimpleBlobDetector_Params()
        p.minArea, p.maxArea = float(0.15 * area), float(2.5 * area)
        p.minInertiaRatio = 0.05
        c, how = find_circles_grid(image, board, detector=cv2.SimpleBlobDetector_create(p))
        if c is None:
            notes.append(f"tilt {tilt:g} deg, {d_px:g} px: OpenCV: {how}")
        found["opencv"] = c
        found["perfect_centroid"] = area_centroids(cam, board, rvec, tvec, n=4000)
        for k, c in found.items():
            if c is None:
                continue
            c, _, _ = match_grid_order(c, true_c, board)
            e = np.hypot(*(c - true_c).T)
            mean[k][i, j] = float(np.mean(e))
            mx[k][i, j] = float(np.max(e))
    out = {"camera": cam, "board": {"rows": BIAS_GRID, "cols": BIAS_GRID, "pitch_mm": BIAS_PITCH_MM,
                                    "diameters_mm": [d / px_per_mm for d in diams]},
           "distance_mm": distance, "tilt_axis_deg": BIAS_TILT_AXIS_DEG, "perturbations": BIAS_BLUR,
           "tilts_deg": tilts, "diameters_px": diams,
           "mean_2d_px": mean, "max_2d_px": mx, "notes": notes}
    return out, time.perf_counter() - t0


# ----------------------------------------------------------------------------------------------------------------
# 6. real photographs
# ----------------------------------------------------------------------------------------------------------------

def realdata_board(folder: Path) -> tuple[Board, dict]:
    """The board of a real-data folder: grid and spacing from ``opencv_baseline.json``, dot diameter from
    ``SOURCE.txt`` ("diameter <x> cm"). Lengths in mm."""
    base = json.loads((folder / "opencv_baseline.json").read_text())
    src = (folder / "SOURCE.txt").read_text()
    m = re.search(r"diameter\s+([0-9.]+)\s*cm", src)
    if m is None:
        raise ValueError(f"{folder / 'SOURCE.txt'} states no dot diameter ('diameter <x> cm')")
    cols, rows = base["pattern_size_cols_rows"]
    unit = {"metres": 1000.0, "meters": 1000.0, "mm": 1.0, "millimetres": 1.0}[base.get("spacing_units", "metres")]
    board = Board(int(rows), int(cols), float(base["spacing_s"]) * unit, float(m.group(1)) * 10.0,
                  "asymmetric" if base["grid"].startswith("asym") else "symmetric")
    return board, base


def _pnp_residual(obj: np.ndarray, img: np.ndarray, cam: Camera) -> np.ndarray:
    """Residual (N, 2) px of ``img`` against the board projected with ``cam`` at the pose fitted to ``img``
    (:func:`circcal.solver.fit_pose`: 6 pose parameters fitted, intrinsics held)."""
    from circcal.solver import fit_pose

    rvec, tvec = fit_pose(obj, img, cam)
    return np.asarray(img, dtype=np.float64) - project(obj, rvec, tvec, cam)


def _finite(centres: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    ok = np.all(np.isfinite(c), axis=1)
    return pts[ok], c[ok]


def _circcal_without(detections: list, keep: list[int], board: Board, size: tuple[int, int], *,
                     refine_board: bool = False):
    """circcal's model from the views ``keep`` only (:func:`circcal.solver.calibrate_detections` on the stored
    detections; ``refine_board`` as there). Returns the :class:`circcal.solver.CalibrationResult`
    (``board_lookup`` gives the refined board points)."""
    from circcal.pipeline import calibrate_detections

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return calibrate_detections([detections[i] for i in keep], board, size, refine_board=refine_board)[0]


def _board_block(res) -> dict[str, Any]:
    """The refined board of a :class:`circcal.solver.CalibrationResult`: nominal points and the refined ones'
    deviations from them, their standard deviations, the gauge, and how far the sheet is from the nominal board
    (``max_abs_dev_mm``: the largest deviation of one coordinate; ``max_abs_dxy_mm``: the largest in-plane
    displacement; ``median_std_mm``: over the estimated coordinates, the held ones left out)."""
    dev = res.board_points - res.board_nominal
    std = res.board_std
    med = float(np.median(std[std > 0]))
    top = float(np.max(np.abs(dev)))
    # deviations, not positions: report.json keeps 6 significant digits, 1e-3 mm on a 200 mm coordinate
    return {"nominal_mm": res.board_nominal, "deviation_mm": dev, "std_mm": std,
            "gauge": [int(i) for i in res.board_gauge], "max_abs_dev_mm": top,
            "max_abs_dz_mm": float(np.max(np.abs(dev[:, 2]))),
            "max_abs_dxy_mm": float(np.max(np.linalg.norm(dev[:, :2], axis=1))),
            "median_std_mm": med, "max_dev_over_median_std": top / med}


def _refined_entry(res, views: list[str]) -> dict[str, Any]:
    return {"status": "ok", "message": "", "camera": res.camera, "std": res.std, "errors": _errors3(res.errors),
            "views": views, "per_view_mean_2d_px": [e["mean_2d_px"] for e in res.per_view_errors],
            "board": _board_block(res)}


def _mean_of_views(per: list[dict]) -> dict[str, Any]:
    good = [p for p in per if "failed" not in p]
    return {"per_view": per,
            "mean_of_views": {m: (float(np.mean([p[m] for p in good])) if good else float("nan"))
                              for m in ("mean_2d_px", "rms_per_point_px", "rms_per_coord_px")}}


def realdata_set(folder: Path, *, heldout: bool = True, progress: bool = True) -> tuple[dict, dict]:
    """circcal on one real-data folder against OpenCV's baseline (its findCirclesGrid centres, recalibrated here with
    :class:`circcal.validators.opencv.OpenCVCalibrator` so all three conventions and the held-out test use one solver), with
    a rigid board and with the board's shape estimated (``refine_board``: circcal on its own centres, and the same
    solver on the baseline's centres put into circcal's point order with
    :func:`circcal.validators.compare.match_views`)."""
    from tqdm import tqdm

    from circcal.pipeline import calibrate_images
    from circcal.solver import CalibrationError, calibrate
    from circcal.detector import recorrect
    from circcal.validators.compare import match_views, projection_diff
    from circcal.validators.opencv import OpenCVCalibrator

    board, base = realdata_board(folder)
    size = tuple(int(v) for v in base["image_size_wh"])
    paths = sorted(str(p) for p in folder.glob("*.jpg"))
    out: dict[str, Any] = {"folder": folder.name, "board": board.to_dict(), "image_size": list(size),
                           "n_images": len(paths),
                           "baseline": {"rms_per_point_px": base["rms_px"], "opencv_version": base["opencv_version"],
                                        "flags": base.get("findCirclesGrid_flags"),
                                        "used": base.get("used_for_calibration"),
                                        "camera_matrix": base["camera_matrix"],
                                        "dist": base["dist_k1k2p1p2k3"]}}
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    pts = board.object_points()
    # OpenCV: the baseline's own findCirclesGrid centres
    ocv_views = [(pi["image"], np.asarray(pi["centers"], dtype=np.float64).reshape(-1, 2)) for pi in base["per_image"]
                 if pi.get("found")]
    ocv = OpenCVCalibrator().calibrate_observations([pts] * len(ocv_views), [c for _, c in ocv_views], size)
    out["opencv"] = {"status": ocv.status, "message": ocv.message, "camera": ocv.camera, "std": ocv.std,
                     "errors": _errors3(ocv.errors), "views": [n for n, _ in ocv_views]}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            cal = calibrate_images(paths, board, progress=False, image_size=size)
        res = cal.result
        out["circcal"] = {"status": "ok", "message": "", "camera": res.camera, "std": res.std,
                          "errors": _errors3(res.errors), "views": [Path(paths[i]).name for i in cal.used],
                          "failed": [[Path(r.path).name, r.reason] for r in cal.failed],
                          "per_view_mean_2d_px": [e["mean_2d_px"] for e in res.per_view_errors],
                          "rounds": len(cal.rounds)}
        if ocv.ok:
            out["circcal"]["vs_opencv"] = {k: projection_diff(ocv.camera, res.camera, fit=True)[k]
                                           for k in ("rms_px", "max_px")}
    except (CalibrationError, ValueError) as exc:
        cal = None
        out["circcal"] = {"status": "failed", "message": f"{type(exc).__name__}: {exc}"}
    times["calibrate"] = time.perf_counter() - t0

    # The board's shape estimated as well (object-releasing method, = cv2.calibrateCameraRO): circcal's loop on its
    # stored detections (what calibrate_images(refine_board=True) does), and the same solver on OpenCV's centres.
    t0 = time.perf_counter()
    cal_r = None
    if cal is not None:
        try:
            cal_r = _circcal_without(cal.detections, cal.used, board, size, refine_board=True)
            out["circcal_refined"] = _refined_entry(cal_r, [Path(paths[i]).name for i in cal.used])
        except (CalibrationError, ValueError) as exc:
            out["circcal_refined"] = {"status": "failed", "message": f"{type(exc).__name__}: {exc}"}
    else:
        out["circcal_refined"] = {"status": "failed", "message": "circcal found no calibration to refine"}
    # circcal's final centres (NaN where a point was missed) give the point order for OpenCV's views
    ours = {} if cal is None else {Path(paths[i]).name: c for i, c in zip(cal.used, cal.centres)}
    ocv_ordered, labels = match_views([c for _, c in ocv_views], [ours.get(n) for n, _ in ocv_views], board)
    flipped = [lab != "rot0" for lab in labels]
    ocv_r = None
    try:
        ocv_r = calibrate([pts] * len(ocv_ordered), ocv_ordered, size, refine_board=True)
        out["opencv_refined"] = _refined_entry(ocv_r, [n for n, _ in ocv_views])
        if cal_r is not None:
            out["opencv_refined"]["board_vs_circcal_max_mm"] = float(np.max(np.abs(ocv_r.board_points
                                                                                    - cal_r.board_points)))
            out["opencv_refined"]["vs_circcal"] = {k: projection_diff(cal_r.camera, ocv_r.camera, fit=True)[k]
                                                   for k in ("rms_px", "max_px")}
    except (CalibrationError, ValueError) as exc:
        out["opencv_refined"] = {"status": "failed", "message": f"{type(exc).__name__}: {exc}"}
    out["opencv_refined"]["reversed"] = [n for (n, _), f in zip(ocv_views, flipped) if f]
    out["opencv_refined"]["unmatched"] = [n for n, _ in ocv_views if n not in ours]
    if any(flipped):
        # what refining in findCirclesGrid's own order gives: points of different views mixed up
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                own = calibrate([pts] * len(ocv_views), [c for _, c in ocv_views], size, refine_board=True)
            out["opencv_refined"]["own_order"] = {"status": "ok", "errors": _errors3(own.errors)}
        except (CalibrationError, ValueError) as exc:
            out["opencv_refined"]["own_order"] = {"status": "failed", "message": f"{type(exc).__name__}: {exc}"}
    # findCirclesGrid as the OpenCV adapter runs it (plain first, CALIB_CB_CLUSTERING only where that fails): the
    # two modes may order a symmetric grid differently, so its views can disagree among themselves. Refining the
    # board in that order mixes up points; in circcal's order it does not.
    if board.layout == "symmetric" and ours:
        det = OpenCVCalibrator().detect(paths, board)
        names = [Path(paths[i]).name for i in det["views"]]
        ordered, labels = match_views(det["image_points"], [ours.get(n) for n in names], board)
        rev = [lab != "rot0" for lab in labels]
        fo: dict[str, Any] = {"views": names, "how": [det["how"][i] for i in det["views"]],
                              "reversed": [n for n, f in zip(names, rev) if f]}
        if len(names) >= 3:
            for key, views in (("refined_own_order", det["image_points"]), ("refined_circcal_order", ordered)):
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", RuntimeWarning)
                        r = calibrate([pts] * len(views), views, size, refine_board=True)
                    fo[key] = {"status": "ok", "errors": _errors3(r.errors)}
                except (CalibrationError, ValueError) as exc:
                    fo[key] = {"status": "failed", "message": f"{type(exc).__name__}: {exc}"}
        out["findcirclesgrid_order"] = fo
    times["calibrate_refined"] = time.perf_counter() - t0

    if heldout:
        t0 = time.perf_counter()
        ho: dict[str, Any] = {}
        if cal is not None and len(cal.used) >= 4:
            for key, refine in (("circcal", False), ("circcal_refined", True)):
                if refine and cal_r is None:
                    continue
                per = []
                for k in tqdm(cal.used, desc=f"held-out {key} {folder.name[:24]}", unit="view",
                              disable=not progress):
                    keep = [i for i in cal.used if i != k]
                    try:
                        r = _circcal_without(cal.detections, keep, board, size, refine_board=refine)
                        o, c = _finite(recorrect(cal.detections[k], board, r.camera), pts)
                        e = error_stats(_pnp_residual(r.board_lookup(o), c, r.camera))
                        per.append({"view": Path(paths[k]).name, **_errors3(e)})
                    except (CalibrationError, ValueError) as exc:
                        per.append({"view": Path(paths[k]).name, "failed": f"{type(exc).__name__}: {exc}"})
                ho[key] = per
        if ocv.ok and len(ocv_views) >= 4:
            per = []
            for k, (name, c) in enumerate(ocv_views):
                keep = [c2 for j, (_, c2) in enumerate(ocv_views) if j != k]
                r = OpenCVCalibrator().calibrate_observations([pts] * len(keep), keep, size)
                if not r.ok:
                    per.append({"view": name, "failed": r.message})
                    continue
                per.append({"view": name, **_errors3(error_stats(_pnp_residual(pts, c, r.camera)))})
            ho["opencv"] = per
        if ocv_r is not None and len(ocv_ordered) >= 4:
            per = []
            for k, (name, _) in enumerate(ocv_views):
                keep = [c2 for j, c2 in enumerate(ocv_ordered) if j != k]
                try:
                    r = calibrate([pts] * len(keep), keep, size, refine_board=True)
                    e = error_stats(_pnp_residual(r.board_lookup(pts), ocv_ordered[k], r.camera))
                    per.append({"view": name, **_errors3(e)})
                except (CalibrationError, ValueError) as exc:
                    per.append({"view": name, "failed": f"{type(exc).__name__}: {exc}"})
            ho["opencv_refined"] = per
        out["heldout"] = {k: _mean_of_views(per) for k, per in ho.items()}
        times["heldout"] = time.perf_counter() - t0
    return out, times


def realdata_study(cfg: ReportConfig, *, progress: bool = True) -> tuple[dict, dict]:
    out, times = {}, {}
    root = REALDATA.resolve()
    for name in cfg.realdata:
        folder = root / name
        if not folder.is_dir():
            out[name] = {"folder": name, "circcal": {"status": "missing", "message": f"{folder} not found"}}
            continue
        out[name], times[name] = realdata_set(folder, heldout=cfg.heldout, progress=progress)
    return out, times


# ----------------------------------------------------------------------------------------------------------------
# environment and the whole computation
# ----------------------------------------------------------------------------------------------------------------

def environment() -> dict[str, Any]:
    """Library versions and machine (no clock)."""
    import importlib

    vers: dict[str, str] = {"python": platform.python_version()}
    for mod, attr in (("numpy", "__version__"), ("scipy", "__version__"), ("cv2", "__version__"),
                      ("torch", "__version__"), ("kornia", "__version__"), ("pycolmap", "__version__"),
                      ("matplotlib", "__version__")):
        try:
            vers["opencv" if mod == "cv2" else mod] = str(getattr(importlib.import_module(mod), attr))
        except Exception as exc:  # noqa: BLE001
            vers[mod] = f"unavailable ({type(exc).__name__})"
    try:
        from circcal.validators import registry

        m = registry.get("mrcal")
        ok, why = m.available()
        vers["mrcal"] = m.version if ok else f"unavailable ({why})"
    except Exception as exc:  # noqa: BLE001
        vers["mrcal"] = f"unavailable ({type(exc).__name__}: {exc})"
    try:
        from importlib.metadata import version

        vers["circcal"] = version("circcal")
    except Exception:  # noqa: BLE001
        vers["circcal"] = "?"
    return {"versions": vers, "platform": platform.platform(), "machine": platform.machine(),
            "cpu_count": os.cpu_count()}


def compute(cfg: ReportConfig = FULL, *, progress: bool = True) -> dict[str, Any]:
    """Every number of the report (JSON-ready). ``result["timings"]`` holds run times (s) and is the only part that
    changes from run to run; :func:`write_report` keeps it out of ``report.json``."""
    timings: dict[str, Any] = {}
    t0 = time.perf_counter()
    paper, timings["paper"] = paper_conditions(cfg, progress=progress)
    cb, timings["checkerboard"] = checkerboard_conditions(cfg, progress=progress)
    bias, timings["bias"] = bias_study(cfg, progress=progress)
    real, timings["realdata"] = realdata_study(cfg, progress=progress)
    timings["total_compute_s"] = time.perf_counter() - t0
    for c in paper.values():
        for ch in c["checks"]:
            # Agreement values of 1e-12..1e-6 px move between runs (threaded reductions in the solvers) and a
            # passing check's note says which side of the px bound it landed: keep them only when a check fails.
            ch["value"] = _quantise(ch["value"], CHECK_QUANTUM)
            if ch["passed"]:
                ch.pop("value")
                ch.pop("note")
    numbers = _round_sig(jsonable({"config": asdict(cfg), "paper": paper, "checkerboard": cb,
                                    "paper_published": PAPER_PUBLISHED, "bias": bias, "realdata": real,
                                    "environment": environment()}))
    numbers["precision"] = (f"floats rounded to {SIG_DIGITS} significant digits; agreement-check values to "
                            f"{CHECK_QUANTUM:g} px and kept only for failed checks (they move between runs at "
                            f"the 1e-7 px level)")
    numbers["timings"] = jsonable(timings)
    return numbers


#: report.json precision: enough for every comparison made, coarse enough that run-to-run jitter of the references
#: (pycolmap's Ceres solve differs ~1e-11 relative between runs; its agreement with circcal, ~2e-8 px, by percent)
#: does not change the published numbers.
SIG_DIGITS = 6
CHECK_QUANTUM = 1e-7


def _quantise(v: Any, q: float) -> Any:
    if isinstance(v, (float, np.floating)) and np.isfinite(v):
        return float(np.round(float(v) / q) * q)
    return v


def _round_sig(x: Any, sig: int = SIG_DIGITS) -> Any:
    """Floats in a JSON tree rounded to ``sig`` significant digits."""
    if isinstance(x, dict):
        return {k: _round_sig(v, sig) for k, v in x.items()}
    if isinstance(x, list):
        return [_round_sig(v, sig) for v in x]
    if isinstance(x, float):
        return float(f"{x:.{sig}g}")
    return x


# ----------------------------------------------------------------------------------------------------------------
# figures (matplotlib, Agg; byte-stable PNGs)
# ----------------------------------------------------------------------------------------------------------------

def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"figure.dpi": 100, "savefig.dpi": 110, "font.size": 9, "svg.hashsalt": "circcal"})
    return plt


def _save(fig, path: Path) -> None:
    fig.savefig(path, format="png", metadata={"Software": None}, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)


def _nan(v: Any) -> float:
    return float("nan") if v is None else float(v)


def fig_per_view(results: dict, path: Path) -> str:
    """Per-view mean 2-D reprojection error, circcal vs the OpenCV circle pipeline, one panel per condition."""
    plt = _plt()
    conds = list(results["paper"])
    fig, axes = plt.subplots(len(conds), 1, figsize=(8.5, 2.3 * len(conds) + 0.4), squeeze=False)
    for ax, c in zip(axes[:, 0], conds):
        rows = results["paper"][c]["rows"]
        n = results["paper"][c]["n_views"]
        x = np.arange(n)
        for k, (key, colour, dx) in enumerate((("circcal", "tab:blue", -0.2), ("opencv-pipeline", "tab:orange", 0.2))):
            r = rows.get(key, {})
            vals = np.full(n, np.nan)
            for v, e in zip(r.get("views") or [], r.get("per_view_mean_2d_px") or []):
                vals[v] = _nan(e)
            mean = (r.get("errors") or {}).get("mean_2d_px")
            lab = f"{r.get('label', key)} (mean {_nan(mean):.4f} px)"
            ax.bar(x + dx, vals, width=0.4, color=colour, label=lab)
            for v in np.flatnonzero(~np.isfinite(vals)):
                ax.text(v + dx, 0, "x", ha="center", va="bottom", color=colour, fontsize=8)
        ax.set_title(f"paper fixture, {c} illumination")
        ax.set_ylabel("mean 2-D error [px]")
        ax.set_xticks(x)
        ax.set_xticklabels([f"{i}" for i in x])
        ax.legend(loc="upper right", fontsize=7)
        ax.grid(axis="y", alpha=0.3)
    axes[-1, 0].set_xlabel("view index (x = view not used)")
    fig.suptitle("Per-view reprojection error (the paper's Tables 2, 4, 6; mean of |residual|, eq. 22)")
    fig.tight_layout()
    _save(fig, path)
    return "Per-view mean 2-D reprojection error of circcal and the OpenCV circle pipeline (findCirclesGrid + "\
           "calibrateCamera), one panel per illumination condition."


def fig_bias(results: dict, path: Path) -> str:
    """Centre error against tilt (largest dot size) and against dot size (largest tilt)."""
    plt = _plt()
    b = results["bias"]
    tilts, diams = np.array(b["tilts_deg"]), np.array(b["diameters_px"])
    series = (("perfect_centroid", "perfect blob centroid (area centroid)", "k", "--", None),
              ("opencv", "OpenCV findCirclesGrid (SimpleBlobDetector, sized)", "tab:orange", "-", "s"),
              ("circcal_nomodel", "circcal detector, no model (perspective only)", "tab:green", ":", "^"),
              ("circcal", "circcal detector, with the lens model", "tab:blue", "-", "o"))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))

    def arr(k):
        return np.array([[_nan(v) for v in row] for row in b["mean_2d_px"][k]])

    floor = 1e-4
    for key, lab, col, ls, mk in series:
        a = np.maximum(arr(key), floor)
        axes[0].plot(tilts, a[:, -1], color=col, ls=ls, marker=mk, label=lab)
        axes[1].plot(diams, a[-1, :], color=col, ls=ls, marker=mk, label=lab)
    axes[0].set_xlabel("board tilt [deg]")
    axes[0].set_title(f"vs tilt, dots {diams[-1]:g} px across")
    axes[1].set_xlabel("dot diameter at the board centre [px]")
    axes[1].set_title(f"vs dot size, tilt {tilts[-1]:g} deg")
    for ax in axes:
        ax.set_yscale("log")
        ax.set_ylabel("mean centre error vs true projection [px]")
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=2, bbox_to_anchor=(0.5, -0.13))
    fig.suptitle(f"Centre bias on clean renders (7x7 dots, f {b['camera']['fx']:g} px, k1 {b['camera']['dist'][0]:g}; "
                 f"blur 0.7 px, 8-bit; values below {floor:g} px drawn at {floor:g})")
    fig.tight_layout()
    _save(fig, path)
    return ("Centre error of each detector against the exact projection of the true circle centre on clean renders. "
            "The dashed line is what a perfect blob detector reports (the exact area centroid of the projected, "
            "distorted dot): the bias that no amount of image quality removes from centroid-based detectors.")


def fig_bias_grid(results: dict, path: Path) -> str:
    """Mean centre error over the whole tilt x dot-size grid, circcal vs OpenCV vs perfect centroid."""
    plt = _plt()
    b = results["bias"]
    tilts, diams = b["tilts_deg"], b["diameters_px"]
    keys = (("circcal", "circcal (with model)"), ("opencv", "OpenCV findCirclesGrid"),
            ("perfect_centroid", "perfect blob centroid"))
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    vals = [np.array([[_nan(v) for v in row] for row in b["mean_2d_px"][k]]) for k, _ in keys]
    top = np.nanmax([np.nanmax(v) for v in vals if np.isfinite(v).any()])
    from matplotlib.colors import LogNorm

    norm = LogNorm(vmin=1e-3, vmax=max(top, 1e-2))
    for ax, (k, lab), v in zip(axes, keys, vals):
        im = ax.imshow(np.maximum(v, 1e-3), origin="lower", aspect="auto", norm=norm, cmap="viridis")
        for i in range(v.shape[0]):
            for j in range(v.shape[1]):
                ax.text(j, i, "n/a" if not np.isfinite(v[i, j]) else f"{v[i, j]:.3f}", ha="center", va="center",
                        fontsize=6, color="w")
        ax.set_xticks(range(len(diams)))
        ax.set_xticklabels([f"{d:g}" for d in diams])
        ax.set_yticks(range(len(tilts)))
        ax.set_yticklabels([f"{t:g}" for t in tilts])
        ax.set_xlabel("dot diameter [px]")
        ax.set_ylabel("tilt [deg]")
        ax.set_title(lab)
    fig.colorbar(im, ax=list(axes), label="mean centre error [px]")
    _save(fig, path)
    return "Mean centre error over the whole tilt x dot-size grid (numbers in px)."


def fig_heatmaps(results: dict, path: Path, condition: str) -> str:
    """Projection difference to the true camera over the image, one panel per calibrator."""
    from circcal.validators.compare import projection_diff

    plt = _plt()
    rows = results["paper"][condition]["rows"]
    truth = _truth_camera(results)
    panels = [(rows.get("circcal"), "circcal"), (rows.get("opencv-pipeline"), "OpenCV circle pipeline"),
              (rows.get("mrcal-default"), "mrcal [default] on circcal's centres")]
    cb = results["checkerboard"].get(condition)
    if cb is not None:
        panels.append((cb, "OpenCV checkerboard"))
    panels = [(r, t) for r, t in panels if r is not None and r.get("camera")]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.3 * len(panels), 3.1), squeeze=False)
    for ax, (r, title) in zip(axes[0], panels):
        d = projection_diff(truth, Camera.from_dict(r["camera"]), fit=True)
        nx = 60
        ny = len(d["uv"]) // nx
        u = d["uv"][:, 0].reshape(ny, nx)
        v = d["uv"][:, 1].reshape(ny, nx)
        z = d["diff"].reshape(ny, nx)
        cs = ax.contourf(u, v, z, levels=12, cmap="magma")
        ax.set_xlim(0, truth.width - 1)
        ax.set_ylim(truth.height - 1, 0)
        ax.set_aspect("equal")
        ax.set_title(f"{title}\nRMS {d['rms_px']:.3f} px, max {d['max_px']:.3f} px", fontsize=8)
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
        fig.colorbar(cs, ax=ax, label="|projection - truth| [px]", shrink=0.8)
    fig.suptitle(f"Projection difference to the true camera ({condition} illumination; implied rotation fitted)")
    fig.tight_layout()
    _save(fig, path)
    return (f"Where each model is wrong ({condition}): the 2-D difference between projecting through the calibrated "
            "and the true camera, over a 60-wide grid of the image, with the implied rotation fitted "
            "(mrcal's projection_diff idea). Each panel has its own colour scale.")


def fig_truth_bars(results: dict, path: Path) -> str:
    """Residual (what calibrators report) beside error against truth (what matters), per condition."""
    plt = _plt()
    conds = list(results["paper"])
    keys = [("circcal", "circcal", "tab:blue"), ("opencv-pipeline", "OpenCV circles", "tab:orange"),
            ("mrcal-default", "mrcal [default]", "tab:purple"), ("checkerboard", "OpenCV checkerboard", "tab:gray")]
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    x = np.arange(len(conds))
    w = 0.8 / len(keys)
    for k, (key, lab, col) in enumerate(keys):
        res, tru = [], []
        for c in conds:
            r = results["checkerboard"].get(c, {}) if key == "checkerboard" else results["paper"][c]["rows"].get(key, {})
            res.append(_nan((r.get("errors") or {}).get("mean_2d_px")))
            tru.append(_nan((r.get("vs_truth") or {}).get("rms_px")))
        axes[0].bar(x + (k - 1.5) * w, res, w, color=col, label=lab)
        axes[1].bar(x + (k - 1.5) * w, tru, w, color=col, label=lab)
    for ax, t, yl in ((axes[0], "what the calibrator reports: mean 2-D residual", "mean 2-D residual [px]"),
                      (axes[1], "what matters: projection error vs the true camera", "RMS projection difference [px]")):
        ax.set_xticks(x)
        ax.set_xticklabels(conds)
        ax.set_xlabel("illumination condition")
        ax.set_ylabel(yl)
        ax.set_title(t)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    _save(fig, path)
    return ("A low residual does not prove the bias is gone: left, the residual each calibrator reports; right, its "
            "error against the true camera on the same images.")


def fig_realdata_board(results: dict, path: Path) -> str:
    """The refined board of each real set against the nominal one: out-of-plane deviation dz as colour at the
    nominal (x, y) of each point, the in-plane deviation (dx, dy) as arrows (exaggerated), the gauge points marked."""
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D

    plt = _plt()
    sets = [(n, s) for n, s in results["realdata"].items() if _g(s, "circcal_refined", "board", "deviation_mm")]
    fig, axes = plt.subplots(1, len(sets), figsize=(5.6 * len(sets), 4.6), squeeze=False)
    for ax, (name, s) in zip(axes[0], sets):
        bd = s["circcal_refined"]["board"]
        nom, dev, std = (np.array(bd[k], dtype=np.float64) for k in ("nominal_mm", "deviation_mm", "std_mm"))
        zmax = max(float(np.max(np.abs(dev[:, 2]))), 1e-6)
        sc = ax.scatter(nom[:, 0], nom[:, 1], c=dev[:, 2], s=110, cmap="RdBu_r", edgecolors="0.3", linewidths=0.4,
                        norm=Normalize(-zmax, zmax), zorder=2)
        pitch = float(s["board"]["pitch_mm"])
        dxy = float(np.max(np.linalg.norm(dev[:, :2], axis=1)))
        # arrows: the largest in-plane deviation drawn 0.8 pitch long; the key shows a round length at that scale
        gain = 0.8 * pitch / max(dxy, 1e-9)
        key = float(f"{dxy:.1g}")
        q = ax.quiver(nom[:, 0], nom[:, 1], dev[:, 0], dev[:, 1], angles="xy", scale_units="xy", scale=1.0 / gain,
                      width=0.005, color="k", zorder=3)
        ax.quiverkey(q, 0.62, -0.21, key, f"{key:g} mm in plane", labelpos="E",
                     coordinates="axes", fontproperties={"size": 7})
        full = np.all(std == 0, axis=1)
        zonly = (std[:, 2] == 0) & ~full
        ax.scatter(nom[full, 0], nom[full, 1], s=260, marker="s", facecolors="none", edgecolors="k", linewidths=1.2,
                   zorder=4)
        ax.scatter(nom[zonly, 0], nom[zonly, 1], s=260, marker="D", facecolors="none", edgecolors="k",
                   linewidths=1.2, zorder=4)
        ax.set_aspect("equal")
        ax.invert_yaxis()
        ax.margins(0.08)
        ax.set_xlabel("board x [mm]")
        ax.set_ylabel("board y [mm]")
        ax.set_title(f"{name}\nlargest deviation {bd['max_abs_dev_mm']:.2f} mm (one coordinate),\n"
                     f"{bd['max_dev_over_median_std']:.0f}x the median sigma of {bd['median_std_mm']:.3f} mm",
                     fontsize=8)
        fig.colorbar(sc, ax=ax, label="dz, out of the board plane [mm]", shrink=0.85)
        ax.legend(handles=[Line2D([], [], marker="s", ls="", mfc="none", mec="k", label="held in x, y, z (gauge)"),
                           Line2D([], [], marker="D", ls="", mfc="none", mec="k", label="held in z (gauge)"),
                           Line2D([], [], marker=r"$\rightarrow$", ls="", color="k", markersize=10,
                                  label=f"in-plane deviation, drawn x{gain:.0f}")],
                  fontsize=7, loc="upper left", bbox_to_anchor=(-0.02, -0.15), ncol=1, frameon=False)
    fig.suptitle("Real photographs: the printed board as circcal estimates it (refine_board), against the nominal "
                 "board", fontsize=9)
    fig.tight_layout()
    _save(fig, path)
    return ("The board points as circcal estimates them on each real set (board refined), against the nominal board: "
            "colour = out-of-plane deviation dz, arrows = in-plane deviation (dx, dy), exaggerated by the factor in "
            "the legend. Deviations are in the frame fixed by the three gauge points (held at their nominal positions: "
            "two in x, y, z, one in z; the default choice, the first point, the one farthest from it and the one "
            "farthest from their line): another choice of gauge changes the picture by a rigid motion and scale, not "
            "the shape. The median sigma is over the estimated coordinates.")


def _truth_camera(results: dict) -> Camera:
    from circcal.fixtures.scenarios import get_scenario

    return get_scenario("paper").camera


#: file name -> figure function (results, path) -> caption; tests may monkeypatch these.
FIGURES: dict[str, Callable[[dict, Path], str]] = {
    "truth_vs_residual.png": fig_truth_bars,
    "per_view_errors.png": fig_per_view,
    "bias.png": fig_bias,
    "bias_grid.png": fig_bias_grid,
}


def make_figures(results: dict, folder: Path) -> dict[str, str]:
    """Draw every figure into ``folder``; returns file name -> caption."""
    caps = {}
    for name, fn in FIGURES.items():
        caps[name] = fn(results, folder / name)
    for c in results["paper"]:
        name = f"heatmap_{c}.png"
        caps[name] = fig_heatmaps(results, folder / name, c)
    if any(_g(s, "circcal_refined", "board", "deviation_mm") for s in results["realdata"].values()):
        caps["realdata_board.png"] = fig_realdata_board(results, folder / "realdata_board.png")
    return caps


# ----------------------------------------------------------------------------------------------------------------
# document (one block list rendered to markdown and to HTML)
# ----------------------------------------------------------------------------------------------------------------

def _f(v: Any, spec: str = ".4f") -> str:
    if v is None:
        return "-"
    try:
        return format(float(v), spec) if np.isfinite(float(v)) else "-"
    except (TypeError, ValueError):
        return str(v)


ROW_ORDER = (("circcal", "own"), ("opencv-pipeline", "own"), ("opencv-fair", "circcal"), ("mrcal-fair", "circcal"),
             ("mrcal-default", "circcal"), ("kornia-fair", "circcal"), ("pycolmap-fair", "circcal"))


def _condition_table(results: dict, metric: Callable[[dict], Any], *, spec: str = ".4f",
                     published: bool = False) -> tuple[list[str], list[list[str]]]:
    conds = list(dict.fromkeys(list(results["paper"]) + list(results["checkerboard"])))
    head = ["calibrator", "detector / observations"] + conds
    rows = []
    keys = [k for k, _ in ROW_ORDER if any(k in results["paper"][c]["rows"] for c in results["paper"])]
    extra = [k for c in results["paper"] for k in results["paper"][c]["rows"] if k not in keys]
    for key in keys + sorted(set(extra)):
        first = next(results["paper"][c]["rows"][key] for c in results["paper"] if key in results["paper"][c]["rows"])
        cells = []
        for c in conds:
            r = results["paper"].get(c, {}).get("rows", {}).get(key)
            cells.append("-" if r is None else (_f(metric(r), spec) if r["status"] == "ok" else r["status"]))
        det = "own detector" if first["observations"] == "own" else "circcal's centres"
        rows.append([first["label"], f"{first['detector']} ({det})" if first["observations"] == "own" else det]
                    + cells)
    cbs = results["checkerboard"]
    if cbs:
        first = next(iter(cbs.values()))
        rows.append([first["label"], first.get("detector") or "findChessboardCorners"] +
                    ["-" if c not in cbs else (_f(metric(cbs[c]), spec) if cbs[c]["status"] == "ok" else
                                               cbs[c]["status"]) for c in conds])
    if published:
        for kind in ("circles", "checkerboard"):
            rows.append([f"Chen et al. 2023, Table 7 ({kind})", "published"] +
                        [_f(PAPER_PUBLISHED[kind].get(c), ".4f") for c in conds])
    return head, rows


def _g(d: dict | None, *keys: str) -> Any:
    for k in keys:
        if not isinstance(d, dict):
            return None
        d = d.get(k)
    return d


#: the computed rows of the real-data table: key in a real-data set's results -> label
REALDATA_ROWS = (("circcal", "circcal"), ("opencv", "OpenCV (baseline centres)"),
                 ("circcal_refined", "circcal, board refined"),
                 ("opencv_refined", "OpenCV centres (circcal's order), board refined"))


def _apart(a: float, b: float) -> float:
    """|a - b| relative to b."""
    return abs(a - b) / abs(b)


def realdata_summary(name: str, s: dict) -> str:
    """What the real-data numbers of one set show, in words, every number formatted in from ``s`` (one real-data
    set of :func:`realdata_study`). Empty when the board-refined rows are missing."""
    rc, ro = _g(s, "circcal", "errors", "rms_per_point_px"), _g(s, "opencv", "errors", "rms_per_point_px")
    fc, fo = (_g(s, "circcal_refined", "errors", "rms_per_point_px"),
              _g(s, "opencv_refined", "errors", "rms_per_point_px"))
    rb = _g(s, "baseline", "rms_per_point_px")
    if None in (rc, ro, fc, fo, rb):
        return ""
    hx = {k: _g(s, "heldout", k, "mean_of_views", "rms_per_point_px")
          for k in ("circcal", "opencv", "circcal_refined", "opencv_refined")}
    bd = _g(s, "circcal_refined", "board") or {}
    layout = _g(s, "board", "layout")
    out = []
    tie_rigid = _apart(rc, ro) < 0.03
    out.append(f"{name}: with a rigid board circcal's RMS per point is {rc:.4f} px and OpenCV's solver on the "
               f"baseline's centres gives {ro:.4f} px (stated: {rb:.4f} px): "
               + (f"the two detectors tie ({100 * _apart(rc, ro):.1f}% apart)." if tie_rigid else
                  f"circcal is {100 * _apart(rc, ro):.1f}% {'lower' if rc < ro else 'higher'}."))
    s2 = (f"With every board point's position estimated, circcal's RMS drops to {fc:.4f} px, "
          f"{rb / fc:.1f}x below the stated baseline")
    if hx["circcal"] and hx["circcal_refined"]:
        better = hx["circcal"] / hx["circcal_refined"]
        s2 += (f", and held-out views are predicted {better:.1f}x {'better' if better > 1 else 'worse'} than with the "
               f"rigid board ({hx['circcal_refined']:.4f} vs {hx['circcal']:.4f} px RMS per point)"
               + ("; a shape fitted to noise would predict them worse, not better" if better > 1 else ""))
    out.append(s2 + ".")
    tie_refined = _apart(fc, fo) < 0.03
    s3 = (f"The same solver on OpenCV's centres, in circcal's point order, gives {fo:.4f} px"
          + (f" (held-out {hx['opencv_refined']:.4f} px)" if hx["opencv_refined"] else "")
          + (f": with the same model the two detectors tie again ({100 * _apart(fc, fo):.1f}% apart"
             if tie_refined else f": {100 * _apart(fc, fo):.1f}% {'below' if fo < fc else 'above'} circcal's ("
             "the same model, different centres"))
    bvc = _g(s, "opencv_refined", "board_vs_circcal_max_mm")
    s3 += (f"; the two estimated boards agree to within {bvc:.3f} mm per coordinate)." if bvc is not None else ").")
    out.append(s3)
    if bd:
        ratio = bd["max_dev_over_median_std"]
        out.append(f"The estimated sheet departs from the nominal board by up to {bd['max_abs_dev_mm']:.2f} mm in "
                   f"one coordinate, {ratio:.0f}x the median standard deviation of a coordinate "
                   f"({bd['median_std_mm']:.3f} mm): up to {bd['max_abs_dz_mm']:.2f} mm out of plane and "
                   f"{bd['max_abs_dxy_mm']:.2f} mm in plane.")
        if tie_rigid and tie_refined and fc < 0.5 * rc and ratio > 5:
            out.append("So the residual of a rigid calibration on this set is the printed sheet's shape, not centre "
                       "detection: modelled, it leaves both detectors with the same, much smaller residual.")
    rev = _g(s, "opencv_refined", "reversed") or []
    n = len(_g(s, "opencv", "views") or [])
    flags = _g(s, "baseline", "flags") or "its flags"
    own = _g(s, "opencv_refined", "own_order", "errors", "rms_per_point_px")
    if not rev:
        out.append("The baseline's centres come in circcal's point order in every view"
                   + (" (an asymmetric grid has no 180-degree ambiguity)." if layout == "asymmetric" else "."))
    elif len(rev) == n:
        out.append(f"The baseline's findCirclesGrid centres ({flags}) come in the reverse of circcal's point order in "
                   f"all {n} views: a consistent relabelling of the board"
                   + (f", harmless (refined in their own order: {own:.4f} px)." if own is not None else "."))
    else:
        out.append(f"The baseline's findCirclesGrid centres ({flags}) are reversed against circcal's point order in "
                   f"{len(rev)} of {n} views" + (f"; refined in that order: {own:.4f} px." if own is not None else "."))
    fg = s.get("findcirclesgrid_order")
    if fg and fg.get("views"):
        k, m = len(fg["reversed"]), len(fg["views"])
        ncl = sum("clustering" in h for h in fg["how"])
        o1 = _g(fg, "refined_own_order", "errors", "rms_per_point_px")
        o2 = _g(fg, "refined_circcal_order", "errors", "rms_per_point_px")
        txt = (f"findCirclesGrid as circcal's OpenCV adapter runs it (plain, CALIB_CB_CLUSTERING only where that "
               f"fails: {ncl} of {m} views) ")
        if 0 < k < m:
            txt += (f"reverses {k} of {m} views against circcal's order: the 180-degree ambiguity resolved "
                    "differently per image. A rigid board hides that (each pose absorbs it); a refined board does "
                    "not")
            txt += (f": {o1:.4f} px in findCirclesGrid's order against {o2:.4f} px in circcal's."
                    if None not in (o1, o2) else ".")
        else:
            txt += "orders all views consistently" + (" (all reversed against circcal's order)." if k else ".")
        out.append(txt)
    return " ".join(out)


def document(results: dict, captions: dict[str, str], header: str) -> list[tuple]:
    """The report as blocks: ("h", level, text) | ("p", text) | ("ul", [items]) | ("table", head, rows) |
    ("img", file, caption) | ("pre", text)."""
    B: list[tuple] = []
    cfg = results["config"]
    B.append(("h", 1, "circcal comparison report"))
    B.append(("p", header))
    B.append(("p", "Every reprojection error names its convention: mean 2-D = mean of |residual| (the paper's eq. 22, "
                   "used in its tables, ~1.253 sigma for per-axis noise sigma); RMS per point = OpenCV's "
                   "calibrateCamera RMS (~1.414 sigma); RMS per coordinate = mrcal's (~sigma). 'vs truth' = RMS over "
                   "a 60-wide pixel grid of the projection difference between the calibrated and the true camera "
                   "(implied rotation fitted, as mrcal.projection_diff); 'centre error' = detected centres (corners "
                   "for the checkerboard) against the exact projections of the true ones. Rendered fixtures: the "
                   "`paper` scenario (Chen et al. 2023's setup: 7x7 dots of 5 mm at 10 mm pitch, 1920x1080, "
                   f"fx 4900 px) and `paper-checkerboard` (12x9 squares of 14 mm); {cfg['n_views'] or 14} views each. "
                   "References marked 'circcal's centres' fit exactly circcal's final centres (rounded to float32, "
                   "OpenCV's input type), so their residuals and their error against truth measure the solver, "
                   "not the detector."))
    if cfg["name"] != "full":
        B.append(("p", f"This is a reduced ({cfg['name']}) run: conditions {', '.join(cfg['conditions'])}, "
                       f"{cfg['n_views']} views, a {len(cfg['bias_tilts_deg'])}x{len(cfg['bias_diameters_px'])} bias "
                       "grid. Not the published numbers."))

    B.append(("h", 2, "1. The paper's Table 7 on rendered fixtures"))
    B.append(("h", 3, "Mean reprojection error, mean 2-D (the paper's convention), px"))
    B.append(("table", *_condition_table(results, lambda r: _g(r, "errors", "mean_2d_px"), published=True)))
    B.append(("p", "The paper's own numbers come from real photographs of its boards, ours from renders of the "
                   "same geometry: compare orders of magnitude and rankings, not digits. Our renders carry little "
                   "noise, so the residual mostly shows the detector's bias that the model could not absorb."))
    B.append(("h", 3, "OpenCV's RMS per point, px"))
    B.append(("table", *_condition_table(results, lambda r: _g(r, "errors", "rms_per_point_px"))))
    B.append(("h", 3, "Against ground truth: RMS projection difference to the true camera, px (rotation fitted)"))
    B.append(("table", *_condition_table(results, lambda r: _g(r, "vs_truth", "rms_px"))))
    B.append(("h", 3, "Against ground truth: max projection difference to the true camera, px (rotation fitted)"))
    B.append(("table", *_condition_table(results, lambda r: _g(r, "vs_truth", "max_px"))))
    B.append(("h", 3, "Against ground truth: detector centre error, mean 2-D, px"))
    B.append(("table", *_condition_table(results, lambda r: _g(r, "centre_error", "mean_2d_px"))))
    B.append(("img", "truth_vs_residual.png", captions.get("truth_vs_residual.png", "")))
    notes = []
    for c, pc in results["paper"].items():
        for key, r in pc["rows"].items():
            if r["status"] != "ok" or r.get("message"):
                what = "note" if r["status"] == "ok" else r["status"]
                notes.append(f"{c}: {r['label']}: {what}{': ' + r['message'] if r.get('message') else ''}")
        for name, why in pc.get("failed_images") or []:
            notes.append(f"{c}: circcal left out {name}: {why}")
        for ch in pc["checks"]:
            if not ch["passed"]:
                notes.append(f"{c}: check failed: {ch['name']}: {_f(ch['value'], '.3g')} (bound {_f(ch['bound'], 'g')})"
                             f"{' - ' + ch['note'] if ch.get('note') else ''}")
    for c, r in results["checkerboard"].items():
        if r["status"] != "ok" or r.get("message"):
            notes.append(f"{c}: checkerboard: {r['status']}{': ' + r['message'] if r.get('message') else ''}")
    if notes:
        B.append(("p", "Notes (failures, notes from the references, left-out views, agreement checks of `circcal validate` "
                       "that did not pass):"))
        B.append(("ul", notes))

    B.append(("h", 2, "2. Per-view errors (the paper's Tables 2, 4, 6)"))
    B.append(("img", "per_view_errors.png", captions.get("per_view_errors.png", "")))

    b = results["bias"]
    B.append(("h", 2, "3. Centre bias against tilt and dot size"))
    B.append(("p", f"Clean renders (blur 0.7 px, 8-bit, no noise) of a 7x7 grid of dots at {BIAS_PITCH_MM:g} mm pitch, "
                   f"centred on the principal point {b['distance_mm']:.0f} mm away, tilted about an axis "
                   f"{b['tilt_axis_deg']:g} deg from the image x axis; camera 1280x960, f 1500 px, k1 -0.1, k2 0.05. "
                   "circcal's detector is shown given the true lens model (what calibrate_images converges to, as it "
                   "re-corrects every centre under its current estimate) and without one; OpenCV's findCirclesGrid "
                   "uses a SimpleBlobDetector whose area window is fitted to the dot size."))
    B.append(("img", "bias.png", captions.get("bias.png", "")))
    tilts, diams = b["tilts_deg"], b["diameters_px"]
    head = ["tilt [deg]", "dot [px]", "circcal (model)", "circcal (no model)", "OpenCV blob", "perfect centroid",
            "circcal max", "OpenCV max"]
    rows = []
    for i, t in enumerate(tilts):
        for j, d in enumerate(diams):
            m, x = b["mean_2d_px"], b["max_2d_px"]
            rows.append([f"{t:g}", f"{d:g}", _f(m["circcal"][i][j]), _f(m["circcal_nomodel"][i][j]),
                         _f(m["opencv"][i][j]), _f(m["perfect_centroid"][i][j]), _f(x["circcal"][i][j]),
                         _f(x["opencv"][i][j])])
    B.append(("p", "Mean (and max) centre error over the 49 dots, px:"))
    B.append(("table", head, rows))
    B.append(("img", "bias_grid.png", captions.get("bias_grid.png", "")))
    if b.get("notes"):
        B.append(("ul", b["notes"]))

    B.append(("h", 2, "4. Where each model is wrong: projection difference to the truth"))
    B.append(("p", "References in 'fair' mode on circcal's centres (OpenCV, mrcal, kornia, pycolmap) land within "
                   "1e-5 px of circcal's model and are not drawn separately."))
    for c in results["paper"]:
        B.append(("img", f"heatmap_{c}.png", captions.get(f"heatmap_{c}.png", "")))

    B.append(("h", 2, "5. Parameters (+- one stated standard deviation)"))
    for c, pc in results["paper"].items():
        B.append(("h", 3, f"{c} illumination"))
        truth = _truth_camera(results)
        cols = [("circcal", pc["rows"].get("circcal")), ("OpenCV circles", pc["rows"].get("opencv-pipeline")),
                ("mrcal [default]", pc["rows"].get("mrcal-default")),
                ("OpenCV checkerboard", results["checkerboard"].get(c))]
        cols = [(n, r) for n, r in cols if r is not None and r.get("camera")]
        head = ["param", "truth"] + [n for n, _ in cols]
        rows = []
        tv = truth.intrinsics
        for k, p in enumerate(PARAM_NAMES):
            line = [p, _f(tv[k], ".6g")]
            for _, r in cols:
                val = Camera.from_dict(r["camera"]).intrinsics[k]
                s = (r.get("std") or {}).get(p)
                line.append(f"{_f(val, '.6g')} +- {_f(s, '.2g')}" if s is not None else _f(val, ".6g"))
            rows.append(line)
        B.append(("table", head, rows))

    B.append(("h", 2, "6. Real photographs"))
    B.append(("p", "Two public sets (BoofCV-Data, CC BY 4.0, Sony DSC-HX5V, 640x480 JPEG): no ground truth, so the "
                   "comparison is with OpenCV's baseline (findCirclesGrid with CALIB_CB_CLUSTERING + calibrateCamera; "
                   "its centres are re-fitted here with the same OpenCV solver, which reproduces its stated RMS). "
                   "Held-out prediction: for each view, calibrate on all the others (circcal: its full "
                   "calibrate / re-correct loop on the remaining views), then take the held-out view's centres "
                   "(circcal: re-corrected under the model that never saw that view), fit only its 6-DoF pose with "
                   "solvePnP (IPPE, then Levenberg-Marquardt) holding the intrinsics, and measure the residual of the "
                   "projected board points. Each detector is scored on its own centres, so a shared bias is not "
                   "caught by this test either; it does measure how well the intrinsics predict a view they were not "
                   "fitted to. Rows marked 'board refined' also estimate the 3-D position of every board point "
                   "(the object-releasing method of Strobl & Hirzinger 2011, the same minimum as "
                   "cv2.calibrateCameraRO; `calibrate_images(refine_board=True)`), three points held to fix the "
                   "board's frame and scale: circcal on its own centres, and the same solver on the baseline's "
                   "findCirclesGrid centres, each view put into circcal's point order (reversed where that matches "
                   "circcal's centres better: a symmetric grid's 180-degree ambiguity). Their held-out views are "
                   "predicted with the refined board points of the model that never saw them."))
    head = ["set", "board", "calibrator", "status", "views", "mean 2-D", "RMS/point", "RMS/coord",
            "held-out mean 2-D", "held-out RMS/point", "fx", "fy", "cx", "cy", "k1"]
    rows = []
    real_notes = []
    for name, s in results["realdata"].items():
        bd = s.get("board") or {}
        btxt = (f"{bd.get('rows')}x{bd.get('cols')} {bd.get('layout')}, {_f(bd.get('pitch_mm'), 'g')} mm pitch, "
                f"{_f(bd.get('diameter_mm'), 'g')} mm dots") if bd else "-"
        for who, label in REALDATA_ROWS:
            r = s.get(who) or {}
            e = r.get("errors") or {}
            ho = _g(s, "heldout", who, "mean_of_views") or {}
            cam = r.get("camera") or {}
            rows.append([name, btxt, label, r.get("status", "-"), str(len(r.get("views") or [])),
                         _f(e.get("mean_2d_px")), _f(e.get("rms_per_point_px")), _f(e.get("rms_per_coord_px")),
                         _f(ho.get("mean_2d_px")), _f(ho.get("rms_per_point_px")), _f(cam.get("fx"), ".2f"),
                         _f(cam.get("fy"), ".2f"), _f(cam.get("cx"), ".2f"), _f(cam.get("cy"), ".2f"),
                         _f((cam.get("dist") or [None])[0], ".4f")])
            if r.get("status") not in (None, "ok"):
                real_notes.append(f"{name}: {label} {r.get('status')}: {r.get('message')}")
        if s.get("baseline"):
            rows.append([name, btxt, f"OpenCV {s['baseline']['opencv_version']} baseline as published", "stated",
                         str(s["baseline"].get("used") or "-"), "-", _f(s["baseline"]["rms_per_point_px"]), "-", "-",
                         "-", _f(s["baseline"]["camera_matrix"][0][0], ".2f"),
                         _f(s["baseline"]["camera_matrix"][1][1], ".2f"), _f(s["baseline"]["camera_matrix"][0][2], ".2f"),
                         _f(s["baseline"]["camera_matrix"][1][2], ".2f"), _f(s["baseline"]["dist"][0], ".4f")])
        vo = _g(s, "circcal", "vs_opencv")
        if vo:
            real_notes.append(f"{name}: circcal's model vs OpenCV's, projection difference (rotation fitted): RMS "
                              f"{_f(vo['rms_px'])} px, max {_f(vo['max_px'])} px")
        vo = _g(s, "opencv_refined", "vs_circcal")
        if vo:
            real_notes.append(f"{name}: board refined, circcal's model vs the one from OpenCV's centres, projection "
                              f"difference (rotation fitted): RMS {_f(vo['rms_px'])} px, max {_f(vo['max_px'])} px")
        for who, label in REALDATA_ROWS:
            for p in _g(s, "heldout", who, "per_view") or []:
                if "failed" in p:
                    real_notes.append(f"{name}: held-out {label} {p['view']}: {p['failed']}")
        for n2, why in _g(s, "circcal", "failed") or []:
            real_notes.append(f"{name}: circcal left out {n2}: {why}")
        for n2 in _g(s, "opencv_refined", "unmatched") or []:
            real_notes.append(f"{name}: OpenCV's view {n2} has no circcal view to take the point order from; kept "
                              "as detected")
    B.append(("table", head, rows))
    if real_notes:
        B.append(("ul", real_notes))
    for name, s in results["realdata"].items():
        text = realdata_summary(name, s)
        if text:
            B.append(("p", text))
    if "realdata_board.png" in captions:
        B.append(("img", "realdata_board.png", captions["realdata_board.png"]))

    B.append(("h", 2, "7. Run times and environment"))
    env = results["environment"]
    B.append(("p", f"Machine: {env['platform']} ({env['machine']}), {env['cpu_count']} CPUs. Versions: " +
              ", ".join(f"{k} {v}" for k, v in env["versions"].items()) + "."))
    tm = results.get("timings") or {}
    head = ["part", "condition / set", "what", "time [s]"]
    rows = []
    for c, d in (tm.get("paper") or {}).items():
        for k, v in d.items():
            rows.append(["paper", c, k, _f(v, ".2f")])
    for c, v in (tm.get("checkerboard") or {}).items():
        rows.append(["checkerboard", c, "detect + calibrate", _f(v, ".2f")])
    if "bias" in tm:
        rows.append(["bias", "-", "render + detect grid", _f(tm["bias"], ".2f")])
    for c, d in (tm.get("realdata") or {}).items():
        for k, v in d.items():
            rows.append(["realdata", c, k, _f(v, ".2f")])
    if "total_compute_s" in tm:
        rows.append(["total", "-", "all computation", _f(tm["total_compute_s"], ".1f")])
    B.append(("p", "Run times (wall clock, this run; they vary between runs and are not part of report.json). "
                   "'circcal' is the whole `circcal calibrate` (detection, calibration, re-correction rounds) with "
                   f"its default of detecting images in parallel, one thread per CPU ({os.cpu_count()} here); "
                   "'opencv-pipeline' is findCirclesGrid + calibrateCamera one image at a time; the 'fair' rows are "
                   "solves on circcal's centres. `make bench` compares the detectors one thread each:"))
    B.append(("table", head, rows))
    return B


def to_markdown(blocks: list[tuple]) -> str:
    out = []
    for b in blocks:
        if b[0] == "h":
            out.append("#" * b[1] + " " + b[2])
        elif b[0] == "p":
            out.append(b[1])
        elif b[0] == "ul":
            out.append("\n".join(f"- {x}" for x in b[1]))
        elif b[0] == "table":
            head, rows = b[1], b[2]
            lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
            lines += ["| " + " | ".join(str(c).replace("|", "/") for c in r) + " |" for r in rows]
            out.append("\n".join(lines))
        elif b[0] == "img":
            out.append(f"![{b[1]}]({b[1]})\n\n*{b[2]}*")
        elif b[0] == "pre":
            out.append("```\n" + b[1] + "\n```")
    return "\n\n".join(out) + "\n"


def _inline(text: str) -> str:
    t = html.escape(text)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", t)


_CSS = ("body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}"
        "table{border-collapse:collapse;margin:1em 0;font-size:0.85em}td,th{border:1px solid #ccc;padding:3px 7px;"
        "text-align:right}td:first-child,th:first-child,td:nth-child(2){text-align:left}th{background:#f2f2f2}"
        "img{max-width:100%}figure{margin:1em 0}figcaption{font-style:italic;font-size:0.9em}"
        "code{background:#f4f4f4;padding:0 3px}")


def to_html(blocks: list[tuple], folder: Path) -> str:
    """Self-contained HTML: figures embedded as base64 data URIs from ``folder``."""
    out = ["<!DOCTYPE html>", "<html lang=\"en\"><head><meta charset=\"utf-8\">",
           "<title>circcal comparison report</title>", f"<style>{_CSS}</style></head><body>"]
    for b in blocks:
        if b[0] == "h":
            out.append(f"<h{b[1]}>{_inline(b[2])}</h{b[1]}>")
        elif b[0] == "p":
            out.append(f"<p>{_inline(b[1])}</p>")
        elif b[0] == "ul":
            out.append("<ul>" + "".join(f"<li>{_inline(x)}</li>" for x in b[1]) + "</ul>")
        elif b[0] == "table":
            head, rows = b[1], b[2]
            t = ["<table><thead><tr>" + "".join(f"<th>{_inline(h)}</th>" for h in head) + "</tr></thead><tbody>"]
            t += ["<tr>" + "".join(f"<td>{_inline(str(c))}</td>" for c in r) + "</tr>" for r in rows]
            out.append("\n".join(t) + "</tbody></table>")
        elif b[0] == "img":
            data = base64.b64encode((folder / b[1]).read_bytes()).decode("ascii")
            out.append(f"<figure><img alt=\"{html.escape(b[1])}\" src=\"data:image/png;base64,{data}\">"
                       f"<figcaption>{_inline(b[2])}</figcaption></figure>")
        elif b[0] == "pre":
            out.append(f"<pre>{html.escape(b[1])}</pre>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"


# ----------------------------------------------------------------------------------------------------------------
# writing
# ----------------------------------------------------------------------------------------------------------------

def headline(results: dict) -> str:
    """One paragraph with the headline numbers (for reports/README.md)."""
    parts = []
    for c, pc in results["paper"].items():
        cc = pc["rows"].get("circcal", {})
        oc = pc["rows"].get("opencv-pipeline", {})
        parts.append(f"{c}: circcal mean 2-D residual {_f(_g(cc, 'errors', 'mean_2d_px'))} px, error vs truth "
                     f"{_f(_g(cc, 'vs_truth', 'rms_px'))} px (OpenCV circles {_f(_g(oc, 'errors', 'mean_2d_px'))} / "
                     f"{_f(_g(oc, 'vs_truth', 'rms_px'))} px")
        cb = results["checkerboard"].get(c)
        if cb:
            parts[-1] += f", checkerboard {_f(_g(cb, 'errors', 'mean_2d_px'))} / {_f(_g(cb, 'vs_truth', 'rms_px'))} px"
        parts[-1] += ")"
    b = results["bias"]
    try:
        i, j = len(b["tilts_deg"]) - 1, len(b["diameters_px"]) - 1
        parts.append(f"bias at {b['tilts_deg'][i]:g} deg tilt, {b['diameters_px'][j]:g} px dots: circcal "
                     f"{_f(b['mean_2d_px']['circcal'][i][j])} px vs OpenCV {_f(b['mean_2d_px']['opencv'][i][j])} px "
                     f"(perfect centroid {_f(b['mean_2d_px']['perfect_centroid'][i][j])} px)")
    except (IndexError, KeyError, TypeError):
        pass
    for name, s in results["realdata"].items():
        cc = s.get("circcal") or {}
        if cc.get("status") == "ok":
            txt = (f"{name}: circcal RMS {_f(_g(cc, 'errors', 'rms_per_point_px'))} px vs OpenCV baseline "
                   f"{_f(_g(s, 'baseline', 'rms_per_point_px'))} px")
            if _g(s, "circcal_refined", "status") == "ok":
                txt += (f", board refined {_f(_g(s, 'circcal_refined', 'errors', 'rms_per_point_px'))} px (OpenCV's "
                        f"centres refined {_f(_g(s, 'opencv_refined', 'errors', 'rms_per_point_px'))} px)")
            txt += (f"; held-out mean 2-D {_f(_g(s, 'heldout', 'circcal', 'mean_of_views', 'mean_2d_px'))} vs "
                    f"{_f(_g(s, 'heldout', 'opencv', 'mean_of_views', 'mean_2d_px'))} px")
            if _g(s, "heldout", "circcal_refined"):
                txt += f", board refined {_f(_g(s, 'heldout', 'circcal_refined', 'mean_of_views', 'mean_2d_px'))} px"
            parts.append(txt)
        else:
            parts.append(f"{name}: circcal {cc.get('status')}: {cc.get('message')}")
    return "; ".join(parts) + "."


def write_report(results: dict, out_dir: str | Path, *, name: str = "latest", header: str | None = None) -> Path:
    """Write ``out_dir/name/`` (index.md, index.html, *.png, report.json, timings.json) atomically, then update
    ``out_dir/README.md``. ``report.json`` holds every number except run times (deterministic)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    final = out_dir / name
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    if header is None:
        header = (f"Generated {date} by `circcal report{' --quick' if results['config']['name'] == 'quick' else ''}` "
                  f"({results['config']['name']} run).")
    with atomic.folder(final) as tmp:
        numbers = {k: v for k, v in results.items() if k != "timings"}
        (tmp / "report.json").write_text(json.dumps(numbers, indent=1, sort_keys=True) + "\n")
        (tmp / "timings.json").write_text(json.dumps({"date": date, "timings": results.get("timings")}, indent=1)
                                          + "\n")
        captions = make_figures(results, tmp)
        blocks = document(results, captions, header)
        (tmp / "index.md").write_text(to_markdown(blocks))
        (tmp / "index.html").write_text(to_html(blocks, tmp))
    readme = ("# circcal comparison reports\n\n"
              "Generated by `circcal report` (`validators/report.py`): circcal against OpenCV, mrcal, kornia, pycolmap "
              "and a checkerboard on rendered fixtures with ground truth (the paper's Table 7 setup) and on real "
              "photographs. Each run folder holds `index.md`, a self-contained `index.html`, the figures and "
              "`report.json` (every number; run times in `timings.json`).\n\n"
              "| run | date | kind | headline |\n|---|---|---|---|\n"
              f"| [{name}/]({name}/index.md) ([html]({name}/index.html)) | {date} | {results['config']['name']} | "
              f"{headline(results)} |\n")
    atomic.write_text(out_dir / "README.md", readme)
    return final


def generate(out: str | Path = "reports", *, quick: bool = False, progress: bool = True,
             config: ReportConfig | None = None) -> Path:
    """Compute and write the report into ``out/latest``; returns that folder."""
    cfg = config or (QUICK if quick else FULL)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        results = compute(cfg, progress=progress)
    return write_report(results, out)
