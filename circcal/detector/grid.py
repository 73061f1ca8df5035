"""Grid recognition and ordering of candidate dot centres, with one documented orientation rule.

Recognition uses OpenCV's circle-grid finder (``cv2.findCirclesGrid``) as a helper for *ordering only*: the candidate
dots are drawn as clean ellipses on a blank canvas and the finder's blob detector reads them back; each ordered
position is then matched to our candidate (the centres returned by circcal are always our own sub-pixel ones).
Clutter (extra dark blobs off the board) is tolerated by the finder's graph search; when the plain search fails,
OpenCV's clustering variant is tried, then the same on the candidates of the dominant size class. A symmetric board
whose candidates are exactly its dots (the usual case) is first ordered directly (:func:`_order_lattice`: hull
corners, one homography, every candidate on its own grid node), which gives the same labelling without the canvas.

Orientation rule (:func:`canonical_order`)
------------------------------------------
A board's point set is symmetric under some rigid relabelings (a symmetric rows x cols grid under 180 deg rotation,
and under 90 deg rotations when square; an asymmetric grid with an even number of rows under 180 deg rotation; with
an odd number of rows, under a mirror only). Among the labelings allowed by those symmetries, circcal keeps only those
whose image handedness matches the board frame seen from the front (board x right and y down map to an image frame
with positive orientation, i.e. the board-to-image homography has a positive Jacobian determinant: x right, y down
in the image as in the board), and among those picks the one whose first point (object point 0) lies nearest to the
image's top-left corner (pixel (0, 0)). So a fronto-parallel, unrolled symmetric board is numbered row by row from
the top-left, like OpenCV's object points; asymmetric grids are at most 2-fold ambiguous and the same rule decides.
"""
from __future__ import annotations

import cv2
import numpy as np

from circcal.board import Board

__all__ = ["canonical_order", "order_grid", "orientation_sign"]

LATTICE_TOLERANCE = 0.3
"""The direct ordering of a symmetric grid (:func:`_order_lattice`) takes a candidate as a grid node's when the
homography from the hull corners puts it within this many cells of the node (under perspective it lands on its node
up to noise; at 0.5 a candidate could be taken for either of two nodes; strong distortion fails and falls back)."""
SIZE_CLASS_FACTOR = 6.0
"""The dominant size class: candidates whose area is within this factor of the median candidate area either way
(~2.4x in radius: more than perspective usually makes a board's dots differ)."""
DRAW_RADIUS_SPACING = 0.35
"""Dots are drawn on the canvas with their own radius, at most this share of the distance to the nearest other
candidate, so two drawn blobs never touch."""
CANVAS_MARGIN_RADII = 3.0
"""The canvas covers the candidates plus this many drawn radii ..."""
CANVAS_MARGIN_PX = 20.0
"""... plus this many px (the blob detector and grid finder see the blobs as on a full-size canvas)."""
DRAW_SHIFT = 2
"""Fractional bits of the drawn circles' centres and radii (``cv2.circle`` ``shift``: quarter pixels)."""
DRAW_MIN_RADIUS_PX = 1.0
"""The smallest drawn radius (px), so that a tiny candidate still draws a blob."""
MATCH_MIN_PX = 1.5
"""A grid-finder position belongs to the candidate nearest it when within ``max(MATCH_MIN_PX, MATCH_RADIUS_SHARE *
drawn radius)``: OpenCV's blob centres of the drawn disks lie within a fraction of a pixel of ours."""
MATCH_RADIUS_SHARE = 0.5
BLOB_THRESHOLDS = (60, 200, 40)
"""OpenCV blob detector on the binary canvas: thresholds from, to, step (grey levels), ..."""
BLOB_MIN_REPEATABILITY = 2
"""... a blob must be seen at this many thresholds (with 1, OpenCV reports the whole canvas as a blob), ..."""
BLOB_AREA_MARGIN_PX = 2.0
"""... and may be up to 4x the area of the largest drawn disk grown by this (px): a larger limit lets OpenCV take
the canvas background for a blob and merge it with a dot."""


def orientation_sign(board: Board, centres: np.ndarray) -> float:
    """Sign of the Jacobian determinant, at the grid centre, of the homography board -> image fitted to ``centres``
    (N, 2) in board order: +1 when the board is seen from the front (see module docstring), -1 mirrored."""
    obj = board.object_points()[:, :2]
    H, _ = cv2.findHomography(obj, np.asarray(centres, np.float64), 0)
    if H is None:
        return 0.0
    c = obj.mean(axis=0)
    w = H[2] @ np.array([c[0], c[1], 1.0])
    J = (H[:2, :2] * w - np.outer(H[:2] @ np.array([c[0], c[1], 1.0]), H[2, :2])) / (w * w)
    return float(np.sign(np.linalg.det(J)))


