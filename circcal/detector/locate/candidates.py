"""Candidate dots: dark blobs of a segmentation mask that look like imaged circles, and the area limits that scale
them to the image and the board.

Pixel convention: OpenCV's (integer coordinates are pixel centres).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from circcal.board import Board
from circcal.detector.kernels.jit import njit

__all__ = ["Candidate", "area_limits", "find_candidates"]

MIN_CIRCULARITY = 0.45
"""``4 pi S / P^2`` of a kept blob (1 for a disk). On the pixel contour a disk measures ~0.9, an ellipse of axis
ratio 2 (a dot at 60 deg tilt) ~0.75, of ratio 1:3.8 (75 deg) ~0.5: dots seen up to ~75 deg are kept, lines,
letters and merged blobs are not."""
MIN_INERTIA = 0.08
"""Minor / major second moment (``(b/a)^2``) of a kept blob's edge: axis ratios down to ~1:3.5 (tilts to ~75 deg).
The pixel contour's own ratio is smaller for a thin blob (:data:`CONTOUR_INSET_PX`): dots 73-79 deg off a fisheye's
axis, 1:3 and ~5 px across the minor axis at full resolution, measured 0.06-0.077 on the half-scale contour and were
lost (issue 33)."""
CONTOUR_INSET_PX = 0.5
"""A blob's pixel contour runs through the centres of its boundary pixels, this far inside its edge (px at the
mask's scale): the inertia test and :func:`_upscale` measure the edge's ellipse, semi-axes this much longer."""
MIN_CONVEXITY = 0.8
"""Blob area / convex-hull area: a dot is convex; two touching blobs or a dot cut by a shadow is not."""
MIN_CONTOUR_POINTS = 5
"""Contours with fewer points are not a measurable blob (and an ellipse needs 5)."""
MAX_AREA_FACTOR = 4.0
"""The largest dot may be this many times the area of an average dot of a board filling the whole image
(perspective makes near dots larger)."""
MIN_AREA_PX2 = 6.0
"""The smallest candidate dot (px^2, at any image size): a disk 2.8 px across. Measured on the fisheye rig's renders
(circcal/fixtures/rig.py ``fisheye``: a 640x480 fisheye whose far dots are 2.9-4.4 px across), the views this
floor keeps against 12 px^2: 13 of 14 against 4 clean, 13 of 14 against 5 with blur and sensor noise, every kept
view's centres 0.005-0.010 px RMS (max 0.029) from the truth; the one view lost has dots below 3 px. At 4 px^2 the
same views; 6 leaves a margin against noise specks. (12 px^2, a guess that a sub-pixel boundary could not be measured
below, lost those views; a share of the image area, before it, dropped dots 8-12 px across at 4000x3000.)"""
MIN_AREA_RANGE = 4.0
"""The area window spans at least this factor (radii within 2x), however small the board's dots."""
SHORTEST_CONTOUR_SHARE = 0.5
"""Contours with fewer points than this share of a disk of ``min_area``'s perimeter are passed over unmeasured (an
8-connected pixel contour of a disk has about 0.9 points per pixel of perimeter; half leaves room for
CHAIN_APPROX_NONE's diagonal steps)."""


@dataclass
class Candidate:
    """A dark blob that may be a dot. ``centre`` (2,) px area centroid of the contour polygon; ``axes`` (a, b)
    semi-axes (px) and ``angle`` (rad, of ``a`` from the image x axis) of the ellipse with the same second moments;
    ``area`` px^2; ``cut``: the blob touches the image border (a dot cut by it: it shows where the lattice goes on,
    and is never measured)."""

    centre: np.ndarray
    axes: tuple[float, float]
    angle: float
    area: float
    cut: bool = False


def area_limits(board: Board, width: int, height: int) -> tuple[float, float]:
    """The area window (min_area, max_area) of candidate dots of ``board`` in a ``width`` x ``height`` image.

    At most :data:`MAX_AREA_FACTOR` times an average dot of a board filling the image (times the markers' area ratio
    on a marker board), at least :data:`MIN_AREA_PX2` (the smallest measurable dot, whatever the image size); the
    window spans at least :data:`MIN_AREA_RANGE`.

    Parameters
    ----------
    board : Board
        The board (its pitch, dot radius, layout, point count and marker scale).
    width, height : int
        The image's size, px.

    Returns
    -------
    tuple of float
        ``(min_area, max_area)``, px^2.
    """
    cell = board.pitch_mm**2 * (2.0 if board.layout == "asymmetric" else 1.0)
    dot_frac = np.pi * board.radius_mm**2 / cell
    max_area = MAX_AREA_FACTOR * dot_frac * width * height / board.n_points * board.marker_scale**2
    min_area = MIN_AREA_PX2
    return min_area, max(max_area, MIN_AREA_RANGE * min_area)


