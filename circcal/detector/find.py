"""Circle-grid detection with unbiased centre projections: :func:`detect` on one image, :func:`recorrect` for
another camera model.

:func:`detect` runs, on one image:

1. grey conversion and a contrast stretch (:mod:`circcal.detector.image`), and segmentation that survives
   uneven/strong/weak illumination (:mod:`circcal.detector.segment`), on a copy shrunk to a short side of 360-719 px
   first for images of 720 px and more (full resolution when that fails, a finer scale when the dots are small; only
   the starting ellipses come from it);
2. candidate dots from contours, filtered by area (limits scaled to the image and the board's dot density),
   circularity, inertia ratio and convexity (:mod:`circcal.detector.candidates`);
3. grid recognition and ordering in OpenCV's object-point order with circcal's orientation rule
   (:mod:`circcal.detector.grid`);
4. sub-pixel edge points on each dot's boundary (half-level crossings along ellipse normals, corrected for edge
   curvature: :mod:`circcal.detector.edges`) and a direct least-squares ellipse fit
   (:mod:`circcal.detector.ellipse`), for all dots at once (:func:`~circcal.detector.dots.fit_dots`: one filtering
   call for the crops around all dots, batched interpolation, stacked 3x3 solves);
5. projective centre correction: each centre is the pole of the board's vanishing line w.r.t. its ellipse, the
   homography re-estimated from the corrected centres until stable (:mod:`circcal.detector.centre`). With a camera
   model the edge points are undistorted first, the correction runs in the undistorted image and the centres are
   distorted back.

:func:`recorrect` repeats step 5 alone for another camera model, reusing the stored edge points (what a calibrator
iterating its distortion estimate needs; ~1 ms per view).

Pixel convention: OpenCV's (integer coordinates are pixel centres); centres in OpenCV's object-point order.
"""
from __future__ import annotations

import numpy as np

from circcal.board import Board
from circcal.detector.candidates import Candidate, area_limits, find_candidates
from circcal.detector.centre import correct_centres
from circcal.detector.detection import Detection, Reason
from circcal.detector.dots import EDGE_SIGMA, fit_dots
from circcal.detector.ellipse import FIT_ERRORS, conic_from_params_batch, conic_params_batch, fit_ellipses_direct
from circcal.detector.grid import order_grid
from circcal.detector.image import as_gray, normalise_u8
from circcal.detector.segment import SHRUNK_MIN_RADIUS, segmentation_scales, segmentations, shrink, upscaled
from circcal.detector.smoothing import SmoothedImage
from circcal.errors import ImageError, InputError
from circcal.model import Camera, distort_pixels, undistort_pixels

__all__ = ["camera_size_mismatch", "detect", "recorrect"]


def camera_size_mismatch(camera: Camera | None, width: int, height: int) -> str | None:
    """Why ``camera`` cannot serve an image of ``width`` x ``height`` px (its model is for another size), or
    ``None`` when it can (or there is no camera)."""
    if camera is not None and (camera.width, camera.height) != (width, height):
        return f"camera model is for {camera.width}x{camera.height} images, image is {width}x{height}"
    return None


def _check_camera(camera: Camera | None, width: int, height: int) -> None:
    """Raise :class:`~circcal.errors.ImageError` when ``camera`` is for another image size."""
    why = camera_size_mismatch(camera, width, height)
    if why is not None:
        raise ImageError(why)


def detect(image: np.ndarray, board: Board, camera: Camera | None = None) -> Detection:
    """Find ``board``'s circle grid in ``image`` and return the images of the circle centres.

    ``image``: (H, W) grey or (H, W, 3) BGR, uint8/uint16/float; dark dots on a bright board. ``camera``: optional
    model; when given, the centre correction accounts for its lens distortion. Never raises for a grid that is not
    there (``found=False`` with a reason); raises :class:`~circcal.errors.ImageError` for an image it cannot take
    (wrong shape/dtype, camera for another image size) and :class:`~circcal.errors.InputError` for a checkerboard.
    """
    gray = as_gray(image)
    H, W = gray.shape
    _check_camera(camera, W, H)
    if board.layout == "checkerboard":
        raise InputError("circcal detect finds circle grids; the board is a checkerboard")
    cands, order, seg_name, best = _segment_and_order(gray, board)
    if order is None:
        if best < board.n_points:
            return Detection(False, None, f"grid {board.rows}x{board.cols} ({board.layout}) not found: at most "
                                          f"{best} candidate dots, {board.n_points} needed",
                             Reason.TOO_FEW_CANDIDATES, image_size=(W, H))
        return Detection(False, None, f"grid {board.rows}x{board.cols} ({board.layout}) not recognised among {best} "
                                      f"candidate dots", Reason.GRID_NOT_RECOGNISED, image_size=(W, H))
    Q0 = conic_from_params_batch(np.array([cands[i].centre for i in order]), np.array([cands[i].axes for i in order]),
                                 np.array([cands[i].angle for i in order]))
    pts, mask, conics_d, errors = fit_dots(SmoothedImage(gray, EDGE_SIGMA), Q0)
    for k, e in enumerate(errors):
        if e is not None:
            return Detection(False, None, f"dot {k} of the grid: {e}", Reason.DOT_UNMEASURABLE, image_size=(W, H),
                             candidates=np.array([c.centre for c in cands]))
    edge_points = [pts[k][mask[k]] for k in range(len(order))]
    try:
        centres, conics, Hb = _correct(edge_points, board, camera, conics_d)
    except ValueError as exc:
        return Detection(False, None, f"centre correction failed: {exc}", Reason.CENTRE_CORRECTION_FAILED,
                         edge_points=edge_points, image_size=(W, H))
    ell_c = conic_params_batch(conics_d)[0]
    return Detection(True, centres, None, edge_points=edge_points, conics=conics, ellipse_centres=ell_c,
                     homography=Hb, candidates=np.array([c.centre for c in cands]), image_size=(W, H),
                     segmentation=seg_name)


