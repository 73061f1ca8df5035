"""Circle-grid detection with unbiased centre projections.

:func:`detect` runs, on one image:

1. grey conversion and segmentation that survives uneven/strong/weak illumination (:mod:`circcal.edges`);
2. candidate dots from contours, filtered by area (limits scaled to the image and the board's dot density),
   circularity, inertia ratio and convexity;
3. grid recognition and ordering in OpenCV's object-point order with circcal's orientation rule
   (:mod:`circcal.grid`);
4. sub-pixel edge points on each dot's boundary (half-level crossings along ellipse normals, corrected for edge
   curvature) and a direct least-squares ellipse fit (:mod:`circcal.ellipse`);
5. projective centre correction: each centre is the pole of the board's vanishing line w.r.t. its ellipse, the
   homography re-estimated from the corrected centres until stable (:mod:`circcal.centre`). With a camera model
   the edge points are undistorted first, the correction runs in the undistorted image and the centres are
   distorted back.

:func:`recorrect` repeats step 5 alone for another camera model, reusing the stored edge points (what a calibrator
iterating its distortion estimate needs; ~1 ms per view).

Pixel convention: OpenCV's (integer coordinates are pixel centres); centres in OpenCV's object-point order.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .board import Board
from .centre import correct_centres
from .edges import find_candidates, normalise_u8, segmentations, subpixel_edge_points, to_gray
from .ellipse import conic_params, fit_ellipse_direct
from .grid import order_grid
from .model import Camera, distort_pixels, undistort_pixels

__all__ = ["Detection", "detect", "recorrect", "detect_files", "fit_dot", "area_limits"]

MIN_EDGE_POINTS = 10


@dataclass
class Detection:
    """Result of :func:`detect` on one image.

    ``found``: whether the whole grid was found; ``centers``: (rows*cols, 2) float64 px, images of the circle
    centres in OpenCV's object-point order (``None`` when not found); ``reason``: ``None`` when found, else why not.
    For re-correction and overlays: ``edge_points`` (list of (M_k, 2) px sub-pixel boundary points per dot, in board
    order, in the *distorted* image as observed), ``conics`` ((N, 3, 3) ellipses fitted to them, in the undistorted
    image when a camera was given), ``ellipse_centers`` ((N, 2) px, the uncorrected ellipse centres, distorted
    image), ``homography`` (board mm -> undistorted image px), ``candidates`` ((K, 2) px all candidate dots),
    ``image_size`` (W, H).
    """

    found: bool
    centers: np.ndarray | None
    reason: str | None
    edge_points: list[np.ndarray] | None = None
    conics: np.ndarray | None = None
    ellipse_centers: np.ndarray | None = None
    homography: np.ndarray | None = None
    candidates: np.ndarray | None = None
    image_size: tuple[int, int] | None = None
    segmentation: str | None = None
    extra: dict = field(default_factory=dict)


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


def _smoothing_sigma(Q: np.ndarray) -> float:
    """Gaussian smoothing (px) for the edge profiles. 1.5 px makes the cubic interpolation of the pixel grid
    accurate to ~1e-3 px even on unblurred (aliased) renders; measured best for dots of radius 7-30 px at tilts up
    to 60 deg (smaller values leave interpolation error, larger ones curvature bias). With an optical blur of
    ~1 px it is also near the noise-optimal (matched) smoothing."""
    return EDGE_SIGMA


def fit_dot(gray: np.ndarray, Q0: np.ndarray, iterations: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel edge points and ellipse of one dot: ``(points (M, 2) px, conic (3, 3))``.

    ``Q0``: a rough ellipse (e.g. from the contour). Edge points are re-measured along the normals of the latest
    fit ``iterations`` times; points further than 4 robust sigmas (and 0.1 px) from the fit are dropped.
    Raises ``ValueError`` when the dot has too few measurable edge points.
    """
    Q = Q0
    sigma = _smoothing_sigma(Q0)
    pts = np.empty((0, 2))
    for _ in range(iterations):
        pts = subpixel_edge_points(gray, Q, sigma=sigma)
        if len(pts) < MIN_EDGE_POINTS:
            raise ValueError(f"only {len(pts)} sub-pixel edge points")
        Q = fit_ellipse_direct(pts)
        # robust: Sampson distances, drop outliers once
        h = np.column_stack([pts, np.ones(len(pts))])
        g = 2.0 * (h @ Q)[:, :2]
        d = np.einsum("ij,jk,ik->i", h, Q, h) / np.linalg.norm(g, axis=1)
        s = 1.4826 * np.median(np.abs(d - np.median(d)))
        keep = np.abs(d) <= max(4.0 * s, 0.1)
        if not np.all(keep) and np.count_nonzero(keep) >= MIN_EDGE_POINTS:
            pts = pts[keep]
            Q = fit_ellipse_direct(pts)
        sigma = _smoothing_sigma(Q)
    return pts, Q