def find_candidates(
    mask: np.ndarray,
    *,
    min_area: float,
    max_area: float,
    min_circularity: float = MIN_CIRCULARITY,
    min_inertia: float = MIN_INERTIA,
    min_convexity: float = MIN_CONVEXITY,
    scale: int = 1,
) -> list[Candidate]:
    """Dark blobs of ``mask`` that look like imaged dots.

    Outer contours only (a dot is a filled component); kept when ``min_area <= area <= max_area`` (px^2), circularity
    ``4 pi S / P^2 >= min_circularity``, inertia ratio (minor/major second moment, ``(b/a)^2``, of the blob's edge: the
    contour's semi-axes plus :data:`CONTOUR_INSET_PX`) ``>= min_inertia``, convexity ``S / hull area >= min_convexity``.
    A blob that touches the image border is kept with ``cut=True`` (a dot cut by the border: never measured, but it
    shows where the board goes on). Contours too short to enclose ``min_area`` (a closed pixel contour of P points
    encloses at most ``P^2 / (4 pi)``) are passed over before any moment is computed: a noise image has 10^5 of them.
    The others are measured in one compiled pass (:func:`_contour_measures`: OpenCV's moments, perimeter, hull area and
    box to the bit, without ~5 OpenCV calls per contour from Python: 1.3 against 0.5 ms per 1080p paper view).

    Parameters
    ----------
    mask : numpy.ndarray
        (H, W) uint8 segmentation, 255 = dark.
    min_area, max_area : float
        The area window, px^2 at the mask's scale (:func:`area_limits`).
    min_circularity : float, optional
        Least ``4 pi S / P^2`` (:data:`MIN_CIRCULARITY`).
    min_inertia : float, optional
        Least minor/major second-moment ratio (:data:`MIN_INERTIA`).
    min_convexity : float, optional
        Least area / convex-hull area (:data:`MIN_CONVEXITY`).
    scale : int, optional
        The mask is of an image shrunk that many times; the candidates are given in full-image pixels
        (:func:`_upscale`; the area limits and tests apply at the mask's scale).

    Returns
    -------
    list of Candidate
        The kept blobs, in full-image pixels (OpenCV's convention), in contour order.

    Examples
    --------
    >>> mask = np.zeros((40, 40), np.uint8)
    >>> _ = cv2.circle(mask, (20, 20), 6, 255, -1)
    >>> [c.cut for c in find_candidates(mask, min_area=12.0, max_area=1000.0)]
    [False]
    """
    H, W = mask.shape
    contours, hier = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    out: list[Candidate] = []
    if hier is None:
        return out
    shortest = max(MIN_CONTOUR_POINTS, int(np.sqrt(4.0 * np.pi * min_area) * SHORTEST_CONTOUR_SHARE))
    outer = hier[0][:, 3] == -1
    todo = [contours[k] for k in np.nonzero(outer)[0] if len(contours[k]) >= shortest]
    if not todo:
        return out
    counts = np.array([len(c) for c in todo], np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    pts = np.ascontiguousarray(np.concatenate(todo).reshape(-1, 2), np.int64)
    meas = np.empty((len(todo), 12))
    _contour_measures(pts, starts, counts, float(min_area), float(max_area), meas)
    geo = np.empty((len(todo), 7))
    _blob_tests(
        meas,
        float(min_area),
        float(max_area),
        float(min_circularity),
        float(min_inertia),
        float(min_convexity),
        W,
        H,
        geo,
    )
    for cx, cy, a, b, ang, S, cut in geo[geo[:, 0] == geo[:, 0]].tolist():  # (the kept blobs: no NaN)
        c, axes, area = _upscale(np.array([cx, cy]), (a, b), S, scale)
        out.append(Candidate(c, axes, ang, area, cut != 0.0))
    return out


@njit(cache=True, nogil=True)
def _blob_tests(meas, min_area, max_area, min_circularity, min_inertia, min_convexity, W, H, out):
    """The tests of :func:`find_candidates` on each blob's measures ``meas`` (C, 12) (:func:`_contour_measures`),
    writing into ``out`` (C, 7) a kept blob's centre ``cx, cy``, semi-axes ``a, b`` (the contour's), angle, area
    and whether it touches the border of the ``W`` x ``H`` mask (1.0), NaN rows for the others: the moments' tests
    first (area, inertia ratio of the edge's semi-axes ``a, b`` + :data:`CONTOUR_INSET_PX`), then those of the whole
    contour (circularity ``4 pi S / P^2``, convexity ``S / hull area``).
    The arithmetic of the Python expressions it replaced, in their order, but for squares as products (Python's
    ``x ** 2`` calls libm's pow, which rounds a few squares one ulp off: starting ellipses move by ~1e-15 px, the
    centres by < 1e-13 px on 2 of 617 views)."""
    for i in range(len(meas)):
        out[i, :] = np.nan
        S, m10, m01, m20, m11, m02, P, hull = (
            meas[i, 0],
            meas[i, 1],
            meas[i, 2],
            meas[i, 3],
            meas[i, 4],
            meas[i, 5],
            meas[i, 6],
            meas[i, 7],
        )
        if not (min_area <= S <= max_area):
            continue
        mu20, mu02, mu11 = m20 / S, m02 / S, m11 / S
        tr = mu20 + mu02
        disc = math.sqrt(max(0.0, (mu20 - mu02) ** 2 + 4 * mu11**2))
        l1, l2 = 0.5 * (tr + disc), 0.5 * (tr - disc)  # principal second moments; a = 2 sqrt(l1) for an ellipse
        if l1 <= 0:
            continue
        # the ratio of the blob's edge, half a pixel outside the contour (through its boundary pixels' centres): the
        # contour's own ratio thins a blob a few pixels across (a 1:3 blob 4 px across: 0.074 for the edge's 0.111)
        ea, eb = 2.0 * math.sqrt(l1) + CONTOUR_INSET_PX, 2.0 * math.sqrt(max(l2, 0.0)) + CONTOUR_INSET_PX
        if (eb * eb) / (ea * ea) < min_inertia:
            continue
        if 4.0 * math.pi * S / (P * P) < min_circularity:
            continue
        if hull <= 0 or S / hull < min_convexity:
            continue
        x0, y0, x1, y1 = meas[i, 8], meas[i, 9], meas[i, 10], meas[i, 11]
        out[i, 0], out[i, 1] = m10 / S, m01 / S
        out[i, 2], out[i, 3] = 2.0 * math.sqrt(l1), 2.0 * math.sqrt(max(l2, 1e-12))
        out[i, 4] = 0.5 * math.atan2(2 * mu11, mu20 - mu02)
        out[i, 5] = S
        out[i, 6] = 1.0 if (x0 <= 0 or y0 <= 0 or x1 + 1 >= W or y1 + 1 >= H) else 0.0


def _upscale(
    centre: np.ndarray, axes: tuple[float, float], area: float, scale: int
) -> tuple[np.ndarray, tuple[float, float], float]:
    """The centre (2,), semi-axes and area of a candidate found on an image shrunk ``scale`` x (pixel-area
    averaging) in full-image pixels (the same objects for ``scale`` 1). The contour runs through the centres of the
    blob's boundary pixels, ~half a pixel inside its edge at either scale: the axes get the difference back, so the
    starting ellipse is as close to the edge as one found at full resolution."""
    if scale == 1:
        return centre, axes, area
    off = CONTOUR_INSET_PX * (scale - 1)
    return centre * scale + off, (axes[0] * scale + off, axes[1] * scale + off), area * scale**2


@njit(cache=True, nogil=True)
def _contour_measures(pts, starts, counts, min_area, max_area, out):
    """Writes into ``out`` (C, 12) per contour ``i`` (points ``pts[starts[i]:starts[i] + counts[i]]`` (x, y) int, a
    closed pixel contour of ``cv2.findContours``) what :func:`find_candidates` tests, with OpenCV's values:
    ``m00, m10, m01`` and the central ``mu20, mu11, mu02`` as ``cv2.moments`` (Green's theorem over the polygon,
    its sums and factors), and, for a contour whose ``m00`` lies in ``[min_area, max_area]`` (else NaN), its
    perimeter as ``cv2.arcLength(cnt, True)`` (float32 steps, exact sums), its convex hull's area as
    ``cv2.contourArea(cv2.convexHull(cnt))`` (monotone chain; integer vertices: the area is exact whichever hull
    algorithm), and its bounding box ``xmin, ymin, xmax, ymax`` (``cv2.boundingRect``'s x, y, x + w - 1,
    y + h - 1)."""
    for i in range(len(starts)):
        s0, n = starts[i], counts[i]
        a00 = a10 = a01 = a20 = a11 = a02 = 0.0
        xi_1 = float(pts[s0 + n - 1, 0])
        yi_1 = float(pts[s0 + n - 1, 1])
        for k in range(n):
            xi = float(pts[s0 + k, 0])
            yi = float(pts[s0 + k, 1])
            xi2 = xi * xi
            yi2 = yi * yi
            dxy = xi_1 * yi - xi * yi_1
            xii_1 = xi_1 + xi
            yii_1 = yi_1 + yi
            a00 += dxy
            a10 += dxy * xii_1
            a01 += dxy * yii_1
            a20 += dxy * (xi_1 * xii_1 + xi2)
            a11 += dxy * (xi_1 * (yii_1 + yi_1) + xi * (yii_1 + yi))
            a02 += dxy * (yi_1 * yii_1 + yi2)
            xi_1 = xi
            yi_1 = yi
        m00 = m10 = m01 = m20 = m11 = m02 = 0.0
        if abs(a00) > 1.1920928955078125e-07:  # FLT_EPSILON, as OpenCV
            sg = 1.0 if a00 > 0 else -1.0
            m00 = a00 * (sg * 0.5)
            m10 = a10 * (sg * 0.16666666666666666)
            m01 = a01 * (sg * 0.16666666666666666)
            m20 = a20 * (sg * 0.083333333333333333)
            m11 = a11 * (sg * 0.041666666666666667)
            m02 = a02 * (sg * 0.083333333333333333)
        cx = cy = 0.0
        if abs(m00) > 2.220446049250313e-16:  # DBL_EPSILON
            inv = 1.0 / m00
            cx = m10 * inv
            cy = m01 * inv
        out[i, 0], out[i, 1], out[i, 2] = m00, m10, m01
        out[i, 3] = m20 - m10 * cx
        out[i, 4] = m11 - m10 * cy
        out[i, 5] = m02 - m01 * cy
        out[i, 6:] = np.nan
        if not (min_area <= m00 <= max_area):
            continue
        # perimeter: OpenCV's float32 steps (1 or sqrt(2) here), summed exactly in double
        per = 0.0
        px, py = pts[s0 + n - 1, 0], pts[s0 + n - 1, 1]
        xmin, ymin, xmax, ymax = px, py, px, py
        for k in range(n):
            x, y = pts[s0 + k, 0], pts[s0 + k, 1]
            dx, dy = np.float32(x - px), np.float32(y - py)
            per += float(np.sqrt(np.float32(dx * dx + dy * dy)))
            px, py = x, y
            xmin, ymin, xmax, ymax = min(xmin, x), min(ymin, y), max(xmax, x), max(ymax, y)
        out[i, 6] = per
        out[i, 7] = _hull_area(pts[s0 : s0 + n])
        out[i, 8], out[i, 9], out[i, 10], out[i, 11] = xmin, ymin, xmax, ymax


@njit(cache=True, nogil=True)
def _hull_area(p):
    """Area of the convex hull of the integer points ``p`` (n, 2) (Andrew's monotone chain; the shoelace sum of
    integer vertices is exact)."""
    n = len(p)
    order = np.argsort(p[:, 0] * (1 << 32) + p[:, 1])
    hull = np.empty((2 * n + 1, 2), np.int64)
    h = 0
    for rep in range(2):  # lower chain left to right, then upper chain right to left
        start = h
        for t in range(n):
            j = order[t] if rep == 0 else order[n - 1 - t]
            x, y = p[j, 0], p[j, 1]
            while (
                h - start >= 2
                and (
                    (hull[h - 1, 0] - hull[h - 2, 0]) * (y - hull[h - 2, 1])
                    - (hull[h - 1, 1] - hull[h - 2, 1]) * (x - hull[h - 2, 0])
                )
                <= 0
            ):
                h -= 1
            hull[h, 0], hull[h, 1] = x, y
            h += 1
        h -= 1  # the chain's last point starts the next one
    area2 = 0
    for k in range(h):
        q = (k + 1) % h
        area2 += hull[k, 0] * hull[q, 1] - hull[q, 0] * hull[k, 1]
    return 0.5 * abs(float(area2))
