"""Each dot of the grid measured: sub-pixel edge points and the ellipse fitted to them, all dots at once
(:func:`fit_dots`).

Pixel convention: OpenCV's (integer coordinates are pixel centres).
"""
from __future__ import annotations

import numpy as np

from circcal.detector.edges import PROFILE_SPACING_PX, subpixel_edge_points_batch
from circcal.detector.ellipse import FIT_ERRORS, fit_ellipses_direct, sampson_distances
from circcal.detector.robust import mad_inliers
from circcal.detector.smoothing import SmoothedImage

__all__ = ["EDGE_SIGMA", "MIN_EDGE_POINTS", "STEERING_LEVEL_STRIDE", "STEERING_SPACING_PX", "fit_dots"]

EDGE_SIGMA = 1.5
"""Gaussian smoothing (px) for the edge profiles, one for all dots (so the board's window is smoothed once). 1.5 px
makes the cubic interpolation of the pixel grid accurate to ~1e-3 px even on unblurred (aliased) renders; measured
best for dots of radius 7-30 px at tilts up to 60 deg (smaller values leave interpolation error, larger ones
curvature bias). With an optical blur of ~1 px it is also near the noise-optimal (matched) smoothing."""
MIN_EDGE_POINTS = 10
"""A dot with fewer edge points is not measured (an ellipse needs 5; the rest give the fit and the outlier rule
some redundancy)."""
FIT_PASSES = 2
"""Passes of measure-and-fit: the edge points of the first are measured along the normals of the starting ellipse,
those of the next along the previous fit's. Only the last pass's points and ellipse are returned: the earlier passes
steer it (:data:`STEERING_SPACING_PX`)."""
STEERING_SPACING_PX = 4.0
"""The passes before the last measure one edge profile per this many px of perimeter (at least
:data:`~circcal.detector.edges.MIN_PROFILES`; the last pass one per
:data:`~circcal.detector.edges.PROFILE_SPACING_PX`). They only steer the last pass: their ellipse sets its profiles'
normals and its regions of interest, and an error of dx px in it tilts a normal by ~dx / r, which moves the last
pass's edge points along the edge, not across it. A fit to a quarter of the points is ~2x noisier, far inside what
steering needs (the starting ellipses from the contours are off by up to ~0.5 px). Measured: from starts 0.5 px and
5 % off, the last pass's ellipses move < 5e-6 px on clean renders (tested); on the hard views the centre RMS against
the truth is that of every profile (216 views; the worst exact render 0.0046 px), the same dots labelled. Detection
is ~7 % faster at 1080p, ~20 % at 4000x3000. A dot the steering pass cannot fit (too few points, no ellipse: a dot
cut by the border or an occluder leaves few profiles) keeps its previous ellipse, and the last pass decides."""
STEERING_LEVEL_STRIDE = 2
"""... and take the dots' grey levels from every second row and column of their pixels
(:func:`~circcal.detector.levels.dot_levels_from_params`: dots of minor semi-axis >= 8 px; smaller ones every
pixel): a level error moves the steering edge points all alike, the ellipse's size, not its centre, and the last
pass takes its levels from every pixel again. ~0.4x the levels' time in that pass."""
OUTLIER_SIGMAS = 4.0
"""Edge points further from the fitted ellipse (Sampson distance) than this many robust sigmas ..."""
OUTLIER_MIN_PX = 0.1
"""... and than this (px: on clean images the robust sigma is tiny) plus the point's uncorrected curvature shift
(where the curvature model fades out, the tight ends of thin ellipses, a point may lie ~0.5 px inside the edge; both
ends alike, so they do not move the centre, while dropping the points of one end only did: 0.01 px on the 55-70 deg
views of ``asym-perspective``) are dropped, and the ellipse refitted once."""


