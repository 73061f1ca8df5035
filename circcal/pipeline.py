"""The detect -> calibrate -> re-correct pipeline: images in, a calibrated model out.

:func:`calibrate_images` detects the board in every image (:mod:`circcal.detector`), calibrates
(:func:`circcal.solver.calibrate`), re-corrects every centre under the current model (perspective and distortion,
:func:`circcal.detector.recorrect`) and recalibrates until no centre moves more than ``tol_px``;
:func:`calibrate_detections` is that loop on detections already made.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from circcal import detector as det_mod
from circcal.solver import CalibrationError, CalibrationResult, calibrate

__all__ = ["ImagesCalibration", "calibrate_images", "calibrate_detections"]



@dataclass
class ImagesCalibration:
    """Outcome of :func:`calibrate_images`. ``result``: the final model; ``paths``: all inputs; ``detections``:
    one per path (``circcal.detector.Detection``); ``used``: indices of the paths in the model (the views of
    ``result``, in order); ``failed``: (path, reason) for every image left out; ``rounds``: per calibration round
    ``{"round", "rms_per_point_px", "rms_per_coord_px", "mean_2d_px", "max_center_shift_px"}``; ``centers``: the
    final (re-corrected) centres of each used view, (N, 2) px in board order, NaN where a point was not detected."""

    result: CalibrationResult
    paths: list[str]
    detections: list[Any]
    used: list[int]
    failed: list[tuple[str, str]]
    rounds: list[dict] = field(default_factory=list)
    centers: list[np.ndarray] = field(default_factory=list)

    def observations(self, board) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """(object_points, image_points) per used view: the final centres with their board points (finite only),
        exactly what the final model was fitted to."""
        pairs = [_points_of(c, board.object_points()) for c in self.centers]
        return [o for o, _ in pairs], [p for _, p in pairs]


def _points_of(centers: np.ndarray, board_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep the detected (finite) centres with their object points; a detector marks missing points with NaN."""
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    if len(c) != len(board_points):
        raise ValueError(f"detector returned {len(c)} centres for a board of {len(board_points)} points")
    ok = np.all(np.isfinite(c), axis=1)
    return board_points[ok], c[ok]


def calibrate_images(
    paths: Sequence[str | Path],
    board,
    *,
    fix_k3: bool = False,
    fix_tangential: bool = False,
    fix_aspect_ratio: bool = False,
    fix_principal_point: bool = False,
    refine_board: bool = False,
    max_rounds: int = 6,
    tol_px: float = 1e-4,
    progress: bool = True,
    image_size: tuple[int, int] | None = None,
    jobs: int | None = None,
) -> ImagesCalibration:
    """Detect the board in every image, calibrate, then re-correct every centre under the current model
    (perspective and distortion aware, ``circcal.detector.recorrect``) and recalibrate, until no centre moves more than
    ``tol_px`` (typically 2-3 rounds) or ``max_rounds`` calibrations were made.

    ``board``: :class:`circcal.board.Board`. ``refine_board``: estimate the board's 3-D shape as well (see
    :func:`calibrate`). ``jobs``: images detected at once (``circcal.detector.detect_files``; None = one per CPU, the
    result does not depend on it). Images where the board is not found are left out and listed in
    ``failed`` with the detector's reason. Raises :class:`CalibrationError` when fewer than 3 images remain.
    """
    import cv2

    paths = [str(p) for p in paths]
    if not paths:
        raise ValueError("no images given")
    detections = det_mod.detect_files(paths, board, camera=None, progress=progress, jobs=jobs)
    failed: list[tuple[str, str]] = []
    used: list[int] = []
    for i, d in enumerate(detections):
        if d.found and d.centers is not None:
            used.append(i)
        else:
            failed.append((paths[i], d.reason or "board not found"))
    if image_size is None:
        sizes = set()
        for i in used:
            size = getattr(detections[i], "image_size", None)
            if size is None:
                im = cv2.imread(paths[i], cv2.IMREAD_UNCHANGED)
                if im is None:
                    raise FileNotFoundError(f"cannot read image {paths[i]}")
                size = (im.shape[1], im.shape[0])
            sizes.add((int(size[0]), int(size[1])))
        if len(sizes) > 1:
            raise CalibrationError(f"images differ in size {sorted(sizes)}: one calibration needs one camera mode")
        image_size = sizes.pop() if sizes else (0, 0)
    if len(used) < 3:
        raise CalibrationError(
            f"the board was found in {len(used)} of {len(paths)} images; calibration needs at least 3"
            + "".join(f"\n  {p}: {r}" for p, r in failed))
    opts = dict(fix_k3=fix_k3, fix_tangential=fix_tangential, fix_aspect_ratio=fix_aspect_ratio,
                fix_principal_point=fix_principal_point, refine_board=refine_board)
    result, centers, rounds = calibrate_detections([detections[i] for i in used], board, image_size,
                                                   max_rounds=max_rounds, tol_px=tol_px, **opts)
    result.view_names = [Path(paths[i]).name for i in used]
    return ImagesCalibration(result, paths, detections, used, failed, rounds, centers)


def calibrate_detections(
    detections: Sequence[Any],
    board,
    image_size: tuple[int, int],
    *,
    max_rounds: int = 6,
    tol_px: float = 1e-4,
    **options: Any,
) -> tuple[CalibrationResult, list[np.ndarray], list[dict]]:
    """The loop of :func:`calibrate_images` on detections already made (``circcal.detector.Detection``, one per view,
    all found): calibrate, re-correct every centre under the current model (``circcal.detector.recorrect``), recalibrate,
    until no centre moves more than ``tol_px`` or ``max_rounds`` calibrations were made (then a RuntimeWarning).
    ``options`` go to :func:`calibrate`. Returns ``(result, centers, rounds)`` as :class:`ImagesCalibration` holds
    them. Reused for held-out checks: the detector runs without a model, so detections do not depend on other views.
    """
    board_pts = board.object_points()
    centers = [np.asarray(d.centers, dtype=np.float64) for d in detections]
    pairs = [_points_of(c, board_pts) for c in centers]
    result = calibrate([o for o, _ in pairs], [p for _, p in pairs], image_size, **options)
    stats = ("rms_per_point_px", "rms_per_coord_px", "mean_2d_px")
    rounds = [{"round": 0, **{k: result.errors[k] for k in stats}, "max_center_shift_px": float("nan")}]
    for r in range(1, max_rounds):
        new = [np.asarray(det_mod.recorrect(d, board, result.camera), dtype=np.float64) for d in detections]
        shift = max(float(np.nanmax(np.linalg.norm(a - b, axis=1))) for a, b in zip(new, centers))
        centers = new
        pairs = [_points_of(c, board_pts) for c in centers]
        result = calibrate([o for o, _ in pairs], [p for _, p in pairs], image_size, initial=result.camera,
                           **options)
        rounds.append({"round": r, **{k: result.errors[k] for k in stats}, "max_center_shift_px": shift})
        if shift < tol_px:
            break
    else:
        if max_rounds > 1:
            warnings.warn(f"centre re-correction did not settle below {tol_px:g} px in {max_rounds} rounds "
                          f"(last shift {rounds[-1]['max_center_shift_px']:.3g} px)", RuntimeWarning, stacklevel=3)
    return result, centers, rounds