def canonical_order(board: Board, centres: np.ndarray) -> np.ndarray:
    """Indices ``idx`` (N,) so that ``centres[idx]`` follows the orientation rule of this module.

    ``centres``: (N, 2) px in some valid board labelling (e.g. OpenCV's output, possibly rotated or mirrored).
    One homography is fitted: relabelling by a board symmetry ``S`` composes it with ``S`` (the least-squares fit of
    the relabelled points is ``H S``), so a labelling's orientation sign is ``orientation_sign(centres) * det S``.
    """
    centres = np.asarray(centres, dtype=np.float64)
    s0 = orientation_sign(board, centres)
    best, best_d = None, np.inf
    for sym in board.symmetries():
        # new labelling: point k of the board is the old point sym.perm[k]
        if s0 * sym.det <= 0:
            continue
        d = np.hypot(*centres[sym.perm[0]])
        if d < best_d - 1e-9:
            best, best_d = sym.perm, d
    if best is None:
        raise ValueError("no labelling of the detected grid is seen from the board's front (mirrored image?)")
    return best.copy()


def _order_lattice(board: Board, points: np.ndarray, tol: float = LATTICE_TOLERANCE) -> np.ndarray | None:
    """Fast ordering of a symmetric board whose candidates are exactly its N dots (no clutter): (N,) indices into
    ``points`` (N, 2) px in a valid board labelling (not yet canonical), or ``None`` when the candidates do not form
    the grid unambiguously (the caller then runs OpenCV's grid finder).

    The grid's four corners are the convex-hull vertices with the largest turning angles; the homography from them
    to the grid's integer coordinates must put every candidate within ``tol`` cells of a distinct grid node. Under
    perspective this is the grid itself, and exactly the assignment OpenCV's finder returns (up to a symmetry, which
    :func:`canonical_order` removes); strong lens distortion fails the test and falls back.
    """
    N = board.n_points
    if board.layout != "symmetric" or len(points) != N:
        return None
    hull = cv2.convexHull(points.astype(np.float32), returnPoints=False).reshape(-1)
    if len(hull) < 4:
        return None
    P = points[hull]
    a = P - np.roll(P, 1, axis=0)
    b = np.roll(P, -1, axis=0) - P
    turn = np.abs(np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], np.sum(a * b, axis=1)))
    corners = P[np.sort(np.argsort(turn)[-4:])].astype(np.float32)          # (4, 2) in hull order
    cols, rows = board.cols, board.rows
    grid = np.array([[0, 0], [cols - 1, 0], [cols - 1, rows - 1], [0, rows - 1]], np.float32)
    for shift in (0, 1):
        Hg = cv2.getPerspectiveTransform(corners, np.roll(grid, shift, axis=0))
        q = cv2.perspectiveTransform(points.reshape(-1, 1, 2), Hg).reshape(-1, 2)
        if not np.all(np.isfinite(q)):
            continue
        r = np.round(q)
        if np.max(np.abs(q - r)) >= tol or r[:, 0].min() < 0 or r[:, 1].min() < 0 or r[:, 0].max() > cols - 1\
                or r[:, 1].max() > rows - 1:
            continue
        k = (r[:, 1] * cols + r[:, 0]).astype(int)                          # board index of each candidate
        idx = np.full(N, -1)
        idx[k] = np.arange(N)
        if np.all(idx >= 0):
            return idx
    return None


