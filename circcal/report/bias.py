"""The centre-bias study on clean renders: centre error against board tilt and dot size, for circcal's detector
(with and without the lens model), OpenCV's blob detector and a perfect blob centroid.

The board (:data:`BIAS_GRID` x :data:`BIAS_GRID` dots at :data:`BIAS_PITCH_MM` pitch) is centred on the principal
point of :data:`BIAS_CAMERA` at the distance where the point grid spans :data:`BIAS_SPAN_PX` at tilt 0; each dot's
diameter (mm) is set so that a dot at the board centre spans ``d`` px at tilt 0. Renders are exact area coverage,
blurred by :data:`BIAS_BLUR_SIGMA_PX`, quantised to :data:`BIAS_BITS` bits, without noise. Errors (px) are against
the exact projections of the true circle centres.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from circcal.board import Board
from circcal.model import Camera, project
from circcal.report.config import ReportConfig

__all__ = [
    "BIAS_BITS",
    "BIAS_BLUR",
    "BIAS_BLUR_SIGMA_PX",
    "BIAS_CAMERA",
    "BIAS_CENTROID_SAMPLES",
    "BIAS_DETECTORS",
    "BIAS_GRID",
    "BIAS_PITCH_MM",
    "BIAS_SPAN_PX",
    "BIAS_SUPERSAMPLE",
    "BIAS_TILT_AXIS_DEG",
    "BLOB_AREA_WINDOW",
    "BLOB_MIN_INERTIA",
    "bias_geometry",
    "bias_study",
]

#: Camera of the bias study: 1280x960, f 1500 px, mild barrel distortion.
BIAS_CAMERA = Camera(1280, 960, 1500.0, 1500.0, 639.5, 479.5, np.array([-0.1, 0.05, 0.0, 0.0, 0.0]))
BIAS_PITCH_MM = 20.0
#: Dots per row and per column.
BIAS_GRID = 7
#: The point grid spans this many px at tilt 0 (55% of the image height): large tilts stay inside the image.
BIAS_SPAN_PX = 528.0
#: The tilt axis, in degrees from the image x axis (off the grid's axes, so no symmetry hides a bias).
BIAS_TILT_AXIS_DEG = 30.0
#: A real lens's blur (Gaussian sigma, px): keeps edges from being unnaturally sharp.
BIAS_BLUR_SIGMA_PX = 0.7
BIAS_BLUR = [{"kind": "gaussian_blur", "sigma_px": BIAS_BLUR_SIGMA_PX}]
#: Quantisation of the rendered image (an 8-bit camera).
BIAS_BITS = 8
#: Sub-cells per pixel side of the coverage renderer at dot edges.
BIAS_SUPERSAMPLE = 6
#: Boundary samples per dot for the exact area centroid (what a perfect blob detector reports).
BIAS_CENTROID_SAMPLES = 4000
#: OpenCV's SimpleBlobDetector area window as fractions of the dot's area at the board centre: wide enough for the
#: foreshortening at 60 degrees and the distortion, narrow enough to reject the gaps between dots.
BLOB_AREA_WINDOW = (0.15, 2.5)
#: SimpleBlobDetector's minimum inertia ratio (squared axis ratio of the blob): a dot tilted by 60 degrees has 0.25;
#: 0.05 keeps dots down to an axis ratio of ~0.22.
BLOB_MIN_INERTIA = 0.05
#: The detectors compared (keys of the results' error grids).
BIAS_DETECTORS = ("circcal", "circcal_nomodel", "opencv", "perfect_centroid")


def bias_geometry(camera: Camera = BIAS_CAMERA) -> tuple[float, float]:
    """Where the bias study's board stands.

    Parameters
    ----------
    camera : circcal.model.Camera

    Returns
    -------
    distance : float
        mm, at which the point grid spans :data:`BIAS_SPAN_PX` at tilt 0.
    px_per_mm : float
        At the board centre.
    """
    f = 0.5 * (camera.fx + camera.fy)
    distance = f * (BIAS_GRID - 1) * BIAS_PITCH_MM / BIAS_SPAN_PX
    return distance, f / distance


def _board(d_px: float, px_per_mm: float) -> Board:
    """The study's board with dots ``d_px`` across at the board centre (``px_per_mm`` there, at tilt 0)."""
    return Board(BIAS_GRID, BIAS_GRID, BIAS_PITCH_MM, d_px / px_per_mm, "symmetric")


