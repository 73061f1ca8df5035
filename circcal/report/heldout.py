"""Held-out prediction on the real photographs: for each view, the model calibrated on all the others predicts it
(the view's pose fitted with the intrinsics held, :func:`circcal.solver.prediction_error`); the RMS of that residual
is what a model fitted to noise cannot fake. Every loop runs through :func:`circcal.solver.leave_one_out`: circcal's
through :func:`circcal.pipeline.holdout_detections` (its calibrate / re-correct loop on the other views, the view's
centres re-corrected under that model), OpenCV's solver on the baseline's fixed centres, and circcal's solver with
the board refined on fixed centres through :func:`circcal.solver.holdout_errors`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from circcal.board import Board
from circcal.errors import CalibrationError
from circcal.observations import MIN_VIEWS
from circcal.report.results import error_summary

__all__ = ["MIN_HELDOUT_VIEWS", "heldout_block", "mean_of_views"]

#: Views a held-out check needs: every model is fitted to all views but one, which must leave a calibration.
MIN_HELDOUT_VIEWS = MIN_VIEWS + 1

#: The conventions averaged over the held-out views.
_MEANS = ("mean_2d_px", "rms_per_point_px", "rms_per_coord_px")


def mean_of_views(per: list[dict[str, Any]]) -> dict[str, Any]:
    """Per-view held-out entries and their means.

    Parameters
    ----------
    per : list of dict
        One entry per view (a failed one has a status).

    Returns
    -------
    dict
        The per-view entries and, over the views that did not fail, the mean of each convention (px).
    """
    good = [p for p in per if "failed" not in p]
    return {
        "per_view": per,
        "mean_of_views": {m: (float(np.mean([p[m] for p in good])) if good else float("nan")) for m in _MEANS},
    }


def _named(per: list[dict[str, Any]], names: list[str]) -> list[dict[str, Any]]:
    """:func:`circcal.solver.leave_one_out`'s entries with each view's index replaced by its name, the error
    statistics cut to :data:`~circcal.report.results.ERROR_KEYS`."""
    out = []
    for p in per:
        name = names[p["view"]]
        out.append({"view": name, "failed": p["failed"]} if "failed" in p else {"view": name, **error_summary(p)})
    return out


def _opencv_heldout(views: list[tuple[str, np.ndarray]], board: Board, size: tuple[int, int]) -> list[dict]:
    """OpenCV's solver (:class:`~circcal.validators.opencv.OpenCVCalibrator`) on the baseline's fixed centres."""
    from circcal.solver import leave_one_out
    from circcal.validators.opencv import OpenCVCalibrator

    pts = board.object_points()

    def fit(rest: list[int]) -> Any:
        r = OpenCVCalibrator().calibrate_observations([pts] * len(rest), [views[i][1] for i in rest], size)
        if not r.ok:
            raise CalibrationError(r.message)
        return r.camera

    return leave_one_out(len(views), fit, lambda k, camera: (pts, views[k][1], camera))


def heldout_block(
    cal: Any,
    board: Board,
    size: tuple[int, int],
    *,
    refined: bool,
    opencv_views: list[tuple[str, np.ndarray]],
    opencv_ok: bool,
    opencv_ordered: list[np.ndarray] | None,
) -> dict[str, Any]:
    """The held-out entries of one real-data set (:func:`mean_of_views` each).

    A loop needs :data:`MIN_HELDOUT_VIEWS` views.

    Parameters
    ----------
    cal : circcal.pipeline.ImagesCalibration or None
        circcal's calibration; gives ``circcal`` and, with ``refined``, ``circcal_refined``.
    board : circcal.board.Board
    size : tuple of int
        (width, height) px.
    refined : bool
        Also run the board-refined loops.
    opencv_views : list of (str, ndarray)
        The baseline's views: (name, (N, 2) px centres).
    opencv_ok : bool
        OpenCV's solver fitted them (gives ``opencv``).
    opencv_ordered : list of ndarray or None
        Those views in circcal's point order, for ``opencv_refined`` (None when their board-refined fit failed).

    Returns
    -------
    dict
        Name -> :func:`mean_of_views` entry.
    """
    from circcal.pipeline import holdout_detections
    from circcal.solver import CalibrationOptions, holdout_errors

    per: dict[str, list[dict]] = {}
    if cal is not None and len(cal.used) >= MIN_HELDOUT_VIEWS:
        detections = [cal.detections[i] for i in cal.used]
        names = [Path(cal.paths[i]).name for i in cal.used]
        per["circcal"] = _named(holdout_detections(detections, board, size), names)
        if refined:
            per["circcal_refined"] = _named(
                holdout_detections(detections, board, size, CalibrationOptions(refine_board=True)), names
            )
    names = [n for n, _ in opencv_views]
    if opencv_ok and len(opencv_views) >= MIN_HELDOUT_VIEWS:
        per["opencv"] = _named(_opencv_heldout(opencv_views, board, size), names)
    if opencv_ordered is not None and len(opencv_ordered) >= MIN_HELDOUT_VIEWS:
        pts = [board.object_points()] * len(opencv_ordered)
        per["opencv_refined"] = _named(
            holdout_errors(pts, opencv_ordered, size, CalibrationOptions(refine_board=True)), names
        )
    return {k: mean_of_views(v) for k, v in per.items()}
