"""Pre-processing, segmentation, candidate dots and sub-pixel edge points of dark dots on a bright board.

Pipeline pieces used by :mod:`circcal.detect`:

* :func:`to_gray` -- any uint8/uint16/float, grey or BGR(A) image -> float64 grey, linear in the input values.
* :func:`segmentations` -- binary masks (255 = dark) that survive uneven, strong and weak illumination: Otsu on an
  edge-preserving denoised image (``cv2.ximgproc.guidedFilter``), then local (adaptive-mean) thresholds at window
  sizes scaled to the image.
* :func:`find_candidates` -- outer contours filtered by area (limits scaled to image and grid size), circularity
  ``4 pi S / P^2``, inertia ratio and convexity ``S / hull area``.
* :func:`subpixel_edge_points` -- sub-pixel boundary points of one dot: along the normals of a current ellipse the
  image (lightly Gaussian-smoothed, cubic-spline interpolated) is sampled, and the point where the profile crosses
  the local half level between the dot's dark level and the board's bright level (fitted as a plane around the dot,
  so an illumination gradient does not move the edges) is interpolated. For any symmetric blur of a straight edge
  this crossing is the edge itself (and it is where the gradient magnitude along the normal peaks); with a
  smoothing scale matched to the edge width it is the efficient (Cramer-Rao) estimator of the edge position, which
  the gradient-peak location is not (``method="gradient"`` gives the gradient-peak variant).

Pixel convention: OpenCV's (integer coordinates are pixel centres). Arrays: ``(M, 2)`` points as ``(x, y)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from .ellipse import conic_from_params, conic_params, ellipse_normals, sample_ellipse

__all__ = ["Candidate", "to_gray", "normalise_u8", "segmentations", "find_candidates", "subpixel_edge_points",
           "dot_levels"]


@dataclass
class Candidate:
    """A dark blob that may be a dot. ``center`` (2,) px area centroid of the contour polygon; ``axes`` (a, b)
    semi-axes (px) and ``angle`` (rad) of the ellipse with the same second moments; ``area`` px^2."""

    center: np.ndarray
    axes: tuple[float, float]
    angle: float
    area: float

    @property
    def conic(self) -> np.ndarray:
        return conic_from_params(self.center, self.axes, self.angle)


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3|4) BGR(A) image of dtype uint8, uint16 or float -> (H, W) float64 grey, same scale as
    the input values. Raises ``ValueError`` for other shapes or dtypes."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3:
        if img.shape[2] not in (3, 4):
            raise ValueError(f"colour image must have 3 (BGR) or 4 (BGRA) channels, got {img.shape[2]}")
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = cv2.cvtColor(img.astype(np.float32) if img.dtype == np.float64 else img, code)
    if img.ndim != 2:
        raise ValueError(f"expected a (H, W) grey or (H, W, 3) BGR image, got shape {np.shape(image)}")
    if not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)) or img.dtype == bool:
        raise ValueError(f"unsupported image dtype {img.dtype}; expected uint8, uint16 or float")
    if min(img.shape) < 8:
        raise ValueError(f"image too small: {img.shape[1]}x{img.shape[0]}")
    out = img.astype(np.float64)
    if not np.all(np.isfinite(out)):
        raise ValueError("image contains NaN or inf")
    return out


def normalise_u8(gray: np.ndarray) -> np.ndarray:
    """Stretch the 0.5-99.5 percentile range of ``gray`` to uint8 (for thresholding only)."""
    sub = gray[::4, ::4] if gray.size > 400_000 else gray
    lo, hi = np.percentile(sub, [0.5, 99.5])
    if hi <= lo:
        hi = lo + 1e-9
    return np.clip((gray - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def _odd(n: float) -> int:
    n = int(round(n))
    return max(3, n | 1)


def segmentations(gray_u8: np.ndarray):
    """Yield ``(name, mask)``: uint8 masks, 255 where the image is dark (dot candidates), in the order worth trying.

    1. Otsu on the guided-filtered image (edge-preserving denoise; global illumination).
    2. Adaptive-mean thresholds with windows of 1/8 and 1/3 of the shorter image side (uneven illumination,
       shadows, weak contrast); the offset is 8% of the global contrast.
    """
    H, W = gray_u8.shape
    g = gray_u8.astype(np.float32) / 255.0
    radius = max(2, int(round(min(H, W) / 400)))
    try:
        filt = cv2.ximgproc.guidedFilter(g, g, radius, 0.02 ** 2)
    except AttributeError:  # opencv without contrib: a bilateral filter is the nearest edge-preserving denoise
        filt = cv2.bilateralFilter(g, 2 * radius + 1, 0.1, radius)
    f8 = np.clip(filt * 255.0 + 0.5, 0, 255).astype(np.uint8)
    _, otsu = cv2.threshold(f8, 0, 255, cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)
    yield "otsu", otsu
    for frac in (8.0, 3.0, 16.0):
        block = _odd(min(H, W) / frac)
        yield f"adaptive{block}", cv2.adaptiveThreshold(f8, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV,
                                                        block, 255 * 0.08)


def find_candidates(
    mask: np.ndarray,
    *,
    min_area: float,
    max_area: float,
    min_circularity: float = 0.45,
    min_inertia: float = 0.08,
    min_convexity: float = 0.8,
) -> list[Candidate]:
    """Dark blobs of ``mask`` (uint8, 255 = dark) that look like imaged dots.

    Outer contours only (a dot is a filled component); kept when ``min_area <= area <= max_area`` (px^2),
    circularity ``4 pi S / P^2 >= min_circularity``, inertia ratio (minor/major second moment, ``(b/a)^2``)
    ``>= min_inertia``, convexity ``S / hull area >= min_convexity``, and the blob does not touch the image border.
    """
    H, W = mask.shape
    contours, hier = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    out: list[Candidate] = []
    if hier is None:
        return out
    for cnt, h in zip(contours, hier[0]):
        if h[3] != -1 or len(cnt) < 5:
            continue
        m = cv2.moments(cnt)
        S = m["m00"]
        if not (min_area <= S <= max_area):
            continue
        x, y, w, hh = cv2.boundingRect(cnt)
        if x <= 0 or y <= 0 or x + w >= W or y + hh >= H:
            continue
        P = cv2.arcLength(cnt, True)
        if 4.0 * np.pi * S / (P * P) < min_circularity:
            continue
        hull = cv2.contourArea(cv2.convexHull(cnt))
        if hull <= 0 or S / hull < min_convexity:
            continue
        mu20, mu02, mu11 = m["mu20"] / S, m["mu02"] / S, m["mu11"] / S
        tr = mu20 + mu02
        disc = np.sqrt(max(0.0, (mu20 - mu02) ** 2 + 4 * mu11 ** 2))
        l1, l2 = 0.5 * (tr + disc), 0.5 * (tr - disc)
        if l1 <= 0 or l2 / l1 < min_inertia:
            continue
        ang = 0.5 * np.arctan2(2 * mu11, mu20 - mu02)
        c = np.array([m["m10"] / S, m["m01"] / S])
        out.append(Candidate(c, (2.0 * np.sqrt(l1), 2.0 * np.sqrt(max(l2, 1e-12))), float(ang), float(S)))
    return out


def dot_levels(img: np.ndarray, Q: np.ndarray, origin: tuple[int, int], edge_px: float = 2.0
               ) -> tuple[float, np.ndarray] | None:
    """Dark level inside a dot and the bright level around it as a plane.

    ``img``: ROI (h, w) float; ``Q``: the dot's ellipse in full-image pixels; ``origin``: (x0, y0) of the ROI.
    Returns ``(dark, plane)`` with ``plane`` (3,) so that bright(x, y) = plane @ (x, y, 1) in full-image pixels,
    or ``None`` when there are not enough pixels.
    """
    c, (a, b), ang = conic_params(Q)
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w]
    xx = xx + origin[0]
    yy = yy + origin[1]
    dx, dy = xx - c[0], yy - c[1]
    ca, sa = np.cos(ang), np.sin(ang)
    u = (ca * dx + sa * dy) / a
    v = (-sa * dx + ca * dy) / b
    rho = np.sqrt(u * u + v * v)
    inner = rho < 1.0 - edge_px / b
    vals_in = img[inner]
    if vals_in.size < 3:
        order = np.argsort(rho, axis=None)[:3]
        vals_in = img.ravel()[order]
    dark = float(np.median(vals_in))
    ring = (rho > 1.0 + edge_px / b) & (rho < 1.0 + (edge_px + max(2.0, 0.5 * b)) / b)
    if np.count_nonzero(ring) < 8:
        return None
    vals = img[ring]
    xs, ys = xx[ring].astype(np.float64), yy[ring].astype(np.float64)
    mid = 0.5 * (dark + np.median(vals))
    keep = vals > mid  # drop neighbouring dots and dark clutter in the ring
    if np.count_nonzero(keep) < 6:
        return None
    A = np.column_stack([xs[keep], ys[keep], np.ones(np.count_nonzero(keep))])
    plane, *_ = np.linalg.lstsq(A, vals[keep], rcond=None)
    res = vals[keep] - A @ plane
    s = 1.4826 * np.median(np.abs(res)) + 1e-12
    ok = np.abs(res) < 4 * s
    if np.count_nonzero(ok) >= 6 and not np.all(ok):
        plane, *_ = np.linalg.lstsq(A[ok], vals[keep][ok], rcond=None)
    return dark, plane


def subpixel_edge_points(
    img: np.ndarray,
    Q: np.ndarray,
    *,
    sigma: float = 0.7,
    spacing: float = 1.0,
    step: float = 0.2,
    method: str = "level",
    curvature_correction: bool = True,
) -> np.ndarray:
    """Sub-pixel boundary points of the dark dot near the ellipse ``Q`` (3, 3) in the grey image ``img`` (H, W).

    Profiles along the ellipse normals, one per ``spacing`` px of perimeter, sampled every ``step`` px on the image
    smoothed by a Gaussian of ``sigma`` px (cubic-spline interpolation). ``method="level"``: where the profile
    crosses the local half level (see module docstring); ``"gradient"``: the peak of the derivative along the normal
    (3-point Gaussian interpolation). With ``curvature_correction`` (level method) each point is moved outwards by
    the exact shift of the half-level contour of a blurred disk with the ellipse's local radius of curvature (the
    level set of a blurred convex shape lies inside it by ~ sigma_t^2 / (2 rho)), sigma_t measured from the edge
    slope. Returns (M, 2) px; profiles without a clear edge are dropped (M may be small;
    the caller decides).
    """
    c, (a, b), _ = conic_params(Q)
    H, W = img.shape
    hw = min(3.0, max(1.0, 0.8 * b))
    pad = hw + 3.0 * sigma + 4.0
    x0 = max(0, int(np.floor(c[0] - a - pad)))
    x1 = min(W, int(np.ceil(c[0] + a + pad)) + 1)
    y0 = max(0, int(np.floor(c[1] - a - pad)))
    y1 = min(H, int(np.ceil(c[1] + a + pad)) + 1)
    roi = np.ascontiguousarray(img[y0:y1, x0:x1], dtype=np.float64)
    if roi.shape[0] < 4 or roi.shape[1] < 4:
        return np.empty((0, 2))
    smooth = cv2.GaussianBlur(roi, (0, 0), sigma, borderType=cv2.BORDER_REFLECT) if sigma > 0 else roi
    coef = ndimage.spline_filter(smooth, order=3, mode="mirror")
    # one profile per `spacing` px of perimeter (Ramanujan's approximation)
    hab = ((a - b) / (a + b)) ** 2
    perim = np.pi * (a + b) * (1 + 3 * hab / (10 + np.sqrt(4 - 3 * hab)))
    n = int(max(24, np.ceil(perim / spacing)))
    base = sample_ellipse(Q, n)
    nrm = ellipse_normals(Q, base)
    s = np.arange(-hw, hw + 1e-9, step)
    pts = base[:, None, :] + s[None, :, None] * nrm[:, None, :]  # (n, k, 2)
    inside = ((pts[..., 0] >= x0 + 1) & (pts[..., 0] <= x1 - 2) & (pts[..., 1] >= y0 + 1)
              & (pts[..., 1] <= y1 - 2)).all(axis=1)
    coords = np.stack([pts[..., 1] - y0, pts[..., 0] - x0])
    prof = ndimage.map_coordinates(coef, coords.reshape(2, -1), order=3, mode="mirror", prefilter=False)
    prof = prof.reshape(n, len(s))
    if method == "level":
        lv = dot_levels(roi, Q, (x0, y0))
        if lv is None:
            return np.empty((0, 2))
        dark, plane = lv
        bright_c = plane @ np.array([c[0], c[1], 1.0])
        if not bright_c > dark:
            return np.empty((0, 2))
        ratio = dark / bright_c
        half = (pts[..., 0] * plane[0] + pts[..., 1] * plane[1] + plane[2]) * (0.5 * (1.0 + ratio))
        f = prof - half
        up = (f[:, :-1] < 0) & (f[:, 1:] >= 0)
        # the crossing nearest to the current boundary
        dist = np.abs(0.5 * (s[:-1] + s[1:]))[None, :]
        score = np.where(up, dist, np.inf)
        k = np.argmin(score, axis=1)
        ok = np.isfinite(score[np.arange(n), k]) & inside
        fa = f[np.arange(n), k]
        fb = f[np.arange(n), k + 1]
        t = fa / (fa - fb)
        off = s[k] + t * step
        if curvature_correction:
            # edge width from the slope at the crossing: a Gaussian-blurred step of height A has slope
            # A / (sqrt(2 pi) sigma_t); the pixel box (variance 1/12) and our smoothing set a lower bound.
            span = (pts[ok, k[ok], 0] * plane[0] + pts[ok, k[ok], 1] * plane[1] + plane[2]) * (1.0 - ratio)
            slope = (fb[ok] - fa[ok]) / step
            with np.errstate(divide="ignore", invalid="ignore"):
                st = span / (np.sqrt(2.0 * np.pi) * slope)
            st = st[np.isfinite(st) & (st > 0)]
            nominal = np.sqrt(sigma * sigma + 1.0 / 12.0)
            sigma_t = max(nominal, float(np.median(st))) if st.size else nominal
            off = off + _curvature_shift(Q, base, sigma_t)
    elif method == "gradient":
        d = np.gradient(prof, step, axis=1)
        k = np.clip(np.argmax(d[:, 1:-1], axis=1) + 1, 1, len(s) - 2)
        r = np.arange(n)
        dm, d0, dp = d[r, k - 1], d[r, k], d[r, k + 1]
        ok = inside & (dm > 0) & (d0 > 0) & (dp > 0) & (d0 >= dm) & (d0 >= dp)
        lm, l0, lp = (np.log(np.maximum(v, 1e-300)) for v in (dm, d0, dp))
        den = lm - 2 * l0 + lp
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.where(den < 0, 0.5 * (lm - lp) / den, 0.0)
        ok &= np.abs(frac) <= 1.0
        off = s[k] + frac * step
    else:
        raise ValueError(f"unknown edge method {method!r}; expected 'level' or 'gradient'")
    return base[ok] + off[ok, None] * nrm[ok]


def _half_level_radius(u: np.ndarray) -> np.ndarray:
    """For a dark disk of radius ``u`` (in units of the Gaussian blur sigma), the radius ``v`` where the blurred
    image reaches the half level: P(|X + v| <= u) = 1/2 for X ~ N(0, I_2), i.e. ``chndtr(u^2, 2, v^2) = 1/2``.
    NaN where the blurred disk never reaches half darkness (u < sqrt(2 ln 2))."""
    from scipy.special import chndtr

    u = np.asarray(u, dtype=np.float64)
    lo = np.zeros_like(u)
    hi = u.copy()
    for _ in range(60):  # bisection; the dark fraction decreases with v
        mid = 0.5 * (lo + hi)
        darker = chndtr(u * u, 2.0, mid * mid) > 0.5
        lo = np.where(darker, mid, lo)
        hi = np.where(darker, hi, mid)
    v = 0.5 * (lo + hi)
    return np.where(u > np.sqrt(2.0 * np.log(2.0)) + 1e-9, v, np.nan)


_U_TABLE = np.geomspace(1.2, 60.0, 400)
_SHIFT_TABLE: np.ndarray | None = None


def _curvature_shift(Q: np.ndarray, points: np.ndarray, sigma_t: float) -> np.ndarray:
    """(M,) outward shift (px) from the half-level contour to the true edge at ``points`` (M, 2) of the ellipse
    ``Q``, modelling the edge locally by its osculating circle blurred by a Gaussian of ``sigma_t`` px."""
    global _SHIFT_TABLE
    if _SHIFT_TABLE is None:
        _SHIFT_TABLE = _U_TABLE - _half_level_radius(_U_TABLE)
    c, (a, b), ang = conic_params(Q)
    d = points - c
    ca, sa = np.cos(ang), np.sin(ang)
    x = ca * d[:, 0] + sa * d[:, 1]
    y = -sa * d[:, 0] + ca * d[:, 1]
    t = np.arctan2(y / b, x / a)
    rho = (a * a * np.sin(t) ** 2 + b * b * np.cos(t) ** 2) ** 1.5 / (a * b)  # radius of curvature
    u = rho / sigma_t
    shift = np.where(u > _U_TABLE[-1], 0.5 / np.maximum(u, 1e-9),
                     np.interp(u, _U_TABLE, _SHIFT_TABLE, left=_SHIFT_TABLE[0]))
    # the osculating-circle model fails where the curvature changes within the blur (tight ends of thin
    # ellipses): no correction below u = 1.5, full above 2.5
    return sigma_t * shift * np.clip(u - 1.5, 0.0, 1.0)