def _canvas(points: np.ndarray, radii: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) = ``shape`` uint8 canvas, white, with a black disk of radius ``radii`` (M,) px at each of ``points``
    (M, 2) px (to :data:`DRAW_SHIFT` fractional bits, at least :data:`DRAW_MIN_RADIUS_PX`)."""
    canvas = np.full(shape, 255, np.uint8)
    unit = 1 << DRAW_SHIFT
    r_min = int(DRAW_MIN_RADIUS_PX * unit)
    for (x, y), r in zip(points, radii):
        cv2.circle(canvas, (int(round(x * unit)), int(round(y * unit))), max(r_min, int(round(r * unit))), 0, -1,
                   lineType=cv2.LINE_8, shift=DRAW_SHIFT)
    return canvas


def _blob_detector(max_radius: float) -> cv2.SimpleBlobDetector:
    """OpenCV's blob detector set up for the canvas of :func:`_canvas` (black disks of radius up to ``max_radius``
    px on white): the blob centres the grid finder reads back (:data:`BLOB_THRESHOLDS`,
    :data:`BLOB_MIN_REPEATABILITY`, :data:`BLOB_AREA_MARGIN_PX`)."""
    p = cv2.SimpleBlobDetector_Params()
    p.minThreshold, p.maxThreshold, p.thresholdStep = BLOB_THRESHOLDS
    p.minRepeatability = BLOB_MIN_REPEATABILITY
    p.minDistBetweenBlobs = 0.5
    p.filterByColor, p.blobColor = True, 0
    p.filterByArea, p.minArea, p.maxArea = True, 1.0, 4.0 * np.pi * (max_radius + BLOB_AREA_MARGIN_PX) ** 2
    p.filterByCircularity = p.filterByInertia = p.filterByConvexity = False
    return cv2.SimpleBlobDetector_create(p)


def order_grid(board: Board, points: np.ndarray, radii: np.ndarray, image_shape: tuple[int, int]
               ) -> np.ndarray | None:
    """Recognise the board among candidate dots and order it.

    ``points``: (M, 2) candidate centres px; ``radii``: (M,) their rough radii px (for drawing); ``image_shape``:
    (H, W). Returns (N,) indices into ``points`` in board order (orientation rule of this module), or ``None``.
    """
    N = board.n_points
    M = len(points)
    if M < N:
        return None
    points = np.asarray(points, np.float64)
    radii = np.asarray(radii, np.float64)
    idx = _order_lattice(board, points)
    if idx is not None:
        try:
            return idx[canonical_order(board, points[idx])]
        except ValueError:
            pass
    # drawn radius: a fraction of the distance to the nearest other candidate, so blobs never merge
    dist = np.linalg.norm(points[:, None] - points[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    nn = dist.min(axis=1)
    draw_r = np.minimum(radii, DRAW_RADIUS_SPACING * nn)
    # the canvas covers the candidates only (plus a margin): an integer shift of a drawing, so the blob detector
    # and the grid finder see the same shapes as on a full-size canvas, at a fraction of the cost
    margin = CANVAS_MARGIN_RADII * float(draw_r.max()) + CANVAS_MARGIN_PX
    ox = int(max(0, np.floor(points[:, 0].min() - margin)))
    oy = int(max(0, np.floor(points[:, 1].min() - margin)))
    cw = int(min(image_shape[1], np.ceil(points[:, 0].max() + margin) + 1)) - ox
    ch = int(min(image_shape[0], np.ceil(points[:, 1].max() + margin) + 1)) - oy
    shape = (max(ch, 1), max(cw, 1))
    local = points - [ox, oy]
    canvas = _canvas(local, draw_r, shape)
    det = _blob_detector(float(draw_r.max()))
    base = cv2.CALIB_CB_ASYMMETRIC_GRID if board.layout == "asymmetric" else cv2.CALIB_CB_SYMMETRIC_GRID
    subsets = [np.arange(M)]
    # the dominant size class (drops clutter of other sizes)
    area = radii ** 2
    med = np.median(area)
    keep = np.nonzero((area > med / SIZE_CLASS_FACTOR) & (area < med * SIZE_CLASS_FACTOR))[0]
    if N <= len(keep) < M:
        subsets.append(keep)
    for sub in subsets:
        cv_ = canvas if len(sub) == M else _canvas(local[sub], draw_r[sub], shape)
        for flags in (base, base | cv2.CALIB_CB_CLUSTERING):
            try:
                ok, found = cv2.findCirclesGrid(cv_, board.pattern_size, flags=flags, blobDetector=det)
            except cv2.error:
                ok, found = False, None
            if not ok or found is None:
                continue
            found = found.reshape(-1, 2).astype(np.float64)
            d = np.linalg.norm(found[:, None] - local[sub][None], axis=-1)
            j = np.argmin(d, axis=1)
            tol = np.maximum(MATCH_MIN_PX, MATCH_RADIUS_SHARE * draw_r[sub][j])
            if len(np.unique(j)) != N or np.any(d[np.arange(N), j] > tol):
                continue
            idx = sub[j]
            try:
                return idx[canonical_order(board, points[idx])]
            except ValueError:
                continue
    return None
