"""Circle-grid detection with unbiased centre projections.

:func:`detect` runs, on one image:

1. grey conversion and segmentation that survives uneven/strong/weak illumination (:mod:`circcal.detector.edges`), on a
   copy shrunk to a short side of 360-719 px first for images of 720 px and more (full resolution when that fails,
   a finer scale when the dots are small; only the starting ellipses come from it);
2. candidate dots from contours, filtered by area (limits scaled to the image and the board's dot density),
   circularity, inertia ratio and convexity;
3. grid recognition and ordering in OpenCV's object-point order with circcal's orientation rule
   (:mod:`circcal.detector.grid`);
4. sub-pixel edge points on each dot's boundary (half-level crossings along ellipse normals, corrected for edge
   curvature) and a direct least-squares ellipse fit (:mod:`circcal.detector.ellipse`), for all dots at once
   (:func:`fit_dots`: one filtering call for the crops around all dots, batched interpolation, stacked 3x3
   solves);
5. projective centre correction: each centre is the pole of the board's vanishing line w.r.t. its ellipse, the
   homography re-estimated from the corrected centres until stable (:mod:`circcal.detector.centre`). With a camera model
   the edge points are undistorted first, the correction runs in the undistorted image and the centres are
   distorted back.

:func:`recorrect` repeats step 5 alone for another camera model, reusing the stored edge points (what a calibrator
iterating its distortion estimate needs; ~1 ms per view).

Pixel convention: OpenCV's (integer coordinates are pixel centres); centres in OpenCV's object-point order.
"""
from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from circcal.board import Board
from circcal.errors import ImageError, InputError
from circcal.detector.centre import correct_centres
from circcal.detector.detection import Detection, Reason
from circcal.detector.edges import (Candidate, SmoothedImage, _masked_median, as_gray, find_candidates, normalise_u8,
                    segmentations, subpixel_edge_points_batch)
from circcal.detector.ellipse import FIT_ERRORS, conic_from_params_batch, conic_params_batch, fit_ellipses_direct
from circcal.detector.grid import order_grid
from circcal.model import Camera, distort_pixels, undistort_pixels

__all__ = ["Detection", "detect", "recorrect", "detect_files", "fit_dot", "fit_dots", "area_limits"]

MIN_EDGE_POINTS = 10


def area_limits(board: Board, width: int, height: int) -> tuple[float, float]:
    """(min_area, max_area) px^2 for candidate dots, scaled to the image and the board's dot density.

    The largest dot cannot exceed 4x the area of an average dot of a board that filled the whole image
    (perspective makes near dots larger); the smallest is 1e-5 of the image (~12 px^2 at 640x480, ~21 px^2 at
    1920x1080), below which a sub-pixel boundary cannot be measured anyway (never below 12 px^2).
    """
    cell = board.pitch_mm ** 2 * (2.0 if board.layout == "asymmetric" else 1.0)
    dot_frac = np.pi * board.radius_mm ** 2 / cell
    max_area = 4.0 * dot_frac * width * height / board.n_points
    min_area = max(12.0, 1e-5 * width * height)
    return min_area, max(max_area, 4 * min_area)


EDGE_SIGMA = 1.5
"""Gaussian smoothing (px) for the edge profiles, one for all dots (so the board's window is smoothed once). 1.5 px
makes the cubic interpolation of the pixel grid accurate to ~1e-3 px even on unblurred (aliased) renders; measured
best for dots of radius 7-30 px at tilts up to 60 deg (smaller values leave interpolation error, larger ones
curvature bias). With an optical blur of ~1 px it is also near the noise-optimal (matched) smoothing."""


