"""The paper's comparison target: the rendered ``paper-checkerboard`` fixture through OpenCV's chessboard detector
and calibrateCamera, one illumination condition at a time."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from circcal.board import Board
from circcal.metrics import error_stats
from circcal.observations import MIN_VIEWS
from circcal.report.config import ReportConfig
from circcal.report.rendered import calibrator_row, load_fixture

__all__ = [
    "SUBPIX_EPS_PX",
    "SUBPIX_ITERATIONS",
    "SUBPIX_WINDOW",
    "checkerboard_condition",
    "checkerboard_label",
    "find_chessboard",
]

#: cornerSubPix search window (px, full width): OpenCV's tutorial value, which the paper's era used.
SUBPIX_WINDOW = (11, 11)
#: cornerSubPix stops after this many iterations or when a corner moves less than :data:`SUBPIX_EPS_PX`.
SUBPIX_ITERATIONS = 100
SUBPIX_EPS_PX = 1e-4


def find_chessboard(gray: np.ndarray, board: Board) -> tuple[np.ndarray | None, str]:
    """Inner corners of a checkerboard in a grey image.

    ``cv2.findChessboardCorners`` (adaptive threshold, normalised) refined by ``cv2.cornerSubPix``
    (:data:`SUBPIX_WINDOW`); ``cv2.findChessboardCornersSB`` (accuracy flag) if that fails.

    Parameters
    ----------
    gray : ndarray, shape (H, W)
        uint8.
    board : circcal.board.Board
        A checkerboard.

    Returns
    -------
    corners : ndarray, shape (N, 2), or None
        px.
    how : str
        How they were found, or why not.
    """
    import cv2

    ok, c = cv2.findChessboardCorners(
        gray, board.pattern_size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    if ok:
        c = cv2.cornerSubPix(
            gray,
            c,
            SUBPIX_WINDOW,
            (-1, -1),
            (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, SUBPIX_ITERATIONS, SUBPIX_EPS_PX),
        )
        return c.reshape(-1, 2).astype(np.float64), "findChessboardCorners+cornerSubPix"
    ok, c = cv2.findChessboardCornersSB(gray, board.pattern_size, flags=cv2.CALIB_CB_ACCURACY)
    if ok:
        return c.reshape(-1, 2).astype(np.float64), "findChessboardCornersSB"
    return None, "checkerboard not found (findChessboardCorners and findChessboardCornersSB)"


def checkerboard_label(board: Board) -> str:
    """The row label: OpenCV's version and the board as inner corners (columns x rows) and squares.

    Parameters
    ----------
    board : circcal.board.Board

    Returns
    -------
    str
    """
    import cv2

    return (
        f"OpenCV {cv2.__version__} checkerboard {board.cols}x{board.rows} corners "
        f"({board.cols + 1}x{board.rows + 1} squares)"
    )


def _corners(views: list[Any], board: Board) -> tuple[list[np.ndarray], list[int], dict[str, str], set[str]]:
    """Corners of every view: (corners per found view, their indices, image name -> why not found, how found)."""
    import cv2

    found, used, missed, hows = [], [], {}, set()
    for i, v in enumerate(views):
        c, how = find_chessboard(cv2.imread(str(v.image), cv2.IMREAD_GRAYSCALE), board)
        if c is None:
            missed[v.image.name] = how
            continue
        found.append(c)
        used.append(i)
        hows.add(how)
    return found, used, missed, hows


def _checkerboard_row(views: list[Any], truth: Any) -> dict[str, Any]:
    """The calibrator row of the views of one condition (``truth``: the fixture's truth)."""
    from circcal.analysis.compare import centre_errors
    from circcal.validators.opencv import OpenCVCalibrator

    board, cam_t = truth.board, truth.camera
    img, used, missed, hows = _corners(views, board)
    label = checkerboard_label(board)
    if len(used) < MIN_VIEWS:
        return calibrator_row(
            label,
            "failed",
            f"board found in {len(used)} of {len(views)} images: {missed}",
            None,
            None,
            None,
            cam_t,
            detector="findChessboardCorners",
        )
    res = OpenCVCalibrator().calibrate_observations(
        [board.object_points()] * len(img), img, (cam_t.width, cam_t.height)
    )
    if not res.ok:
        return calibrator_row(label, res.status, res.message, None, None, None, cam_t)
    centre = centre_errors(img, [views[i].centres for i in used], board=board)
    msg = f"missed {len(missed)} of {len(views)} views: {missed}" if missed else ""
    return calibrator_row(
        label,
        "ok",
        msg,
        res.camera,
        res.std,
        res.errors,
        cam_t,
        centre=centre["overall"],
        per_view=[error_stats(r)["mean_2d_px"] for r in res.residuals],
        views=used,
        detector=" / ".join(sorted(hows)),
        observations="own",
        centre_note="corner error vs true corners",
    )


def checkerboard_condition(variant: str, cfg: ReportConfig, *, progress: bool = True) -> tuple[dict[str, Any], float]:
    """One illumination condition of the ``paper-checkerboard`` fixture through OpenCV.

    Parameters
    ----------
    variant : str
        The condition.
    cfg : ReportConfig
    progress : bool

    Returns
    -------
    row : dict
        The calibrator row, with ``n_views`` (the views tried).
    seconds : float
        Time taken, s (rendering or loading the fixture included).
    """
    t0 = time.perf_counter()
    truth, views = load_fixture("paper-checkerboard", variant, cfg.n_views, progress)
    row = _checkerboard_row(views, truth)
    return {**row, "n_views": len(views)}, time.perf_counter() - t0
