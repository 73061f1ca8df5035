"""The observations every reference calibrator fits: circcal's final centres, rounded to float32, and circcal's own
solver run once more on exactly those points (what each reference is compared with).

Why the rounding: OpenCV takes float32 points only, and on a weakly conditioned problem (k3 at a long focal length)
that rounding alone moves the answer by ~5e-3 px at the image corners. So every solver gets the same rounded points,
and the identical-observations agreement (1e-6 px) is measured against circcal's solver on those, not against the
model circcal fitted to its float64 centres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from circcal.solver import CalibrationOptions, CalibrationResult, calibrate

__all__ = ["SharedObservations", "share", "ssr"]


def ssr(residuals: list[np.ndarray] | None) -> float:
    """Sum of squared residuals over every view.

    Parameters
    ----------
    residuals : list of ndarray, shape (N_v, 2), or None
        Residuals per view, px.

    Returns
    -------
    float
        px^2; NaN for none. NaN entries (points a reference dropped as outliers) make it NaN: such a cost is not
        comparable with a plain least-squares one.
    """
    if not residuals:
        return float("nan")
    return float(sum(np.sum(np.asarray(r, dtype=np.float64) ** 2) for r in residuals))


@dataclass
class SharedObservations:
    """The observations every reference fits, and circcal's solve on them.

    Attributes
    ----------
    object_points : list of ndarray, shape (N_v, 3)
        Board points per view, mm, float32-rounded and back to float64.
    image_points : list of ndarray, shape (N_v, 2)
        Centres per view, px, float32-rounded and back to float64.
    image_size : tuple of int
        (W, H) px.
    result : circcal.solver.CalibrationResult
        circcal's solver on exactly these points, started from circcal's final model.
    ssr : float
        Its sum of squared residuals, px^2.
    """

    object_points: list[np.ndarray]
    image_points: list[np.ndarray]
    image_size: tuple[int, int]
    result: CalibrationResult

    @property
    def ssr(self) -> float:
        return ssr(self.result.residuals)


def share(cal: Any, board: Any, options: CalibrationOptions | None = None) -> SharedObservations:
    """The shared observations of an images calibration.

    Parameters
    ----------
    cal : circcal.pipeline.ImagesCalibration
        A finished calibration.
    board : circcal.board.Board
        Its board.
    options : CalibrationOptions or None
        The calibration's options (its held parameters, board refinement, lens model), for circcal's solve on the
        shared points; outlier rejection is not repeated (the points are the final ones, outliers already out).
        None: the defaults for the calibration's lens model.

    Returns
    -------
    SharedObservations
    """
    obj, img = cal.observations(board)
    obj = [np.asarray(o, np.float32).astype(np.float64) for o in obj]
    img = [np.asarray(p, np.float32).astype(np.float64) for p in img]
    size = (cal.result.camera.width, cal.result.camera.height)
    if options is not None:
        options = options.replace(outlier_rule=None)
    return SharedObservations(obj, img, size, calibrate(obj, img, size, options, initial=cal.result.camera))
