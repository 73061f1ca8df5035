"""Each dot of the grid measured: sub-pixel edge points and the ellipse fitted to them, all dots at once
(:func:`fit_dots`).

Pixel convention: OpenCV's (integer coordinates are pixel centres).
"""

from __future__ import annotations

import numpy as np

from circcal.detector.kernels.jit import njit
from circcal.detector.measure.edges import PROFILE_HALF_MAX_PX, PROFILE_SPACING_PX, subpixel_edge_points_batch
from circcal.detector.measure.ellipse import _sampson_kernel
from circcal.detector.measure.ellipsefit import FIT_ERRORS, _fit_kernel
from circcal.detector.measure.robust import MAD_TO_SIGMA, _mad_inliers_kernel
from circcal.detector.measure.smoothing import SmoothedImage

KERNEL_IMPORTS = (
    "circcal.detector.measure.ellipse",
    "circcal.detector.measure.ellipsefit",
    "circcal.detector.measure.robust",
)
"""Kernel modules whose kernels this module's kernels call (:mod:`circcal.detector.kernels.jit`)."""

__all__ = ["EDGE_SIGMA", "MIN_EDGE_POINTS", "STEERING_LEVEL_STRIDE", "STEERING_SPACING_PX", "fit_dots"]

EDGE_SIGMA = 1.5
"""Gaussian smoothing (px) for the edge profiles, one for all dots (so the board's window is smoothed once). 1.5 px
makes the cubic interpolation of the pixel grid accurate to ~1e-3 px even on unblurred (aliased) renders; measured
best for dots of radius 7-30 px at tilts up to 60 deg (smaller values leave interpolation error, larger ones
curvature bias). With an optical blur of ~1 px it is also near the noise-optimal (matched) smoothing."""
TOO_FEW = "only "
"""How the error of a dot with fewer than :data:`MIN_EDGE_POINTS` edge points begins."""
RETRY_HALF_MAX_PX = 12.0
"""A dot with too few edge points is measured again, from its starting ellipse, with profiles of half length up to
this (``PROFILE_HALF_PER_MINOR`` b, b its minor semi-axis; the first measurement's at most
:data:`~circcal.detector.measure.edges.PROFILE_HALF_MAX_PX`): a big dot with a soft edge (defocus, a high-resolution
image) whose half level lies farther from the contours' ellipse than the short profiles reach."""
MIN_EDGE_POINTS = 10
"""A dot with fewer edge points is not measured (an ellipse needs 5; the rest give the fit and the outlier rule
some redundancy)."""
FIT_PASSES = 2
"""Passes of measure-and-fit: the edge points of the first are measured along the normals of the starting ellipse,
those of the next along the previous fit's. Only the last pass's points and ellipse are returned: the earlier passes
steer it (:data:`STEERING_SPACING_PX`)."""
STEERING_SPACING_PX = 4.0
"""The passes before the last measure one edge profile per this many px of perimeter (at least
:data:`~circcal.detector.measure.edges.MIN_PROFILES`; the last pass one per
:data:`~circcal.detector.measure.edges.PROFILE_SPACING_PX`). They only steer the last pass: their ellipse sets its profiles'
normals and its regions of interest, and an error of dx px in it tilts a normal by ~dx / r, which moves the last
pass's edge points along the edge, not across it. A fit to a quarter of the points is ~2x noisier, far inside what
steering needs (the starting ellipses from the contours are off by up to ~0.5 px). Measured: from starts 0.5 px and
5 % off, the last pass's ellipses move < 5e-6 px on clean renders (tested); on the hard views the centre RMS against
the truth is that of every profile (216 views; the worst exact render 0.0046 px), the same dots labelled. Detection
is ~7 % faster at 1080p, ~20 % at 4000x3000. A dot the steering pass cannot fit (too few points, no ellipse: a dot
cut by the border or an occluder leaves few profiles) keeps its previous ellipse, and the last pass decides."""
STEERING_LEVEL_STRIDE = 2
"""... and take the dots' grey levels from every second row and column of their pixels
(:func:`~circcal.detector.measure.levels.dot_levels_from_params`: dots of minor semi-axis >= 8 px; smaller ones every
pixel): a level error moves the steering edge points all alike, the ellipse's size, not its centre, and the last
pass takes its levels from every pixel again. ~0.4x the levels' time in that pass."""
OUTLIER_SIGMAS = 4.0
"""Edge points further from the fitted ellipse (Sampson distance) than this many robust sigmas ..."""
OUTLIER_MIN_PX = 0.1
"""... and than this (px: on clean images the robust sigma is tiny) plus the point's uncorrected curvature shift
(where the curvature model fades out, the tight ends of thin ellipses, a point may lie ~0.5 px inside the edge; both
ends alike, so they do not move the centre, while dropping the points of one end only did: 0.01 px on the 55-70 deg
views of ``asym-perspective``) are dropped, and the ellipse refitted once."""