def fit_dot(gray: np.ndarray, Q0: np.ndarray, iterations: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel edge points and ellipse of one dot: ``(points (M, 2) px, conic (3, 3))``.

    ``Q0``: a rough ellipse (e.g. from the contour). Edge points are re-measured along the normals of the latest
    fit ``iterations`` times; points further than 4 robust sigmas (and 0.1 px) from the fit are dropped.
    Raises ``ValueError`` when the dot has too few measurable edge points. (One-dot form of :func:`fit_dots`.)
    """
    pts, mask, Q, errors = fit_dots(gray, np.asarray(Q0, np.float64)[None], iterations)
    if errors[0] is not None:
        raise ValueError(errors[0])
    return pts[0][mask[0]], Q[0]


def fit_dots(gray: np.ndarray | SmoothedImage, conics0: np.ndarray, iterations: int = 2
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str | None]]:
    """:func:`fit_dot` for all dots at once (the detector's path): rough ellipses ``conics0`` (D, 3, 3).

    ``gray``: (H, W) grey image, or a :class:`~circcal.detector.edges.SmoothedImage` of it at :data:`EDGE_SIGMA` (reused
    across calls). Returns ``(points (D, M, 2), mask (D, M), conics (D, 3, 3), errors)``: dot ``d``'s edge points
    are ``points[d][mask[d]]`` and ``conics[d]`` the ellipse fitted to exactly them; ``errors[d]`` is ``None`` or
    why the dot could not be measured (then its points and conic are not meaningful).
    """
    src = gray if isinstance(gray, SmoothedImage) else SmoothedImage(gray, EDGE_SIGMA)
    Q = np.asarray(conics0, np.float64).copy()
    D = len(Q)
    errors: list[str | None] = [None] * D
    pts = np.zeros((D, 0, 2))
    mask = np.zeros((D, 0), bool)
    for _ in range(iterations):
        act = np.array([e is None for e in errors])
        if not np.any(act):
            break
        ai = np.nonzero(act)[0]
        p_a, m_a, err_a = subpixel_edge_points_batch(src, Q[ai])
        if p_a.shape[1] != pts.shape[1]:
            width = max(p_a.shape[1], pts.shape[1])
            pts = np.concatenate([pts, np.zeros((D, width - pts.shape[1], 2))], axis=1)
            mask = np.concatenate([mask, np.zeros((D, width - mask.shape[1]), bool)], axis=1)
        pts[ai] = 0.0
        mask[ai] = False
        pts[ai, :p_a.shape[1]] = p_a
        mask[ai, :p_a.shape[1]] = m_a
        cnt = mask.sum(axis=1)
        for d, e in zip(ai, err_a):
            if e is not None:
                errors[d] = e
            elif cnt[d] < MIN_EDGE_POINTS:
                errors[d] = f"only {cnt[d]} sub-pixel edge points"
        ai = np.array([d for d in ai if errors[d] is None], int)
        if len(ai) == 0:
            break
        Qa, ferr = fit_ellipses_direct(pts[ai], mask[ai])
        # robust: Sampson distances, drop outliers once
        h = np.concatenate([pts[ai], np.ones((len(ai), pts.shape[1], 1))], axis=2)
        hQ = h @ Qa
        g = 2.0 * hQ[..., :2]
        with np.errstate(invalid="ignore", divide="ignore"):  # sums over the last axis written out (faster)
            dist = ((hQ[..., 0] * h[..., 0] + hQ[..., 1] * h[..., 1]) + hQ[..., 2] * h[..., 2]) / np.sqrt(
                g[..., 0] * g[..., 0] + g[..., 1] * g[..., 1])
        m = mask[ai] & (ferr == 0)[:, None]
        med = _masked_median(np.where(m, dist, 0.0), m)
        sdev = 1.4826 * _masked_median(np.where(m, np.abs(dist - med[:, None]), 0.0), m)
        with np.errstate(invalid="ignore"):
            keep = m & (np.abs(dist) <= np.maximum(4.0 * sdev, 0.1)[:, None])
        nk = keep.sum(axis=1)
        refit = (ferr == 0) & (nk < m.sum(axis=1)) & (nk >= MIN_EDGE_POINTS)
        if np.any(refit):
            ri = ai[refit]
            Qr, rerr = fit_ellipses_direct(pts[ri], keep[refit])
            mask[ri] = keep[refit]
            Qa[refit] = Qr
            ferr = ferr.copy()
            ferr[refit] = rerr
        for j, d in enumerate(ai):
            if ferr[j]:
                errors[d] = FIT_ERRORS[int(ferr[j])]
        Q[ai] = Qa
    return pts, mask, Q, errors


def _correct(edge_points: list[np.ndarray], board: Board, camera: Camera | None,
             conics: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (N, 2) in the observed image, conics (N, 3, 3) in the undistorted image, H board -> undistorted.
    ``conics``: the ellipses already fitted to ``edge_points`` (distorted image), reused when there is no
    distortion to remove."""
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


SHRINK_MIN_SIDE = 360
"""Segmentation starts on the image shrunk by the largest integer factor that leaves its shorter side at least this
many pixels (factor 2 from 720 px, 3 from 1080 px, ...; none below 720 px)."""
SHRUNK_MIN_RADIUS = 3.0
"""Dots smaller than this (px, in the shrunk image) are segmented again at a finer scale."""


def _segmentation_scales(height: int, width: int) -> tuple[int, ...]:
    """Image scales (1 = full, s = shrunk s times) to segment at, in order: the working scale
    ``min(H, W) // SHRINK_MIN_SIDE`` first (when at least 2; pixel-area averaging; ~ s^2 fewer pixels to filter),
    then halving it (rounded up) down to 2 (a grid of small dots in a large image) and full resolution as the
    fallbacks. The edges are always measured at full resolution, starting from these contours:
    only the starting ellipses differ between scales (on the fixtures the centres move by ~1e-4 px, up to ~1e-2 px on
    strongly blurred images, where the two-pass refinement still depends slightly on its start, with the same accuracy
    against the truth). When the dots found are smaller than :data:`SHRUNK_MIN_RADIUS` at that scale, :func:`detect`
    goes on at the coarsest scale where they are not. Setting ``SHRINK_MIN_SIDE`` above any image size restores
    full-resolution segmentation everywhere."""
    s = min(height, width) // SHRINK_MIN_SIDE
    out = [s] if s >= 2 else []
    while s > 2:
        s = (s + 1) // 2
        out.append(s)
    return (*out, 1)


def _shrink(gray: np.ndarray, scale: int) -> np.ndarray:
    """(H // s, W // s) averages of the s x s pixel blocks of ``gray`` (H, W) (float64 via float32, as :func:`as_gray`
    gives colour)."""
    Hh, W = gray.shape
    g = gray[:Hh // scale * scale, :W // scale * scale]
    if g.dtype not in (np.uint8, np.uint16, np.float32):
        g = g.astype(np.float32)
    return cv2.resize(g, (W // scale, Hh // scale), interpolation=cv2.INTER_AREA)


def _upscaled(c: Candidate, scale: int) -> Candidate:
    """A candidate found on an image shrunk ``scale`` x (pixel-area averaging) in full-image pixels. The contour
    runs through the centres of the blob's boundary pixels, ~half a pixel inside its edge at either scale: the axes
    get the difference back, so the starting ellipse is as close to the edge as one found at full resolution."""
    off = 0.5 * (scale - 1)
    return Candidate(c.centre * scale + off, (c.axes[0] * scale + off, c.axes[1] * scale + off), c.angle,
                     c.area * scale ** 2)


def _check_camera(camera: Camera | None, width: int, height: int) -> None:
    if camera is not None and (camera.width, camera.height) != (width, height):
        raise ImageError(f"camera model is for {camera.width}x{camera.height} images, image is {width}x{height}")


def detect(image: np.ndarray, board: Board, camera: Camera | None = None) -> Detection:
    """Find ``board``'s circle grid in ``image`` and return the images of the circle centres.

    ``image``: (H, W) grey or (H, W, 3) BGR, uint8/uint16/float; dark dots on a bright board. ``camera``: optional
    model; when given, the centre correction accounts for its lens distortion. Never raises for a grid that is not
    there (``found=False`` with a reason); raises ``ValueError`` for unusable input (wrong shape/dtype, camera for
    another image size).
    """
    gray = as_gray(image)
    Hh, W = gray.shape
    _check_camera(camera, W, Hh)
    if board.layout == "checkerboard":
        raise InputError("circcal detect finds circle grids; the board is a checkerboard")
    min_area, max_area = area_limits(board, W, Hh)
    best = 0
    order = cands = None
    seg_name = None
    scales = list(_segmentation_scales(Hh, W))
    while scales:
        scale = scales.pop(0)
        # shrunk (pixel-area averaging) before the contrast stretch: the stretch then touches s^2 fewer pixels
        img = normalise_u8(gray if scale == 1 else _shrink(gray, scale))
        for name, mask in segmentations(img):
            cs = find_candidates(mask, min_area=min_area / scale ** 2, max_area=max_area / scale ** 2)
            best = max(best, len(cs))
            if len(cs) < board.n_points:
                continue
            if scale != 1:
                cs = [_upscaled(c, scale) for c in cs]
            pts = np.array([c.centre for c in cs])
            radii = np.array([np.sqrt(c.axes[0] * c.axes[1]) for c in cs])
            order = order_grid(board, pts, radii, (Hh, W))
            r_min = np.min(radii[order]) if order is not None else np.inf
            if scale != 1 and r_min < SHRUNK_MIN_RADIUS * scale:
                # small dots: their contours are worth a finer scale, the coarsest one where they are not small
                order = None
                finer = max([s for s in range(2, scale) if r_min >= SHRUNK_MIN_RADIUS * s], default=1)
                scales = [finer, 1] if finer != 1 else [1]
                break
            if order is not None:
                cands, seg_name = cs, name if scale == 1 else f"{name}@1/{scale}"
                break
        if order is not None:
            break
    if order is None:
        if best < board.n_points:
            return Detection(False, None, f"grid {board.rows}x{board.cols} ({board.layout}) not found: at most "
                                          f"{best} candidate dots, {board.n_points} needed",
                             Reason.TOO_FEW_CANDIDATES, image_size=(W, Hh))
        return Detection(False, None, f"grid {board.rows}x{board.cols} ({board.layout}) not recognised among {best} "
                                      f"candidate dots", Reason.GRID_NOT_RECOGNISED, image_size=(W, Hh))
    Q0 = conic_from_params_batch(np.array([cands[i].centre for i in order]), np.array([cands[i].axes for i in order]),
                                 np.array([cands[i].angle for i in order]))
    pts, mask, conics_d, errors = fit_dots(SmoothedImage(gray, EDGE_SIGMA), Q0)
    for k, e in enumerate(errors):
        if e is not None:
            return Detection(False, None, f"dot {k} of the grid: {e}", Reason.DOT_UNMEASURABLE, image_size=(W, Hh),
                             candidates=np.array([c.centre for c in cands]))
    edge_points = [pts[k][mask[k]] for k in range(len(order))]
    try:
        centres, conics, H = _correct(edge_points, board, camera, conics_d)
    except ValueError as exc:
        return Detection(False, None, f"centre correction failed: {exc}", Reason.CENTRE_CORRECTION_FAILED,
                         edge_points=edge_points,
                         image_size=(W, Hh))
    ell_c = conic_params_batch(conics_d)[0]
    return Detection(True, centres, None, edge_points=edge_points, conics=conics, ellipse_centres=ell_c,
                     homography=H, candidates=np.array([c.centre for c in cands]), image_size=(W, Hh),
                     segmentation=seg_name)


def recorrect(detection: Detection, board: Board, camera: Camera | None) -> np.ndarray:
    """(N, 2) centres of a found ``detection`` corrected with ``camera`` (its distortion), from the stored edge
    points: undistort them, refit the ellipses, iterate homography/poles in the undistorted image, distort back."""
    if not detection.found or detection.edge_points is None:
        raise ValueError(f"cannot re-correct a detection that was not found ({detection.reason})")
    if detection.image_size is not None:
        _check_camera(camera, *detection.image_size)
    return _correct(detection.edge_points, board, camera)[0]


def _read_image(path: Path) -> np.ndarray | None:
    data = np.fromfile(str(path), dtype=np.uint8) if path.is_file() else None
    if data is None or data.size == 0:
        return None
    return cv2.imdecode(data, cv2.IMREAD_UNCHANGED)


def _detect_file(path: Path, board: Board, camera: Camera | None) -> Detection:
    """:func:`detect` on one image file. What a file can legitimately cause (missing, unreadable, undecodable, an
    image the detector cannot take) gives ``found=False`` with its :class:`Reason`; any other exception is a bug
    and propagates."""
    if not path.is_file():
        return Detection(False, None, "file not found" if not path.exists() else "not a file", Reason.FILE_NOT_FOUND)
    try:
        img = _read_image(path)
    except OSError as exc:  # permission denied, I/O error
        return Detection(False, None, f"cannot read the file: {exc.strerror or exc}", Reason.UNREADABLE)
    if img is None:
        return Detection(False, None, "unreadable file (not an image, or corrupt)", Reason.UNREADABLE)
    h, w = img.shape[:2]
    if camera is not None and (camera.width, camera.height) != (w, h):
        return Detection(False, None, f"image is {w}x{h}, the camera model is for {camera.width}x{camera.height}",
                         Reason.WRONG_IMAGE_SIZE, image_size=(w, h))
    try:
        return detect(img, board, camera)
    except ImageError as exc:
        return Detection(False, None, str(exc), Reason.BAD_IMAGE, image_size=(w, h))


def detect_files(paths: list[Path], board: Board, camera: Camera | None = None, progress: bool = True,
                 jobs: int | None = None) -> list[Detection]:
    """:func:`detect` on each image file, in the order given. A missing, unreadable or corrupt file, or an image the
    detector cannot use, gives ``found=False`` with its reason and code (:func:`_detect_file`); nothing else is
    caught. Shows a tqdm progress bar when ``progress``.

    ``jobs``: images processed at once, in threads (decoding, OpenCV and the compiled loops release the GIL); ``None``
    = one per CPU (at most 8). The results do not depend on it: each image is detected on its own.
    """
    from concurrent.futures import ThreadPoolExecutor

    from tqdm import tqdm

    paths = [Path(p) for p in paths]
    jobs = min(8, os.cpu_count() or 1) if jobs is None else int(jobs)
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    bar = tqdm(total=len(paths), desc="detect", unit="img", disable=not progress)
    try:
        if jobs == 1 or len(paths) < 2:
            out = []
            for p in paths:
                out.append(_detect_file(p, board, camera))
                bar.update()
            return out
        with ThreadPoolExecutor(max_workers=min(jobs, len(paths))) as pool:
            futures = [pool.submit(_detect_file, p, board, camera) for p in paths]
            for f in futures:
                f.add_done_callback(lambda _: bar.update())
            return [f.result() for f in futures]
    finally:
        bar.close()
