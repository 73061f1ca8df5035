"""The real photographs (one folder per set under :func:`circcal.report.config.realdata_root`): circcal against the
set's OpenCV baseline (its findCirclesGrid centres, re-fitted here with OpenCV's solver so all three conventions and
the held-out test use one solver), with a rigid board and with every board point's position estimated
(``refine_board``: circcal on its own centres, and the same solver on the baseline's centres put into circcal's
point order with :func:`circcal.analysis.compare.match_views`).

Lengths in mm, errors in px; views are named by their image file.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

from circcal.board import Board
from circcal.errors import InputError
from circcal.report.config import REALDATA_ENV, ReportConfig, realdata_root
from circcal.report.heldout import heldout_block
from circcal.report.results import error_summary, failure

__all__ = ["board_block", "realdata_board", "realdata_entry", "realdata_set", "refined_entry"]

#: Spacing units of an ``opencv_baseline.json``, in mm.
_UNIT_MM = {"metres": 1000.0, "meters": 1000.0, "mm": 1.0, "millimetres": 1.0}


def realdata_board(folder: Path) -> tuple[Board, dict[str, Any]]:
    """The board of a real-data folder and its OpenCV baseline.

    Grid and spacing from ``opencv_baseline.json``, dot diameter from ``SOURCE.txt`` ("diameter <x> cm").

    Parameters
    ----------
    folder : Path

    Returns
    -------
    board : circcal.board.Board
        Lengths in mm.
    baseline : dict
        ``opencv_baseline.json``'s content.

    Raises
    ------
    ValueError
        ``SOURCE.txt`` states no dot diameter.
    """
    base = json.loads((folder / "opencv_baseline.json").read_text())
    m = re.search(r"diameter\s+([0-9.]+)\s*cm", (folder / "SOURCE.txt").read_text())
    if m is None:
        raise ValueError(f"{folder / 'SOURCE.txt'} states no dot diameter ('diameter <x> cm')")
    cols, rows = base["pattern_size_cols_rows"]
    unit = _UNIT_MM[base.get("spacing_units", "metres")]
    board = Board(
        int(rows),
        int(cols),
        float(base["spacing_s"]) * unit,
        float(m.group(1)) * 10.0,
        "asymmetric" if base["grid"].startswith("asym") else "symmetric",
    )
    return board, base


def board_block(res: Any) -> dict[str, Any]:
    """The refined board of a calibration.

    Parameters
    ----------
    res : circcal.solver.CalibrationResult
        A board-refined result.

    Returns
    -------
    dict
        Nominal points, the refined ones' deviations from them and their standard deviations (mm), the gauge, and how
        far the sheet is from the nominal board (``max_abs_dev_mm``: the largest deviation of one coordinate;
        ``max_abs_dxy_mm``: the largest in-plane displacement; ``median_std_mm``: over the estimated coordinates, the
        held ones left out).
    """
    dev = res.board_points - res.board_nominal
    std = res.board_std
    med = float(np.median(std[std > 0]))
    top = float(np.max(np.abs(dev)))
    # deviations, not positions: report.json keeps 6 significant digits, 1e-3 mm on a 200 mm coordinate
    return {
        "nominal_mm": res.board_nominal,
        "deviation_mm": dev,
        "std_mm": std,
        "gauge": [int(i) for i in res.board_gauge],
        "max_abs_dev_mm": top,
        "max_abs_dz_mm": float(np.max(np.abs(dev[:, 2]))),
        "max_abs_dxy_mm": float(np.max(np.linalg.norm(dev[:, :2], axis=1))),
        "median_std_mm": med,
        "max_dev_over_median_std": top / med,
    }


def refined_entry(res: Any, views: list[str]) -> dict[str, Any]:
    """A board-refined calibration as an entry: model, errors, per-view mean 2-D error and :func:`board_block`.

    Parameters
    ----------
    res : circcal.solver.CalibrationResult
    views : list of str
        The views' image names.

    Returns
    -------
    dict
    """
    return {
        "status": "ok",
        "message": "",
        "camera": res.camera,
        "std": res.std,
        "errors": error_summary(res.errors),
        "views": views,
        "per_view_mean_2d_px": [e["mean_2d_px"] for e in res.per_view_errors],
        "board": board_block(res),
    }


def _refined_errors(views: list[np.ndarray], board: Board, size: tuple[int, int]) -> dict[str, Any]:
    """The reprojection errors of :func:`circcal.solver.calibrate` with the board refined on ``views`` (each (N, 2)
    px in ``board``'s point order, as given)."""
    from circcal.solver import CalibrationOptions, calibrate

    try:
        r = calibrate([board.object_points()] * len(views), views, size, CalibrationOptions(refine_board=True))
    except InputError as exc:
        return failure(exc)
    return {"status": "ok", "errors": error_summary(r.errors)}


def _baseline_entry(base: dict[str, Any]) -> dict[str, Any]:
    """What the baseline file states: its RMS per point (px), OpenCV version, flags, views used and model."""
    return {
        "rms_per_point_px": base["rms_px"],
        "opencv_version": base["opencv_version"],
        "flags": base.get("findCirclesGrid_flags"),
        "used": base.get("used_for_calibration"),
        "camera_matrix": base["camera_matrix"],
        "dist": base["dist_k1k2p1p2k3"],
    }


def _opencv_rigid(base: dict[str, Any], board: Board, size: tuple[int, int]) -> tuple[list, Any, dict[str, Any]]:
    """OpenCV's solver on the baseline's own findCirclesGrid centres: ((image name, (N, 2) px) per found view, the
    :class:`~circcal.validators.reference_result.ReferenceResult`, its entry)."""
    from circcal.validators.opencv import OpenCVCalibrator

    views = [
        (pi["image"], np.asarray(pi["centers"], dtype=np.float64).reshape(-1, 2))
        for pi in base["per_image"]
        if pi.get("found")
    ]
    ocv = OpenCVCalibrator().calibrate_observations([board.object_points()] * len(views), [c for _, c in views], size)
    return (
        views,
        ocv,
        {
            "status": ocv.status,
            "message": ocv.message,
            "camera": ocv.camera,
            "std": ocv.std,
            "errors": error_summary(ocv.errors),
            "views": [n for n, _ in views],
        },
    )


def _circcal_rigid(paths: list[str], board: Board, size: tuple[int, int], ocv: Any) -> tuple[Any, dict[str, Any]]:
    """circcal's whole loop on the images (:func:`circcal.pipeline.calibrate_images`): (the
    :class:`~circcal.pipeline.ImagesCalibration` or None, its entry, with the projection difference to OpenCV's
    model)."""
    from circcal.analysis.compare import projection_diff
    from circcal.pipeline import calibrate_images

    try:
        cal = calibrate_images(paths, board, progress=False, image_size=size)
    except InputError as exc:
        return None, failure(exc)
    res = cal.result
    entry = {
        "status": "ok",
        "message": "",
        "camera": res.camera,
        "std": res.std,
        "errors": error_summary(res.errors),
        "views": [Path(paths[i]).name for i in cal.used],
        "failed": [[Path(r.path).name, r.reason] for r in cal.failed],
        "per_view_mean_2d_px": [e["mean_2d_px"] for e in res.per_view_errors],
        "rounds": len(cal.rounds),
    }
    if ocv.ok:
        d = projection_diff(ocv.camera, res.camera, fit=True)
        entry["vs_opencv"] = {k: d[k] for k in ("rms_px", "max_px")}
    return cal, entry


def _circcal_refined(cal: Any, board: Board, size: tuple[int, int]) -> tuple[Any, dict[str, Any]]:
    """circcal's loop on its stored detections with the board refined (what ``calibrate_images(refine_board=True)``
    does, without detecting again): (the result or None, its entry)."""
    from circcal.pipeline import calibrate_detections
    from circcal.solver import CalibrationOptions

    if cal is None:
        return None, {"status": "failed", "message": "circcal found no calibration to refine"}
    try:
        res = calibrate_detections(
            [cal.detections[i] for i in cal.used], board, size, CalibrationOptions(refine_board=True)
        )[0]
    except InputError as exc:
        return None, failure(exc)
    return res, refined_entry(res, [Path(cal.paths[i]).name for i in cal.used])


def _opencv_refined(
    ocv_views: list, ours: dict[str, np.ndarray], board: Board, size: tuple[int, int], cal_r: Any
) -> tuple[Any, list[np.ndarray], dict[str, Any]]:
    """The same solver, board refined, on the baseline's centres put into circcal's point order: (the result or
    None, the re-ordered views, the entry: which views were reversed, which had no circcal view to take the order
    from, and how the estimated board and model compare with circcal's)."""
    from circcal.analysis.compare import match_views, projection_diff
    from circcal.solver import CalibrationOptions, calibrate

    ordered, labels = match_views([c for _, c in ocv_views], [ours.get(n) for n, _ in ocv_views], board)
    pts = board.object_points()
    res = None
    try:
        res = calibrate([pts] * len(ordered), ordered, size, CalibrationOptions(refine_board=True))
    except InputError as exc:
        entry = failure(exc)
    else:
        entry = refined_entry(res, [n for n, _ in ocv_views])
        if cal_r is not None:
            entry["board_vs_circcal_max_mm"] = float(np.max(np.abs(res.board_points - cal_r.board_points)))
            d = projection_diff(cal_r.camera, res.camera, fit=True)
            entry["vs_circcal"] = {k: d[k] for k in ("rms_px", "max_px")}
    entry["reversed"] = [n for (n, _), lab in zip(ocv_views, labels) if lab != "rot0"]
    entry["unmatched"] = [n for n, _ in ocv_views if n not in ours]
    if entry["reversed"]:
        # what refining in findCirclesGrid's own order gives: points of different views mixed up
        entry["own_order"] = _refined_errors([c for _, c in ocv_views], board, size)
    return res, ordered, entry


def _findcirclesgrid_order(
    paths: list[str], board: Board, ours: dict[str, np.ndarray], size: tuple[int, int]
) -> dict[str, Any]:
    """findCirclesGrid as the OpenCV adapter runs it (plain first, CALIB_CB_CLUSTERING only where that fails): the
    two modes may order a symmetric grid differently, so its views can disagree among themselves. Refining the
    board in that order mixes up points; in circcal's order it does not."""
    from circcal.analysis.compare import match_views
    from circcal.observations import MIN_VIEWS
    from circcal.validators.opencv import OpenCVCalibrator

    det = OpenCVCalibrator().detect(paths, board)
    names = [Path(paths[i]).name for i in det["views"]]
    ordered, labels = match_views(det["image_points"], [ours.get(n) for n in names], board)
    out: dict[str, Any] = {
        "views": names,
        "how": [det["how"][i] for i in det["views"]],
        "reversed": [n for n, lab in zip(names, labels) if lab != "rot0"],
    }
    if len(names) >= MIN_VIEWS:
        out["refined_own_order"] = _refined_errors(det["image_points"], board, size)
        out["refined_circcal_order"] = _refined_errors(ordered, board, size)
    return out


def realdata_set(folder: Path, *, heldout: bool = True) -> tuple[dict[str, Any], dict[str, float]]:
    """Every number of one real-data set, and the run times of its parts.

    Parameters
    ----------
    folder : Path
        The set's folder.
    heldout : bool
        Run the held-out loops.

    Returns
    -------
    numbers : dict
    timings : dict of str to float
        s.
    """
    board, base = realdata_board(folder)
    size = tuple(int(v) for v in base["image_size_wh"])
    paths = sorted(str(p) for p in folder.glob("*.jpg"))
    out: dict[str, Any] = {
        "folder": folder.name,
        "board": board.to_dict(),
        "image_size": list(size),
        "n_images": len(paths),
        "baseline": _baseline_entry(base),
    }
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    ocv_views, ocv, out["opencv"] = _opencv_rigid(base, board, size)
    cal, out["circcal"] = _circcal_rigid(paths, board, size, ocv)
    times["calibrate"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    cal_r, out["circcal_refined"] = _circcal_refined(cal, board, size)
    # circcal's final centres (NaN where a point was missed) give the point order for OpenCV's views
    ours = {} if cal is None else {Path(paths[i]).name: c for i, c in zip(cal.used, cal.centres)}
    ocv_r, ocv_ordered, out["opencv_refined"] = _opencv_refined(ocv_views, ours, board, size, cal_r)
    if board.layout == "symmetric" and ours:
        out["findcirclesgrid_order"] = _findcirclesgrid_order(paths, board, ours, size)
    times["calibrate_refined"] = time.perf_counter() - t0

    if heldout:
        t0 = time.perf_counter()
        out["heldout"] = heldout_block(
            cal,
            board,
            size,
            refined=cal_r is not None,
            opencv_views=ocv_views,
            opencv_ok=ocv.ok,
            opencv_ordered=ocv_ordered if ocv_r is not None else None,
        )
        times["heldout"] = time.perf_counter() - t0
    return out, times


def realdata_entry(name: str, cfg: ReportConfig) -> tuple[dict[str, Any], dict[str, float]]:
    """:func:`realdata_set` on a named set under :func:`~circcal.report.config.realdata_root`.

    Parameters
    ----------
    name : str
    cfg : ReportConfig

    Returns
    -------
    numbers : dict
        Or a "missing" entry saying where it was looked for.
    timings : dict of str to float
        s.
    """
    folder = realdata_root() / name
    if not folder.is_dir():
        why = f"{folder} not found (set {REALDATA_ENV} to the folder of real photographs)"
        return {"folder": name, "circcal": {"status": "missing", "message": why}}, {}
    return realdata_set(folder, heldout=cfg.heldout)
