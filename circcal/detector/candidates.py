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

__all__ = ["Candidate", "area_limits", "find_candidates"]

MIN_CIRCULARITY = 0.45
"""``4 pi S / P^2`` of a kept blob (1 for a disk). On the pixel contour a disk measures ~0.9, an ellipse of axis
ratio 2 (a dot at 60 deg tilt) ~0.75, of ratio 1:3.8 (75 deg) ~0.5: dots seen up to ~75 deg are kept, lines,
letters and merged blobs are not."""
MIN_INERTIA = 0.08
"""Minor / major second moment (``(b/a)^2``) of a kept blob: axis ratios down to ~1:3.5 (tilts to ~75 deg)."""
MIN_CONVEXITY = 0.8
"""Blob area / convex-hull area: a dot is convex; two touching blobs or a dot cut by a shadow is not."""
MIN_CONTOUR_POINTS = 5
"""Contours with fewer points are not a measurable blob (and an ellipse needs 5)."""
MAX_AREA_FACTOR = 4.0
"""The largest dot may be this many times the area of an average dot of a board filling the whole image
(perspective makes near dots larger)."""
MIN_AREA_PX2 = 12.0
"""The smallest candidate dot (px^2, at any image size): a dot 6 px across (28 px^2) seen at 60 deg of tilt has
14; below, a sub-pixel boundary cannot be measured. (A share of the image area, as before, dropped dots 8-12 px
across at 4000x3000 and 20 px across at 8000x6000.)"""
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
    """(min_area, max_area) px^2 for candidate dots of ``board`` in a ``width`` x ``height`` image: at most
    :data:`MAX_AREA_FACTOR` times an average dot of a board filling the image (times the markers' area ratio on a
    marker board), at least :data:`MIN_AREA_PX2` (the smallest measurable dot, whatever the image size); the window
    spans at least :data:`MIN_AREA_RANGE`."""
    cell = board.pitch_mm ** 2 * (2.0 if board.layout == "asymmetric" else 1.0)
    dot_frac = np.pi * board.radius_mm ** 2 / cell
    max_area = MAX_AREA_FACTOR * dot_frac * width * height / board.n_points * board.marker_scale ** 2
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
) -> list[Candidate]:
    """Dark blobs of ``mask`` (H, W) uint8 (255 = dark) that look like imaged dots.

    Outer contours only (a dot is a filled component); kept when ``min_area <= area <= max_area`` (px^2),
    circularity ``4 pi S / P^2 >= min_circularity``, inertia ratio (minor/major second moment, ``(b/a)^2``)
    ``>= min_inertia``, convexity ``S / hull area >= min_convexity``. A blob that touches the image border is
    kept with ``cut=True`` (a dot cut by the border: never measured, but it shows where the board goes on).
    Contours too short to enclose ``min_area`` (a closed pixel contour of P points encloses at most
    ``P^2 / (4 pi)``) are passed over before any moment is computed: a noise image has 10^5 of them.
    """
    H, W = mask.shape
    contours, hier = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    out: list[Candidate] = []
    if hier is None:
        return out
    shortest = max(MIN_CONTOUR_POINTS, int(np.sqrt(4.0 * np.pi * min_area) * SHORTEST_CONTOUR_SHARE))
    outer = hier[0][:, 3] == -1
    for k in np.nonzero(outer)[0]:
        cnt = contours[k]
        if len(cnt) < shortest:
            continue
        m = cv2.moments(cnt)
        S = m["m00"]
        if not (min_area <= S <= max_area):
            continue
        # the tests from the moments first, then those that need more of the contour (the same candidates)
        mu20, mu02, mu11 = m["mu20"] / S, m["mu02"] / S, m["mu11"] / S
        tr = mu20 + mu02
        # (math on Python floats: numpy's values without numpy's per-scalar overhead)
        disc = math.sqrt(max(0.0, (mu20 - mu02) ** 2 + 4 * mu11 ** 2))
        l1, l2 = 0.5 * (tr + disc), 0.5 * (tr - disc)   # principal second moments; a = 2 sqrt(l1) for an ellipse
        if l1 <= 0 or l2 / l1 < min_inertia:
            continue
        P = cv2.arcLength(cnt, True)
        if 4.0 * math.pi * S / (P * P) < min_circularity:
            continue
        hull = cv2.contourArea(cv2.convexHull(cnt))
        if hull <= 0 or S / hull < min_convexity:
            continue
        x, y, w, hh = cv2.boundingRect(cnt)
        cut = x <= 0 or y <= 0 or x + w >= W or y + hh >= H
        ang = 0.5 * math.atan2(2 * mu11, mu20 - mu02)
        c = np.array([m["m10"] / S, m["m01"] / S])
        out.append(Candidate(c, (2.0 * math.sqrt(l1), 2.0 * math.sqrt(max(l2, 1e-12))), ang, S, cut))
    return out