def _render(board: Board, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """The clean render of ``board`` at (rvec, tvec) through :data:`BIAS_CAMERA`: coverage, blur, quantisation."""
    from circcal.fixtures.perturb import apply_perturbations
    from circcal.fixtures.render import Levels, render_coverage

    lv = Levels()
    bc, dc = render_coverage(BIAS_CAMERA, board, rvec, tvec, supersample=BIAS_SUPERSAMPLE)
    clean = lv.background + bc * (lv.board - lv.background) - dc * (lv.board - lv.dark)
    image, _, _ = apply_perturbations(clean, BIAS_BLUR, 0, board_mask=bc > 0.5, bits=BIAS_BITS)
    return image


def _blob_detector(d_px: float) -> Any:
    """OpenCV's SimpleBlobDetector with its area window fitted to dots ``d_px`` across."""
    import cv2

    area = np.pi / 4.0 * d_px**2
    p = cv2.SimpleBlobDetector_Params()
    p.minArea, p.maxArea = float(BLOB_AREA_WINDOW[0] * area), float(BLOB_AREA_WINDOW[1] * area)
    p.minInertiaRatio = BLOB_MIN_INERTIA
    return cv2.SimpleBlobDetector_create(p)


def _centres(
    image: np.ndarray, board: Board, rvec: np.ndarray, tvec: np.ndarray, d_px: float
) -> tuple[dict[str, np.ndarray], list[str]]:
    """Every detector's centres (N, 2) px on one render (a detector that finds no grid is left out) and why any
    failed."""
    from circcal.detector import detect, recorrect
    from circcal.fixtures.render import area_centroids
    from circcal.validators.opencv import find_circles_grid

    found: dict[str, np.ndarray] = {}
    why: list[str] = []
    det = detect(image, board, camera=None)
    if det.found:
        found["circcal_nomodel"] = det.centres
        found["circcal"] = recorrect(det, board, BIAS_CAMERA)
    else:
        why.append(f"circcal: {det.reason}")
    c, how = find_circles_grid(image, board, detector=_blob_detector(d_px))
    if c is None:
        why.append(f"OpenCV: {how}")
    else:
        found["opencv"] = c
    found["perfect_centroid"] = area_centroids(BIAS_CAMERA, board, rvec, tvec, n=BIAS_CENTROID_SAMPLES)
    return found, why


def bias_study(cfg: ReportConfig, *, progress: bool = True) -> tuple[dict[str, Any], float]:
    """Mean and max centre error of each of :data:`BIAS_DETECTORS` per (tilt, diameter) of a config's grid.

    Parameters
    ----------
    cfg : ReportConfig
        ``bias_tilts_deg`` and ``bias_diameters_px``.
    progress : bool

    Returns
    -------
    numbers : dict
        px; NaN where a detector found no grid, with a note why.
    seconds : float
    """
    from tqdm import tqdm

    from circcal.analysis.compare import match_grid_order
    from circcal.fixtures.poses import pose_looking_at

    t0 = time.perf_counter()
    distance, px_per_mm = bias_geometry()
    tilts, diams = list(cfg.bias_tilts_deg), list(cfg.bias_diameters_px)
    mean = {k: np.full((len(tilts), len(diams)), np.nan) for k in BIAS_DETECTORS}
    top = {k: np.full((len(tilts), len(diams)), np.nan) for k in BIAS_DETECTORS}
    notes: list[str] = []
    cells = [(i, j) for i in range(len(tilts)) for j in range(len(diams))]
    for i, j in tqdm(cells, desc="report: bias renders", unit="render", disable=not progress):
        tilt, d_px = tilts[i], diams[j]
        board = _board(d_px, px_per_mm)
        rvec, tvec = pose_looking_at(
            BIAS_CAMERA, board, distance_mm=distance, tilt_deg=tilt, tilt_axis_deg=BIAS_TILT_AXIS_DEG
        )
        true_c = project(board.object_points(), rvec, tvec, BIAS_CAMERA)
        found, why = _centres(_render(board, rvec, tvec), board, rvec, tvec, d_px)
        notes += [f"tilt {tilt:g} deg, {d_px:g} px: {w}" for w in why]
        for k, c in found.items():
            c, _, _ = match_grid_order(c, true_c, board)
            e = np.hypot(*(c - true_c).T)
            mean[k][i, j] = float(np.mean(e))
            top[k][i, j] = float(np.max(e))
    out = {
        "camera": BIAS_CAMERA,
        "board": {
            "rows": BIAS_GRID,
            "cols": BIAS_GRID,
            "pitch_mm": BIAS_PITCH_MM,
            "n_points": _board(diams[0], px_per_mm).n_points,
            "diameters_mm": [d / px_per_mm for d in diams],
        },
        "distance_mm": distance,
        "tilt_axis_deg": BIAS_TILT_AXIS_DEG,
        "perturbations": BIAS_BLUR,
        "bits": BIAS_BITS,
        "tilts_deg": tilts,
        "diameters_px": diams,
        "mean_2d_px": mean,
        "max_2d_px": top,
        "notes": notes,
    }
    return out, time.perf_counter() - t0