def _correct(edge_points: list[np.ndarray], board: Board, camera: Camera | None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (N, 2) in the observed image, conics (N, 3, 3) in the undistorted image, H board -> undistorted."""
    obj = board.object_points()[:, :2]
    if camera is not None and np.any(camera.dist):
        und = [undistort_pixels(p, camera) for p in edge_points]
        und = [p[np.all(np.isfinite(p), axis=1)] for p in und]
    else:
        und = edge_points
    conics = np.array([fit_ellipse_direct(p) for p in und])
    centres, H = correct_centres(conics, obj)
    if camera is not None and np.any(camera.dist):
        centres = distort_pixels(centres, camera)
    return centres, conics, H


def _check_camera(camera: Camera | None, width: int, height: int) -> None:
    if camera is not None and (camera.width, camera.height) != (width, height):
        raise ValueError(f"camera model is for {camera.width}x{camera.height} images, image is {width}x{height}")


def detect(image: np.ndarray, board: Board, camera: Camera | None = None) -> Detection:
    """Find ``board``'s circle grid in ``image`` and return the images of the circle centres.

    ``image``: (H, W) grey or (H, W, 3) BGR, uint8/uint16/float; dark dots on a bright board. ``camera``: optional
    model; when given, the centre correction accounts for its lens distortion. Never raises for a grid that is not
    there (``found=False`` with a reason); raises ``ValueError`` for unusable input (wrong shape/dtype, camera for
    another image size).
    """
    gray = to_gray(image)
    Hh, W = gray.shape
    _check_camera(camera, W, Hh)
    if board.layout == "checkerboard":
        raise ValueError("circcal detect finds circle grids; the board is a checkerboard")
    u8 = normalise_u8(gray)
    min_area, max_area = area_limits(board, W, Hh)
    best = 0
    order = cands = None
    seg_name = None
    for name, mask in segmentations(u8):
        cs = find_candidates(mask, min_area=min_area, max_area=max_area)
        best = max(best, len(cs))
        if len(cs) < board.n_points:
            continue
        pts = np.array([c.center for c in cs])
        radii = np.array([np.sqrt(c.axes[0] * c.axes[1]) for c in cs])
        order = order_grid(board, pts, radii, (Hh, W))
        if order is not None:
            cands, seg_name = cs, name
            break
    if order is None:
        return Detection(False, None, f"grid {board.rows}x{board.cols} ({board.layout}) not found: at most {best} "
                                      f"candidate dots, {board.n_points} needed" if best < board.n_points else
                         f"grid {board.rows}x{board.cols} ({board.layout}) not recognised among {best} candidate "
                         f"dots", image_size=(W, Hh))
    edge_points = []
    for k, i in enumerate(order):
        try:
            pts, _ = fit_dot(gray, cands[i].conic)
        except ValueError as exc:
            return Detection(False, None, f"dot {k} of the grid: {exc}", image_size=(W, Hh),
                             candidates=np.array([c.center for c in cands]))
        edge_points.append(pts)
    try:
        centres, conics, H = _correct(edge_points, board, camera)
    except ValueError as exc:
        return Detection(False, None, f"centre correction failed: {exc}", edge_points=edge_points,
                         image_size=(W, Hh))
    ell_c = np.array([conic_params(fit_ellipse_direct(p))[0] for p in edge_points])
    return Detection(True, centres, None, edge_points=edge_points, conics=conics, ellipse_centers=ell_c,
                     homography=H, candidates=np.array([c.center for c in cands]), image_size=(W, Hh),
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
    import cv2

    data = np.fromfile(str(path), dtype=np.uint8) if path.is_file() else None
    if data is None or data.size == 0:
        return None
    return cv2.imdecode(data, cv2.IMREAD_UNCHANGED)


def detect_files(paths: list[Path], board: Board, camera: Camera | None = None, progress: bool = True
                 ) -> list[Detection]:
    """:func:`detect` on each image file; never raises per image: a missing, unreadable or corrupt file, or any
    failure, gives ``found=False`` with the reason. Shows a tqdm progress bar when ``progress``."""
    from tqdm import tqdm

    out = []
    for p in tqdm(list(paths), desc="detect", unit="img", disable=not progress):
        p = Path(p)
        try:
            if not p.exists():
                out.append(Detection(False, None, "file not found"))
                continue
            img = _read_image(p)
            if img is None:
                out.append(Detection(False, None, "unreadable file (not an image, or corrupt)"))
                continue
            out.append(detect(img, board, camera))
        except Exception as exc:  # noqa: BLE001 -- one bad image must never stop the others
            out.append(Detection(False, None, f"{type(exc).__name__}: {exc}"))
    return out