def fit_dots(
    gray: np.ndarray | SmoothedImage, conics0: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str | None]]:
    """Sub-pixel edge points and the ellipse of each dot, all dots at once, from rough starting ellipses.

    Edge points are measured :data:`FIT_PASSES` times along the normals of the latest ellipse
    (:func:`~circcal.detector.measure.edges.subpixel_edge_points_batch`; sparser in the steering passes,
    :data:`STEERING_SPACING_PX`), each time fitted (direct least squares) and refitted once without the outliers
    (:data:`OUTLIER_SIGMAS`, :data:`OUTLIER_MIN_PX`; :func:`_fit_pass_kernel`). A dot left with fewer than
    :data:`MIN_EDGE_POINTS` is measured again from its starting ellipse with longer profiles
    (:data:`RETRY_HALF_MAX_PX`); the other dots are not (their results are those of the short profiles to the bit).
    Each dot's result depends on that dot alone.

    Parameters
    ----------
    gray : numpy.ndarray or SmoothedImage
        (H, W) grey image (float or uint8), or a :class:`~circcal.detector.measure.smoothing.SmoothedImage` of it at
        :data:`EDGE_SIGMA` (reused across calls).
    conics0 : numpy.ndarray
        (D, 3, 3) float64: the rough ellipses (e.g. from the contours) as conic matrices, px.

    Returns
    -------
    points : numpy.ndarray
        (D, M, 2) float64 px ``(x, y)``: dot ``d``'s edge points are ``points[d][mask[d]]``.
    mask : numpy.ndarray
        (D, M) bool.
    conics : numpy.ndarray
        (D, 3, 3) float64: ``conics[d]`` is the ellipse fitted to exactly dot ``d``'s edge points.
    errors : list of (str or None)
        (D,): ``None``, or why the dot could not be measured (then its points and conic are not meaningful).
    """
    src = gray if isinstance(gray, SmoothedImage) else SmoothedImage(gray, EDGE_SIGMA)
    Q0 = np.asarray(conics0, np.float64)
    pts, mask, Q, errors = _measure(src, Q0.copy(), PROFILE_HALF_MAX_PX)
    again = np.array([d for d, e in enumerate(errors) if e is not None and e.startswith(TOO_FEW)], np.int64)
    if len(again):  # a soft edge far from its start: the same dots measured again with longer profiles
        p2, m2, q2, e2 = _measure(src, Q0[again].copy(), RETRY_HALF_MAX_PX)
        ok = [j for j, e in enumerate(e2) if e is None]
        if ok:
            M = max(pts.shape[1], p2.shape[1])
            pts = np.concatenate([pts, np.zeros((len(pts), M - pts.shape[1], 2))], axis=1)
            mask = np.concatenate([mask, np.zeros((len(mask), M - mask.shape[1]), bool)], axis=1)
            for j in ok:
                d = again[j]
                pts[d], mask[d] = 0.0, False
                pts[d, : p2.shape[1]], mask[d, : m2.shape[1]] = p2[j], m2[j]
                Q[d], errors[d] = q2[j], None
    return pts, mask, Q, errors