def _segment_and_order(gray: np.ndarray, board: Board
                       ) -> tuple[list[Candidate] | None, np.ndarray | None, str | None, int]:
    """Candidate dots of ``gray`` (H, W) in which ``board``'s grid is recognised, trying the segmentations at each
    scale of :func:`~circcal.detector.segment.segmentation_scales` in turn (candidates in full-image pixels).

    Returns ``(candidates, order, segmentation name, most candidates seen)``: ``order`` (N,) indexes the candidates
    in board order; ``candidates``, ``order`` and the name are ``None`` when no segmentation gave the grid. A grid of
    dots smaller than :data:`~circcal.detector.segment.SHRUNK_MIN_RADIUS` at a shrunk scale sends the search on to
    the coarsest scale where they are not."""
    H, W = gray.shape
    min_area, max_area = area_limits(board, W, H)
    best = 0
    scales = list(segmentation_scales(H, W))
    while scales:
        scale = scales.pop(0)
        # shrunk (pixel-area averaging) before the contrast stretch: the stretch then touches s^2 fewer pixels
        img = normalise_u8(gray if scale == 1 else shrink(gray, scale))
        for name, mask in segmentations(img):
            cs = find_candidates(mask, min_area=min_area / scale ** 2, max_area=max_area / scale ** 2)
            best = max(best, len(cs))
            if len(cs) < board.n_points:
                continue
            if scale != 1:
                cs = [upscaled(c, scale) for c in cs]
            pts = np.array([c.centre for c in cs])
            radii = np.array([np.sqrt(c.axes[0] * c.axes[1]) for c in cs])
            order = order_grid(board, pts, radii, (H, W))
            r_min = np.min(radii[order]) if order is not None else np.inf
            if scale != 1 and r_min < SHRUNK_MIN_RADIUS * scale:
                # small dots: their contours are worth a finer scale, the coarsest one where they are not small
                finer = max([s for s in range(2, scale) if r_min >= SHRUNK_MIN_RADIUS * s], default=1)
                scales = [finer, 1] if finer != 1 else [1]
                break
            if order is not None:
                return cs, order, name if scale == 1 else f"{name}@1/{scale}", best
    return None, None, None, best


def recorrect(detection: Detection, board: Board, camera: Camera | None) -> np.ndarray:
    """(N, 2) centres of a found ``detection`` corrected with ``camera`` (its distortion), from the stored edge
    points: undistort them, refit the ellipses, iterate homography/poles in the undistorted image, distort back."""
    if not detection.found or detection.edge_points is None:
        raise ValueError(f"cannot re-correct a detection that was not found ({detection.reason})")
    if detection.image_size is not None:
        _check_camera(camera, *detection.image_size)
    return _correct(detection.edge_points, board, camera)[0]


def _correct(edge_points: list[np.ndarray], board: Board, camera: Camera | None,
             conics: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (N, 2) in the observed image, conics (N, 3, 3) in the undistorted image, H board -> undistorted
    image, from the ``edge_points`` (N lists of (M_k, 2) px, board order, observed image). ``conics``: the ellipses
    already fitted to ``edge_points`` (observed image), reused when there is no distortion to remove. Raises
    ``ValueError`` when an ellipse cannot be fitted or no board homography fits the centres."""
    obj = board.object_points()[:, :2]
    distorted = camera is not None and np.any(camera.dist)
    if conics is None or distorted:
        counts = [len(p) for p in edge_points]
        width = max(counts) if counts else 0
        P = np.zeros((len(edge_points), width, 2))
        M = np.zeros((len(edge_points), width), bool)
        for i, p in enumerate(edge_points):
            P[i, :len(p)] = p
            M[i, :len(p)] = True
        if distorted:
            P[M] = undistort_pixels(P[M], camera)
            M &= np.isfinite(P[..., 0]) & np.isfinite(P[..., 1])
        conics, err = fit_ellipses_direct(P, M)
        if np.any(err):
            i = int(np.argmax(err != 0))
            msg = FIT_ERRORS[int(err[i])]
            raise ValueError(f"{msg}, got {int(M[i].sum())}" if err[i] == 1 else msg)
    centres, H = correct_centres(conics, obj)
    if distorted:
        centres = distort_pixels(centres, camera)
    return centres, conics, H