def fit_dots(gray: np.ndarray | SmoothedImage, conics0: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str | None]]:
    """Sub-pixel edge points and ellipse of each dot, from rough ellipses ``conics0`` (D, 3, 3) (e.g. from the
    contours).

    ``gray``: (H, W) grey image, or a :class:`~circcal.detector.smoothing.SmoothedImage` of it at
    :data:`EDGE_SIGMA` (reused across calls). Edge points are measured :data:`FIT_PASSES` times along the normals of
    the latest ellipse (:func:`~circcal.detector.edges.subpixel_edge_points_batch`; sparser in the steering passes,
    :data:`STEERING_SPACING_PX`), each time fitted (direct least squares) and refitted once without the outliers
    (:data:`OUTLIER_SIGMAS`, :data:`OUTLIER_MIN_PX`). Returns
    ``(points (D, M, 2), mask (D, M), conics (D, 3, 3), errors)``: dot ``d``'s edge points are ``points[d][mask[d]]``
    and ``conics[d]`` the ellipse fitted to exactly them; ``errors[d]`` is ``None`` or why the dot could not be
    measured (then its points and conic are not meaningful). Each dot's result depends on that dot alone.
    """
    src = gray if isinstance(gray, SmoothedImage) else SmoothedImage(gray, EDGE_SIGMA)
    Q = np.asarray(conics0, np.float64).copy()
    D = len(Q)
    errors: list[str | None] = [None] * D
    pts = np.zeros((D, 0, 2))
    mask = np.zeros((D, 0), bool)
    slack = np.zeros((D, 0))
    for pas in range(FIT_PASSES):
        last = pas == FIT_PASSES - 1
        act = np.array([e is None for e in errors])
        if not np.any(act):
            break
        ai = np.nonzero(act)[0]
        p_a, m_a, err_a, sl_a = subpixel_edge_points_batch(
            src, Q[ai], with_slack=True, spacing_px=PROFILE_SPACING_PX if last else STEERING_SPACING_PX,
            level_stride=1 if last else STEERING_LEVEL_STRIDE)
        if p_a.shape[1] != pts.shape[1]:
            width = max(p_a.shape[1], pts.shape[1])
            pts = np.concatenate([pts, np.zeros((D, width - pts.shape[1], 2))], axis=1)
            mask = np.concatenate([mask, np.zeros((D, width - mask.shape[1]), bool)], axis=1)
            slack = np.concatenate([slack, np.zeros((D, width - slack.shape[1]))], axis=1)
        pts[ai] = 0.0
        mask[ai] = False
        pts[ai, :p_a.shape[1]] = p_a
        mask[ai, :p_a.shape[1]] = m_a
        slack[ai] = 0.0
        slack[ai, :p_a.shape[1]] = sl_a
        cnt = mask.sum(axis=1)
        for d, e in zip(ai, err_a):
            if e is not None:
                errors[d] = e
            elif cnt[d] < MIN_EDGE_POINTS and last:
                errors[d] = f"only {cnt[d]} sub-pixel edge points"
        ai = np.array([d for d in ai if errors[d] is None and cnt[d] >= MIN_EDGE_POINTS], int)   # (a steering pass
        # leaves a dot with too few points on its previous ellipse)
        if len(ai) == 0:
            break
        Qa, ferr = fit_ellipses_direct(pts[ai], mask[ai])
        m = mask[ai] & (ferr == 0)[:, None]
        keep = m & _inliers(sampson_distances(pts[ai], Qa), m, slack[ai])
        nk = keep.sum(axis=1)
        refit = (ferr == 0) & (nk < m.sum(axis=1)) & (nk >= MIN_EDGE_POINTS)
        if np.any(refit):
            ri = ai[refit]
            Qr, rerr = fit_ellipses_direct(pts[ri], keep[refit])
            mask[ri] = keep[refit]
            Qa[refit] = Qr
            ferr = ferr.copy()
            ferr[refit] = rerr
        if last:
            for j, d in enumerate(ai):
                if ferr[j]:
                    errors[d] = FIT_ERRORS[int(ferr[j])]
            Q[ai] = Qa
        else:   # (a steering pass's failed fit leaves the dot on its previous ellipse)
            Q[ai[ferr == 0]] = Qa[ferr == 0]
    return pts, mask, Q, errors


def _inliers(dist: np.ndarray, mask: np.ndarray, slack: np.ndarray | float = 0.0) -> np.ndarray:
    """(D, M) bool: the distances ``dist`` (D, M) px, of the points where ``mask`` (D, M), within the outlier rule:
    ``|dist| <= max(OUTLIER_SIGMAS * robust sigma, OUTLIER_MIN_PX + slack)``, the robust sigma from the median
    absolute deviation from the median of each row (:func:`~circcal.detector.robust.mad_inliers`), ``slack``
    (D, M) px each point's uncorrected curvature shift."""
    return mad_inliers(dist, mask, OUTLIER_MIN_PX + np.asarray(slack, np.float64), OUTLIER_SIGMAS)