def _measure(
    src: SmoothedImage, Q: np.ndarray, half_max_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str | None]]:
    """:func:`fit_dots`' passes from the ellipses ``Q`` (D, 3, 3; refined in place) with profiles of half length at
    most ``half_max_px``: ``(points, mask, conics, errors)``."""
    D = len(Q)
    errors: list[str | None] = [None] * D
    pts = np.zeros((D, 0, 2))
    mask = np.zeros((D, 0), bool)
    for pas in range(FIT_PASSES):
        last = pas == FIT_PASSES - 1
        ai = np.array([d for d in range(D) if errors[d] is None], np.int64)
        if not len(ai):
            break
        p_a, m_a, err_a, sl_a = subpixel_edge_points_batch(
            src,
            Q[ai],
            with_slack=True,
            spacing_px=PROFILE_SPACING_PX if last else STEERING_SPACING_PX,
            level_stride=1 if last else STEERING_LEVEL_STRIDE,
            half_max_px=half_max_px,
        )
        cnt = m_a.sum(axis=1)
        for j in range(len(ai)):
            if err_a[j] is not None:
                errors[ai[j]] = err_a[j]
            elif cnt[j] < MIN_EDGE_POINTS and last:
                errors[ai[j]] = f"{TOO_FEW}{cnt[j]} sub-pixel edge points"
        sel = np.array([err_a[j] is None and cnt[j] >= MIN_EDGE_POINTS for j in range(len(ai))], bool)  # (a
        # steering pass leaves a dot with too few points on its previous ellipse)
        if last:
            pts = np.zeros((D,) + p_a.shape[1:])
            mask = np.zeros((D, p_a.shape[1]), bool)
            pts[ai] = p_a
            mask[ai] = m_a
        if not np.any(sel):  # no dot to fit: the next pass measures them on their previous ellipses
            continue
        fi = ai[sel]
        P, M = p_a[sel], m_a[sel]
        Qa = np.empty((len(fi), 3, 3))
        ferr = np.zeros(len(fi), np.int64)
        _fit_pass_kernel(
            P,
            M,
            np.ascontiguousarray(sl_a[sel]),
            OUTLIER_MIN_PX,
            OUTLIER_SIGMAS,
            MAD_TO_SIGMA,
            MIN_EDGE_POINTS,
            Qa,
            ferr,
        )
        if last:
            mask[fi] = M
            for j in np.nonzero(ferr)[0]:
                errors[fi[j]] = FIT_ERRORS[int(ferr[j])]
            Q[fi] = Qa
        else:  # (a steering pass's failed fit leaves the dot on its previous ellipse)
            Q[fi[ferr == 0]] = Qa[ferr == 0]
    return pts, mask, Q, errors


@njit(cache=True, nogil=True)
def _fit_pass_kernel(P, mask, slack, min_px, sigmas, mad_to_sigma, min_points, Q, err):
    """One pass's fit of the edge points ``P`` (D, M, 2) where ``mask`` (D, M): the direct ellipse fit of each row
    (``Q`` (D, 3, 3), ``err`` (D,) zeros on entry: :func:`~circcal.detector.measure.ellipsefit._fit_kernel`), then the points
    within the outlier rule (the Sampson distances within ``max(sigmas * robust sigma, min_px + slack)``, the
    robust sigma from the median absolute deviation of each row: :func:`~circcal.detector.measure.robust.mad_inliers`;
    ``slack`` (D, M) each point's uncorrected curvature shift), refitted once to those where some were left out and
    ``min_points`` remain: their ``mask`` rows become the kept points, ``Q`` and ``err`` the refit's. The numpy
    steps' values, in their order."""
    D, M = mask.shape
    _fit_kernel(P, mask, Q, err)
    m = np.zeros((D, M), np.bool_)
    for d in range(D):
        if err[d] == 0:
            m[d] = mask[d]
    dist = np.empty((D, M))
    _sampson_kernel(P, Q, dist)
    floor = np.empty((D, M))
    for d in range(D):
        for i in range(M):
            floor[d, i] = min_px + slack[d, i]
    inl = np.zeros((D, M), np.bool_)
    _mad_inliers_kernel(dist, m, floor, sigmas, mad_to_sigma, inl)
    n_refit = 0
    refit = np.zeros(D, np.bool_)
    for d in range(D):
        nk = 0
        nm = 0
        for i in range(M):
            inl[d, i] = m[d, i] and inl[d, i]
            nk += inl[d, i]
            nm += m[d, i]
        refit[d] = err[d] == 0 and nk < nm and nk >= min_points
        n_refit += refit[d]
    if n_refit == 0:
        return
    ri = np.nonzero(refit)[0]
    Pr = np.empty((n_refit, M, 2))
    Kr = np.empty((n_refit, M), np.bool_)
    for j in range(n_refit):
        Pr[j] = P[ri[j]]
        Kr[j] = inl[ri[j]]
    Qr = np.empty((n_refit, 3, 3))
    rerr = np.zeros(n_refit, np.int64)
    _fit_kernel(Pr, Kr, Qr, rerr)
    for j in range(n_refit):
        d = ri[j]
        mask[d] = Kr[j]
        Q[d] = Qr[j]
        err[d] = rerr[j]
