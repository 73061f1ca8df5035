"""Pre-processing, segmentation, candidate dots and sub-pixel edge points of dark dots on a bright board.

Pipeline pieces used by :mod:`circcal.detector`:

* :func:`to_gray` -- any uint8/uint16/float, grey or BGR(A) image -> float64 grey, linear in the input values.
* :func:`segmentations` -- binary masks (255 = dark) that survive uneven, strong and weak illumination: Otsu on an
  edge-preserving denoised image (self-guided filter, :func:`guided_filter`), then local (adaptive-mean) thresholds
  at window sizes scaled to the image.
* :func:`find_candidates` -- outer contours filtered by area (limits scaled to image and grid size), circularity
  ``4 pi S / P^2``, inertia ratio and convexity ``S / hull area``.
* :func:`subpixel_edge_points` -- sub-pixel boundary points of one dot: along the normals of a current ellipse the
  image (lightly Gaussian-smoothed, cubic-spline interpolated) is sampled, and the point where the profile crosses
  the local half level between the dot's dark level and the board's bright level (fitted as a plane around the dot,
  so an illumination gradient does not move the edges) is interpolated. For any symmetric blur of a straight edge
  this crossing is the edge itself (and it is where the gradient magnitude along the normal peaks); with a
  smoothing scale matched to the edge width it is the efficient (Cramer-Rao) estimator of the edge position, which
  the gradient-peak location is not (``method="gradient"`` gives the gradient-peak variant).

All dots are measured at once (:func:`subpixel_edge_points_batch`): the Gaussian smoothing and spline prefilter of
one crop per dot, all crops filtered by one OpenCV call (:class:`SmoothedImage`); the per-pixel work is compiled
(numba, cached on disk): the levels of each dot in one pass over its pixels (:func:`_levels_kernel`; medians of uint8
images from histograms), the profile geometry (:func:`_profiles_kernel`), and the nearest crossing of each profile
(:func:`_crossings_kernel`: intervals examined nearest the current boundary first, each spline sample computed once
when first needed; the nearest crossing is the same as with the whole profile sampled). :func:`subpixel_edge_points`
is the one-dot form.

Pixel convention: OpenCV's (integer coordinates are pixel centres). Arrays: ``(M, 2)`` points as ``(x, y)``.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from circcal.errors import ImageError
from circcal.detector.ellipse import conic_from_params, conic_params_batch
from circcal.detector.jit import njit

__all__ = ["Candidate", "to_gray", "as_gray", "normalise_u8", "segmentations", "find_candidates",
           "subpixel_edge_points", "subpixel_edge_points_batch", "SmoothedImage", "dot_levels", "dot_levels_batch",
           "guided_filter"]


@dataclass
class Candidate:
    """A dark blob that may be a dot. ``center`` (2,) px area centroid of the contour polygon; ``axes`` (a, b)
    semi-axes (px) and ``angle`` (rad) of the ellipse with the same second moments; ``area`` px^2."""

    centre: np.ndarray
    axes: tuple[float, float]
    angle: float
    area: float

    @property
    def conic(self) -> np.ndarray:
        return conic_from_params(self.centre, self.axes, self.angle)


def as_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3|4) BGR(A) image of dtype uint8, uint16 or float -> (H, W) grey in its own dtype (colour
    converted by ``cv2.cvtColor``; float64 colour via float32 as in :func:`to_gray`). Raises :class:`~circcal.errors.ImageError` for other
    shapes or dtypes, and for NaN/inf."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3:
        if img.shape[2] not in (3, 4):
            raise ImageError(f"colour image must have 3 (BGR) or 4 (BGRA) channels, got {img.shape[2]}")
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = cv2.cvtColor(img.astype(np.float32) if img.dtype == np.float64 else img, code)
    if img.ndim != 2:
        raise ImageError(f"expected a (H, W) grey or (H, W, 3) BGR image, got shape {np.shape(image)}")
    if not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)) or img.dtype == bool:
        raise ImageError(f"unsupported image dtype {img.dtype}; expected uint8, uint16 or float")
    if min(img.shape) < 8:
        raise ImageError(f"image too small: {img.shape[1]}x{img.shape[0]}")
    if np.issubdtype(img.dtype, np.floating) and not np.all(np.isfinite(img)):
        raise ImageError("image contains NaN or inf")
    return img


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3|4) BGR(A) image of dtype uint8, uint16 or float -> (H, W) float64 grey, same scale as
    the input values. Raises ``ValueError`` for other shapes or dtypes."""
    return as_gray(image).astype(np.float64)


def normalise_u8(gray: np.ndarray) -> np.ndarray:
    """Stretch the 0.5-99.5 percentile range of ``gray`` (H, W) to uint8 (for thresholding only). Integer images
    (uint8/uint16, e.g. from :func:`as_gray`): percentiles of all pixels from their histogram, the stretch through a
    lookup table of the same formula (identical results); float images: percentiles of every 4th pixel in each
    direction above 400k pixels."""
    if gray.dtype in (np.uint8, np.uint16):
        lo, hi = _histogram_percentiles(gray, (0.5, 99.5))
    else:
        sub = gray[::4, ::4] if gray.size > 400_000 else gray
        lo, hi = np.percentile(sub.astype(np.float64), [0.5, 99.5])
    if hi <= lo:
        hi = lo + 1e-9
    scale = 255.0 / (hi - lo)
    if gray.dtype in (np.uint8, np.uint16):
        lut = np.clip((np.arange(np.iinfo(gray.dtype).max + 1, dtype=np.float64) - lo) * scale, 0, 255)
        lut = lut.astype(np.uint8)
        return cv2.LUT(gray, lut) if gray.dtype == np.uint8 else lut[gray]
    return np.clip((gray.astype(np.float64) - lo) * scale, 0, 255).astype(np.uint8)


def _histogram_percentiles(img: np.ndarray, q: tuple[float, ...]) -> np.ndarray:
    """``np.percentile(img, q)`` (linear interpolation between order statistics) of an integer image, from its
    histogram: O(pixels), no sort."""
    if img.dtype == np.uint8 and img.size < 2 ** 24:   # (float32 counts: exact below 2^24)
        cum = np.cumsum(cv2.calcHist([img], [0], None, [256], [0, 256]).reshape(-1).astype(np.int64))
    else:
        cum = np.cumsum(np.bincount(img.ravel(), minlength=1))
    n = int(cum[-1])
    h = (n - 1) * np.asarray(q, np.float64) / 100.0
    k = np.floor(h).astype(np.int64)
    lo = np.searchsorted(cum, k, side="right")                          # the k-th smallest value (0-based)
    hi = np.searchsorted(cum, np.minimum(k + 1, n - 1), side="right")
    return lo + (h - k) * (hi - lo)


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
    radius = max(2, int(round(min(H, W) / 400)))
    f8 = guided_filter(gray_u8, radius, 0.02 ** 2)
    _, otsu = cv2.threshold(f8, 0, 255, cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)
    yield "otsu", otsu
    for frac in (8.0, 3.0, 16.0):
        block = _odd(min(H, W) / frac)
        yield f"adaptive{block}", cv2.adaptiveThreshold(f8, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV,
                                                        block, 255 * 0.08)


def guided_filter(gray_u8: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """Self-guided filter (He, Sun & Tang 2013) of a uint8 image: ``cv2.ximgproc.guidedFilter(g, g, radius, eps)``
    on ``g = gray_u8 / 255`` (``eps`` in units of the [0, 1] intensity range), rounded back to uint8.
    The edge-preserving denoise the paper uses before segmentation; OpenCV's implementation, not ours."""
    g = gray_u8.astype(np.float32) * np.float32(1.0 / 255.0)
    out = cv2.ximgproc.guidedFilter(g, g, int(radius), float(eps))
    return cv2.convertScaleAbs(out, alpha=255.0)


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


def _masked_median(vals: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(D,) median of ``vals[d][mask[d]]`` per row of (D, P) arrays (as ``np.median``: the mean of the two middle
    values for an even count; NaN for an empty row)."""
    vals = np.asarray(vals, np.float64).reshape(len(mask), -1)
    mask = np.asarray(mask, bool).reshape(vals.shape)
    m = mask.sum(axis=1)
    if vals.shape[1] == 0:
        return np.full(len(m), np.nan)
    srt = np.sort(np.where(mask, vals, np.inf), axis=1)
    rows = np.arange(len(m))
    lo = np.clip((m - 1) // 2, 0, vals.shape[1] - 1)
    hi = np.clip(m // 2, 0, vals.shape[1] - 1)
    return np.where(m > 0, 0.5 * (srt[rows, lo] + srt[rows, hi]), np.nan)


class SmoothedImage:
    """A grey image (H, W) and its Gaussian smoothing (``sigma`` px, reflected borders) as cubic B-spline coefficients
    (mirror boundary), computed on demand in one crop per requested box (one box per dot), for sampling edge profiles.

    A crop extends beyond its box (clipped to the image) by the reach of its filters plus the spline's own support,
    so samples inside the box equal those of smoothing the whole image. The prefilter is the exact recursive B-spline
    filter written as its (symmetric, exponentially decaying) impulse response truncated at
    :data:`PREFILTER_HALF_LENGTH` taps (a 5e-8 share of its weight is left out). Both filters run in float32 (values
    good to ~1e-7 relative, edge points to ~1e-6 px): the crops inside the image as one separable filter (Gaussian and
    prefilter convolved, the product's tails truncated at the same 5e-8 share: :func:`_combined_kernel`, reach
    :attr:`margin` - 3) on all of them stacked (``cv2.sepFilter2D``), crops at the image border each on their own
    with the border reflections (``cv2.GaussianBlur`` then the prefilter, reach :attr:`border_margin` - 3). The
    coefficients of all crops are sampled from one stacked atlas (compiled cubic B-spline evaluation, or
    ``map_coordinates`` in :meth:`sample`). A later box reuses the crop
    made for the same dot (a crop holding the box, centred within :attr:`REUSE_PX` px of it), so a dot's samples
    depend on that dot alone: measuring all dots at once gives the same points as one at a time. ``gray`` may be any
    real dtype.
    """

    SLACK = 4
    REUSE_PX = 4.0

    def __init__(self, gray: np.ndarray, sigma: float):
        self.gray = gray
        self.sigma = float(sigma)
        self.crops: list[tuple[int, int, int, int]] = []   # x0, y0, x1, y1 (exclusive) of each crop
        self._sheets: list[np.ndarray] = []                # float32 coefficients of crops stacked top to bottom
        self._place: list[tuple[int, int]] = []            # (sheet, first row) of each crop
        self._atlas: np.ndarray | None = None              # all sheets stacked
        self._rows = np.zeros(0, int)                      # first atlas row of each crop

    @property
    def shape(self) -> tuple[int, int]:
        return self.gray.shape

    @property
    def margin(self) -> int:
        """Pixels a crop inside the image extends beyond its box: combined filter half length + spline support."""
        return len(_combined_kernel(self.sigma)) // 2 + 3

    @property
    def border_margin(self) -> int:
        """Pixels a crop at the image border extends beyond its box: Gaussian radius + prefilter half length +
        spline support."""
        return _gauss_radius(self.sigma) + PREFILTER_HALF_LENGTH + 3

    def crops_for(self, boxes: np.ndarray) -> np.ndarray:
        """(D,) crop index for each box of ``boxes`` (D, 4) float ``x0, y0, x1, y1`` px (the extent of the points to
        be sampled; rows with NaN get -1), making the crops that are missing."""
        H, W = self.gray.shape
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        out = np.full(len(boxes), -1)
        todo = np.all(np.isfinite(boxes), axis=1)
        if not np.any(todo):
            return out
        m = self.margin
        f = np.floor(boxes[todo]).astype(int)
        need = np.stack([np.maximum(0, f[:, 0] - m), np.maximum(0, f[:, 1] - m),
                         np.minimum(W, f[:, 2] + 1 + m), np.minimum(H, f[:, 3] + 1 + m)], axis=1)   # (T, 4)
        idx = np.nonzero(todo)[0]
        if self.crops:
            have = np.array(self.crops)                                                         # (C, 4)
            r = 2.0 * self.REUSE_PX
            hit = ((have[None, :, 0] <= need[:, None, 0]) & (have[None, :, 1] <= need[:, None, 1])
                   & (have[None, :, 2] >= need[:, None, 2]) & (have[None, :, 3] >= need[:, None, 3])
                   & (np.abs((have[None, :, 0] + have[None, :, 2]) - (need[:, 0] + need[:, 2])[:, None]) <= r)
                   & (np.abs((have[None, :, 1] + have[None, :, 3]) - (need[:, 1] + need[:, 3])[:, None]) <= r))
            found = hit.any(axis=1)
            out[idx[found]] = np.argmax(hit[found], axis=1)
            idx, need = idx[~found], need[~found]
        sl = self.SLACK
        new = [(max(0, x0 - sl), max(0, y0 - sl), min(W, x1 + sl), min(H, y1 + sl)) for x0, y0, x1, y1 in need.tolist()]
        grow = self.border_margin - m   # crops that reach the border are filtered in two steps, reaching further
        new = [c if c[0] > 0 and c[1] > 0 and c[2] < W and c[3] < H else
               (max(0, c[0] - grow), max(0, c[1] - grow), min(W, c[2] + grow), min(H, c[3] + grow)) for c in new]
        # crops inside the image are filtered together, stacked in one array (the filters reach less than the margin,
        # so each crop's box only sees its own pixels; a pixel's arithmetic does not depend on where its crop sits);
        # crops at the image border each on their own, with the borders' reflections
        inner = [k for k, c in enumerate(new) if c[0] > 0 and c[1] > 0 and c[2] < W and c[3] < H]
        place: dict[int, tuple[int, int]] = {}
        if inner:
            stack = _stacked([self.gray[c[1]:c[3], c[0]:c[2]] for c in (new[k] for k in inner)])
            k1 = _combined_kernel(self.sigma)
            self._sheets.append(cv2.sepFilter2D(stack, cv2.CV_32F, k1, k1, borderType=cv2.BORDER_REFLECT_101))
            starts = np.cumsum([0] + [new[k][3] - new[k][1] for k in inner]).tolist()
            place.update((k, (len(self._sheets) - 1, r0)) for k, r0 in zip(inner, starts))
        for k, c in enumerate(new):
            if k not in place:
                self._sheets.append(_spline_coefficients(self.gray[c[1]:c[3], c[0]:c[2]], self.sigma))
                place[k] = (len(self._sheets) - 1, 0)
        for k, (d, c) in enumerate(zip(idx.tolist(), new)):
            self._place.append(place[k])
            self.crops.append(c)
            out[d] = len(self.crops) - 1
        if new:
            self._atlas = None
        return out

    def coefficient_atlas(self, crop: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The spline coefficients of all crops stacked (float32 (R, C)), and for the crops ``crop`` (D,) (indices
        from :meth:`crops_for`; -1 gives zeros) their first atlas row (D,) int and origin (D, 2) float ``x0, y0``:
        the coefficient of image pixel (x, y) of crop k is ``atlas[rows[k] + y - y0, x - x0]``."""
        if self._atlas is None:
            self._atlas = self._sheets[0] if len(self._sheets) == 1 else _stacked(self._sheets)
            first = np.cumsum([0] + [s.shape[0] for s in self._sheets])
            self._rows = np.array([first[s] + r0 for s, r0 in self._place], np.int64)
        crop = np.asarray(crop, np.int64)
        valid = crop >= 0
        rows = np.where(valid, self._rows[np.where(valid, crop, 0)] if len(self._rows) else 0, 0)
        org = np.array(self.crops, np.float64).reshape(-1, 4)[np.where(valid, crop, 0), :2] if self.crops else\
            np.zeros((len(crop), 2))
        return self._atlas, rows.astype(np.int64), np.where(valid[:, None], org, 0.0)

    def sample(self, crop: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Smoothed image at points (x, y) px (1-D arrays) from the crops ``crop`` (same length, indices from
        :meth:`crops_for`; the points must lie inside their crop's box), cubic B-spline."""
        atlas, rows, org = self.coefficient_atlas(crop)
        coords = np.empty((2, len(crop)))
        np.subtract(y, org[:, 1], out=coords[0])
        coords[0] += rows
        np.subtract(x, org[:, 0], out=coords[1])
        return ndimage.map_coordinates(atlas, coords, order=3, mode="mirror", prefilter=False, output=np.float64)


PREFILTER_HALF_LENGTH = 13
"""Taps on either side of the FIR form of the cubic B-spline prefilter (the recursive filter's impulse response
sqrt(3) z^|k|, z = sqrt(3) - 2, is below 1e-8 of its peak beyond 13 taps; the left-out tail is 5e-8 of its weight)."""


def _gauss_radius(sigma: float) -> int:
    """Radius of OpenCV's Gaussian kernel for float images (``ksize = round(8 sigma + 1) | 1``); 0 for no blur."""
    return (int(round(8.0 * sigma + 1.0)) | 1) // 2 if sigma > 0 else 0


@functools.lru_cache(maxsize=1)
def _prefilter_kernel() -> np.ndarray:
    """(2 L + 1,) float32 FIR cubic B-spline prefilter (interpolation coefficients from samples), normalised to a sum
    of 1 (so a constant image keeps its value)."""
    z = np.sqrt(3.0) - 2.0
    k = np.sqrt(3.0) * z ** np.abs(np.arange(-PREFILTER_HALF_LENGTH, PREFILTER_HALF_LENGTH + 1))
    return (k / k.sum()).astype(np.float32)


COMBINED_TAIL = 5e-8
"""Share of the combined (Gaussian * prefilter) kernel's weight its truncation may leave out (as the prefilter's)."""


@functools.lru_cache(maxsize=8)
def _combined_kernel(sigma: float) -> np.ndarray:
    """(2 h + 1,) float32: OpenCV's Gaussian kernel of ``sigma`` (radius r, none for 0) convolved with the FIR
    prefilter (half length L): smoothing and prefiltering in one separable filter (away from the image borders).
    The product's tails decay like the prefilter's; they are cut where at most :data:`COMBINED_TAIL` of the weight
    is left out (h = 11 instead of r + L = 19 for sigma 1.5: 23 taps, not 39) and the rest renormalised to a sum of 1.
    """
    k = _prefilter_kernel().astype(np.float64)
    r = _gauss_radius(sigma)
    if r:
        k = np.convolve(k, cv2.getGaussianKernel(2 * r + 1, sigma, cv2.CV_64F)[:, 0])
    n = len(k) // 2
    tail = np.cumsum(np.abs(k[::-1][:n]))[::-1] * 2.0 / np.abs(k).sum()   # tail[j]: weight beyond half length j
    h = next((j for j in range(1, n) if tail[j] <= COMBINED_TAIL), n)
    k = k[n - h:n + h + 1]
    return (k / k.sum()).astype(np.float32)


def _stacked(rois: list[np.ndarray]) -> np.ndarray:
    """The images ``rois`` (each (h_k, w_k)) stacked top to bottom, left-aligned, zero-padded on the right, as one
    (sum h_k, max w_k) array (uint8 kept, other dtypes as float32)."""
    dt = np.uint8 if all(r.dtype == np.uint8 for r in rois) else np.float32
    out = np.zeros((sum(r.shape[0] for r in rois), max(r.shape[1] for r in rois)), dt)
    r0 = 0
    for r in rois:
        out[r0:r0 + r.shape[0], :r.shape[1]] = r
        r0 += r.shape[0]
    return out


def _spline_coefficients(roi: np.ndarray, sigma: float) -> np.ndarray:
    """(h, w) float32 cubic B-spline coefficients of ``roi`` (h, w) smoothed by a Gaussian of ``sigma`` px (reflected
    border, as ``cv2.GaussianBlur``), with the prefilter's mirror boundary (OpenCV's ``BORDER_REFLECT_101``)."""
    img = roi.astype(np.float32)
    if sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    k = _prefilter_kernel()
    return cv2.sepFilter2D(img, cv2.CV_32F, k, k, borderType=cv2.BORDER_REFLECT_101)


def _roi_boxes(c: np.ndarray, axes: np.ndarray, sigma: float, shape: tuple[int, int]) -> tuple[np.ndarray, ...]:
    """Per-dot half profile length ``hw`` (D,) and ROI boxes x0, y0, x1, y1 (D,) int, clipped to the image."""
    H, W = shape
    a, b = axes[:, 0], axes[:, 1]
    hw = np.minimum(3.0, np.maximum(1.0, 0.8 * b))
    pad = hw + 3.0 * sigma + 4.0
    x0 = np.maximum(0, np.floor(c[:, 0] - a - pad)).astype(int)
    x1 = np.minimum(W, np.ceil(c[:, 0] + a + pad).astype(int) + 1)
    y0 = np.maximum(0, np.floor(c[:, 1] - a - pad)).astype(int)
    y1 = np.minimum(H, np.ceil(c[:, 1] + a + pad).astype(int) + 1)
    return hw, x0, y0, x1, y1


def dot_levels(img: np.ndarray, Q: np.ndarray, origin: tuple[int, int], edge_px: float = 2.0
               ) -> tuple[float, np.ndarray] | None:
    """Dark level inside a dot and the bright level around it as a plane.

    ``img``: ROI (h, w) float; ``Q``: the dot's ellipse in full-image pixels; ``origin``: (x0, y0) of the ROI.
    Returns ``(dark, plane)`` with ``plane`` (3,) so that bright(x, y) = plane @ (x, y, 1) in full-image pixels,
    or ``None`` when there are not enough pixels. (One-dot form of :func:`dot_levels_batch`.)
    """
    h, w = img.shape
    x0, y0 = origin
    box = np.array([[x0, y0, x0 + w, y0 + h]])
    full = np.zeros((y0 + h, x0 + w))
    full[y0:, x0:] = img
    dark, plane, ok = dot_levels_batch(full, np.asarray(Q, np.float64)[None], box, edge_px)
    return (float(dark[0]), plane[0]) if ok[0] else None


def dot_levels_batch(gray: np.ndarray, conics: np.ndarray, boxes: np.ndarray, edge_px: float = 2.0
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dark level inside each dot and the bright level around it as a plane, for all dots at once.

    ``gray``: (H, W) image; ``conics``: (D, 3, 3) ellipses (px); ``boxes``: (D, 4) int ROIs ``x0, y0, x1, y1``
    (exclusive ends) whose pixels are used. Dark: median inside the ellipse shrunk by ``edge_px`` (the 3 pixels
    nearest the centre for tiny dots); bright: plane fitted (least squares, refitted once without >4 robust-sigma
    residuals) to the ring ``edge_px`` .. ``edge_px + max(2, b/2)`` px outside, keeping only pixels brighter than
    halfway between the dark level and the ring median (drops neighbouring dots). Returns ``(dark (D,),
    plane (D, 3), ok (D,) bool)``: bright(x, y) = plane @ (x, y, 1) in image pixels; ``ok`` false where the ring has
    too few pixels. One compiled pass per dot (:func:`_levels_kernel`); the medians of a uint8 image come from
    histograms (same values as sorting).
    """
    return _dot_levels(gray, *conic_params_batch(np.asarray(conics, np.float64)), boxes, edge_px)


def _dot_levels(gray: np.ndarray, c: np.ndarray, axes: np.ndarray, ang: np.ndarray, okc: np.ndarray,
                boxes: np.ndarray, edge_px: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`dot_levels_batch` from the ellipses' parameters (centres (D, 2), semi-axes (D, 2), angles (D,), valid
    (D,), as :func:`~circcal.detector.ellipse.conic_params_batch` gives them)."""
    D = len(okc)
    H, W = np.shape(gray)
    boxes = np.asarray(boxes, np.int64).reshape(D, 4).copy()
    np.clip(boxes[:, 0::2], 0, W, out=boxes[:, 0::2])   # (the compiled pass reads only inside the image)
    np.clip(boxes[:, 1::2], 0, H, out=boxes[:, 1::2])
    dark = np.full(D, np.nan)
    plane = np.full((D, 3), np.nan)
    ok = np.zeros(D, bool)
    if D == 0:
        return dark, plane, ok
    gray = np.ascontiguousarray(gray)
    if gray.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        gray = gray.astype(np.float64)
    # the ellipse as rho^2 = qa dx^2 + qb dx dy + qc dy^2 (1 on the boundary) and the radii bounding the regions
    a, b = np.where(okc, axes[:, 0], 1.0), np.where(okc, axes[:, 1], 1.0)
    ca, sa = np.cos(ang), np.sin(ang)
    ia2, ib2 = 1.0 / (a * a), 1.0 / (b * b)
    q = np.stack([ca * ca * ia2 + sa * sa * ib2, 2.0 * ca * sa * (ia2 - ib2), sa * sa * ia2 + ca * ca * ib2], 1)
    t_in = 1.0 - edge_px / b
    t = np.stack([np.where(t_in > 0, t_in * t_in, -1.0), (1.0 + edge_px / b) ** 2,
                  (1.0 + (edge_px + np.maximum(2.0, 0.5 * b)) / b) ** 2], 1)
    _levels_kernel(gray, np.where(okc[:, None], c, 0.0), q, t, boxes, okc, 256 if gray.dtype == np.uint8 else 0,
                   dark, plane, ok)
    return dark, plane, ok


@njit(cache=True, nogil=True)
def _median_hist(hist: np.ndarray, m: int) -> float:
    """Median of ``m`` integer values given by their histogram (the mean of the two middle values for even m)."""
    lo_i, hi_i = (m - 1) // 2, m // 2
    lo = hi = -1
    cum = 0
    for v in range(len(hist)):
        cum += hist[v]
        if lo < 0 and cum > lo_i:
            lo = v
        if cum > hi_i:
            hi = v
            break
    return 0.5 * (lo + hi)


@njit(cache=True, nogil=True)
def _median_values(vals, n, hist, scratch):
    """Median of ``vals[:n]``, leaving ``vals`` as it is: from a histogram when ``hist`` has bins (uint8 values, one
    bin per value), else by quickselect on a copy in ``scratch``."""
    if len(hist):
        hist[:] = 0
        for i in range(n):
            hist[int(vals[i])] += 1
        return _median_hist(hist, n)
    scratch[:n] = vals[:n]
    return _median_inplace(scratch, n)


@njit(cache=True, nogil=True)
def _plane_fit(rx, ry, rv, use, n):
    """(p0, p1, p2): least-squares plane v = p0 x + p1 y + p2 through the first ``n`` points where ``use``
    (normal equations solved by Cramer's rule: the coordinates are centred on the dot, the system well scaled);
    NaN for collinear points."""
    sxx = sxy = sx = syy = sy = s1 = sxv = syv = sv = 0.0
    for i in range(n):
        if use[i]:
            x, y, v = rx[i], ry[i], rv[i]
            sxx += x * x
            sxy += x * y
            sx += x
            syy += y * y
            sy += y
            s1 += 1.0
            sxv += x * v
            syv += y * v
            sv += v
    c00, c01, c02 = syy * s1 - sy * sy, sy * sx - sxy * s1, sxy * sy - syy * sx
    det = sxx * c00 + sxy * c01 + sx * c02
    if det == 0.0:  # collinear points (checked: numba, like Python, raises on a division by zero)
        return np.nan, np.nan, np.nan
    p0 = (sxv * c00 + syv * c01 + sv * c02) / det
    p1 = (sxv * c01 + syv * (sxx * s1 - sx * sx) + sv * (sxy * sx - sxx * sy)) / det
    p2 = (sxv * c02 + syv * (sxy * sx - sxx * sy) + sv * (sxx * syy - sxy * sxy)) / det
    return p0, p1, p2


@njit(cache=True, nogil=True)
def _median_inplace(a, n):
    """Median of ``a[:n]`` (the mean of the two middle values for even n), reordering ``a[:n]`` (quickselect)."""
    k = (n - 1) // 2
    lo, hi = 0, n - 1
    while lo < hi:
        pivot = a[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    m = a[k]
    if n % 2 == 1:
        return m
    nxt = a[k + 1]
    for i in range(k + 2, n):  # the next order statistic: the smallest of the upper part
        if a[i] < nxt:
            nxt = a[i]
    return 0.5 * (m + nxt)


@njit(cache=True, nogil=True)
def _levels_kernel(gray, c, q, t, boxes, okc, nbins, dark, plane, ok):
    """The per-pixel work of :func:`dot_levels_batch`, one dot at a time; writes ``dark``, ``plane``, ``ok``."""
    D = len(c)
    npx = 1
    for d in range(D):
        npx = max(npx, max(boxes[d, 2] - boxes[d, 0], 0) * max(boxes[d, 3] - boxes[d, 1], 0))
    inner = np.empty(npx)
    rx = np.empty(npx)
    ry = np.empty(npx)
    rv = np.empty(npx)
    keep = np.zeros(npx, np.bool_)
    okr = np.zeros(npx, np.bool_)
    res = np.empty(npx)
    hist = np.zeros(nbins, np.int64)   # empty: values are not uint8, medians by selection
    near_r = np.empty(3)
    near_v = np.empty(3)
    for d in range(D):
        if not okc[d]:
            continue
        x0, y0, x1, y1 = boxes[d, 0], boxes[d, 1], boxes[d, 2], boxes[d, 3]
        cx, cy = c[d, 0], c[d, 1]
        qa, qb, qc = q[d, 0], q[d, 1], q[d, 2]
        t_in, t_lo, t_hi = t[d, 0], t[d, 1], t[d, 2]
        n_in = 0
        n_ring = 0
        n_near = 0
        for y in range(y0, y1):
            dy = y - cy
            # the columns inside the outer ellipse rho^2 < t_hi (a pixel beyond it is neither inside nor in the ring;
            # one pixel of slack, the test below decides)
            disc = (qb * dy) ** 2 - 4.0 * qa * (qc * dy * dy - t_hi)
            if disc < 0:
                continue
            half = np.sqrt(disc) / (2.0 * qa)
            mid = cx - qb * dy / (2.0 * qa)
            for x in range(max(x0, int(np.floor(mid - half)) - 1), min(x1, int(np.ceil(mid + half)) + 2)):
                dx = x - cx
                rho2 = (qb * dx) * dy + (qa * dx) * dx + (qc * dy) * dy
                v = gray[y, x]
                if rho2 < t_in:
                    inner[n_in] = v
                    n_in += 1
                elif t_lo < rho2 < t_hi:
                    rx[n_ring] = dx
                    ry[n_ring] = dy
                    rv[n_ring] = v
                    n_ring += 1
                # the 3 pixels nearest the centre (for dots too small to have an inside)
                if n_near < 3 or rho2 < near_r[n_near - 1]:
                    i = min(n_near, 2)
                    while i > 0 and near_r[i - 1] > rho2:
                        near_r[i], near_v[i] = near_r[i - 1], near_v[i - 1]
                        i -= 1
                    near_r[i], near_v[i] = rho2, v
                    n_near = min(n_near + 1, 3)
        if n_in >= 3:
            dk = _median_values(inner, n_in, hist, res)
        elif n_near:
            dk = np.median(near_v[:n_near])
        else:
            dk = np.nan
        if n_ring < 8:
            continue
        ring_med = _median_values(rv, n_ring, hist, res)
        mid = 0.5 * (dk + ring_med)
        n_keep = 0
        for i in range(n_ring):
            keep[i] = rv[i] > mid
            n_keep += keep[i]
        if n_keep < 6:
            continue
        p0, p1, p2 = _plane_fit(rx, ry, rv, keep, n_ring)
        m = 0
        for i in range(n_ring):
            res[i] = abs(rv[i] - (p0 * rx[i] + p1 * ry[i] + p2))
            if keep[i]:
                inner[m] = res[i]   # (the inner values are used up: the buffer holds the kept residuals)
                m += 1
        s = 1.4826 * _median_inplace(inner, m) + 1e-12
        n_ok = 0
        for i in range(n_ring):
            okr[i] = keep[i] and res[i] < 4.0 * s
            n_ok += okr[i]
        if 6 <= n_ok < n_keep:
            p0, p1, p2 = _plane_fit(rx, ry, rv, okr, n_ring)
        if not (np.isfinite(p0) and np.isfinite(p1) and np.isfinite(p2)):  # collinear ring pixels
            continue
        dark[d] = dk
        plane[d, 0], plane[d, 1], plane[d, 2] = p0, p1, p2 - p0 * cx - p1 * cy
        ok[d] = True


_S_CACHE: dict[tuple[float, float], np.ndarray] = {}


def _profile_offsets(hw: float, step: float) -> np.ndarray:
    key = (float(hw), float(step))
    s = _S_CACHE.get(key)
    if s is None:
        s = _S_CACHE[key] = np.arange(-hw, hw + 1e-9, step)
    return s


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
    the caller decides). One-dot form of :func:`subpixel_edge_points_batch`.
    """
    if method not in ("level", "gradient"):
        raise ValueError(f"unknown edge method {method!r}; expected 'level' or 'gradient'")
    pts, mask, err = subpixel_edge_points_batch(SmoothedImage(img, sigma), np.asarray(Q, np.float64)[None],
                                                spacing=spacing, step=step, method=method,
                                                curvature_correction=curvature_correction)
    if err[0] == "conic is not a real ellipse":
        raise ValueError(err[0])
    return pts[0][mask[0]]


def subpixel_edge_points_batch(
    src: SmoothedImage,
    conics: np.ndarray,
    *,
    spacing: float = 1.0,
    step: float = 0.2,
    method: str = "level",
    curvature_correction: bool = True,
) -> tuple[np.ndarray, np.ndarray, list[str | None]]:
    """Sub-pixel boundary points of many dots at once: :func:`subpixel_edge_points` for each ellipse of
    ``conics`` (D, 3, 3) on ``src`` (the image and its smoothing scale).

    Each dot keeps its own region of interest (the pixels its levels come from and the box its profiles must stay
    inside, as in the one-dot form). For the level method each profile's intervals are examined nearest to the
    current boundary first (:func:`_crossings_kernel`), sampling the image only where needed: the first up-crossing
    met is the nearest one of the whole profile, found from a few samples.

    Returns ``(points (D, Nmax, 2) px, mask (D, Nmax) bool, errors)``: the boundary points of dot ``d`` are
    ``points[d][mask[d]]``; ``errors[d]`` is ``None`` or why dot ``d`` gave no points at all.
    """
    if method not in ("level", "gradient"):
        raise ValueError(f"unknown edge method {method!r}; expected 'level' or 'gradient'")
    conics = np.asarray(conics, np.float64)
    D = len(conics)
    errors: list[str | None] = [None] * D
    c, axes, ang, okc = conic_params_batch(conics)
    for d in np.nonzero(~okc)[0]:
        errors[d] = "conic is not a real ellipse"
    sigma = src.sigma
    H, W = src.shape
    a_ = np.where(okc, axes[:, 0], 1.0)
    b_ = np.where(okc, axes[:, 1], 1.0)
    c = np.where(okc[:, None], c, 0.0)
    ang = np.where(okc, ang, 0.0)
    hw, x0, y0, x1, y1 = _roi_boxes(c, np.stack([a_, b_], 1), sigma, (H, W))
    live = okc & (y1 - y0 >= 4) & (x1 - x0 >= 4)
    if not np.any(live):
        return np.zeros((D, 0, 2)), np.zeros((D, 0), bool), errors
    # one profile per `spacing` px of perimeter (Ramanujan's approximation)
    hab = ((a_ - b_) / (a_ + b_)) ** 2
    perim = np.pi * (a_ + b_) * (1 + 3 * hab / (10 + np.sqrt(4 - 3 * hab)))
    n = np.maximum(24, np.ceil(perim / spacing)).astype(int)
    n[~live] = 0
    N = int(n.max())
    prof_ok = np.arange(N)[None, :] < n[:, None]                         # (D, N)
    # profile offsets (one array per distinct half length, as np.arange gives them)
    svecs = [_profile_offsets(h, step) for h in hw]
    K = max(len(v) for v in svecs)
    S = np.full((D, K), np.nan)
    for d, v in enumerate(svecs):
        S[d, :len(v)] = v
    klen = np.array([len(v) for v in svecs])
    # base points and outward normals, profiles entirely inside the ROI, the extent of those to be sampled
    boxes = np.stack([x0, y0, x1, y1], 1).astype(np.int64)
    base, nrm, cos_t, sin_t, inside, ext = _profiles_kernel(c, a_, b_, ang, conics, n, N, S[:, 0],
                                                            S[np.arange(D), klen - 1], boxes, method == "level")
    crop = src.crops_for(ext)

    if method == "gradient":
        prof = np.full((D, N, K), np.nan)
        sd, sj, sk = np.nonzero(live[:, None, None] & prof_ok[:, :, None] & (np.arange(K)[None, None, :] <
                                                                             klen[:, None, None]))
        px = base[sd, sj, 0] + S[sd, sk] * nrm[sd, sj, 0]
        py = base[sd, sj, 1] + S[sd, sk] * nrm[sd, sj, 1]
        prof[sd, sj, sk] = src.sample(crop[sd], px, py)
        ok = np.zeros((D, N), bool)
        off = np.zeros((D, N))
        for d in np.nonzero(live)[0]:  # np.gradient per dot (profiles of one dot share their offsets)
            kk = klen[d]
            pr = prof[d, :n[d], :kk]
            dd = np.gradient(pr, step, axis=1)
            k = np.clip(np.argmax(dd[:, 1:-1], axis=1) + 1, 1, kk - 2)
            r = np.arange(n[d])
            dm, d0, dp = dd[r, k - 1], dd[r, k], dd[r, k + 1]
            okd = inside[d, :n[d]] & (dm > 0) & (d0 > 0) & (dp > 0) & (d0 >= dm) & (d0 >= dp)
            lm, l0, lp = (np.log(np.maximum(v, 1e-300)) for v in (dm, d0, dp))
            den = lm - 2 * l0 + lp
            with np.errstate(divide="ignore", invalid="ignore"):
                frac = np.where(den < 0, 0.5 * (lm - lp) / den, 0.0)
            okd &= np.abs(frac) <= 1.0
            ok[d, :n[d]] = okd
            off[d, :n[d]] = S[d, k] + frac * step
        return base + off[..., None] * nrm, ok, errors

    # ---- level method
    dark, plane, okl = _dot_levels(src.gray, c, np.stack([a_, b_], 1), ang, okc, boxes)
    bright_c = plane[:, 0] * c[:, 0] + plane[:, 1] * c[:, 1] + plane[:, 2]
    with np.errstate(invalid="ignore"):
        okl &= live & (bright_c > dark)
    ratio = np.where(okl, dark / np.where(okl, bright_c, 1.0), 0.0)
    halfk = 0.5 * (1.0 + ratio)
    todo = okl[:, None] & inside
    # intervals of each profile nearest to the boundary first (ties: the lower index), NaN ones (past the end) last
    mid_dist = np.abs(0.5 * (S[:, :-1] + S[:, 1:]))  # (D, K-1)
    rank = np.argsort(np.where(np.isfinite(mid_dist), mid_dist, np.inf), axis=1, kind="stable")
    atlas, rows, org = src.coefficient_atlas(crop)
    k = np.zeros((D, N), np.int64)
    fa = np.zeros((D, N))
    fb = np.zeros((D, N))
    found = np.zeros((D, N), bool)
    _crossings_kernel(atlas, rows, org, base, nrm, S, klen - 1, rank, todo, plane, halfk, k, fa, fb, found)
    ok = found & todo
    with np.errstate(invalid="ignore", divide="ignore"):
        tt = fa / (fa - fb)
    sk = np.take_along_axis(S, k, axis=1)
    off = sk + tt * step
    if curvature_correction:
        # edge width from the slope at the crossing: a Gaussian-blurred step of height A has slope
        # A / (sqrt(2 pi) sigma_t); the pixel box (variance 1/12) and our smoothing set a lower bound.
        px = base[..., 0] + sk * nrm[..., 0]
        py = base[..., 1] + sk * nrm[..., 1]
        span = (px * plane[:, 0:1] + py * plane[:, 1:2] + plane[:, 2:3]) * (1.0 - ratio)[:, None]
        slope = (fb - fa) / step
        with np.errstate(divide="ignore", invalid="ignore"):
            st = span / (np.sqrt(2.0 * np.pi) * slope)
            use = ok & np.isfinite(st) & (st > 0)
        med = _masked_median(np.where(use, st, 0.0), use)
        nominal = np.sqrt(sigma * sigma + 1.0 / 12.0)
        sigma_t = np.where(use.any(axis=1), np.maximum(nominal, med), nominal)
        off = off + _curvature_shift_param(a_, b_, cos_t, sin_t, sigma_t)
    off = np.where(ok, off, 0.0)
    return base + off[..., None] * nrm, ok, errors


@njit(cache=True, nogil=True)
def _profiles_kernel(c, a, b, ang, conics, n, N, s_first, s_last, boxes, inside_only):
    """Geometry of the edge profiles of D ellipses (centres ``c`` (D, 2), semi-axes ``a``, ``b``, angles ``ang``,
    conics (D, 3, 3)): ``n[d]`` profiles at equal steps of the parameter t, from ``s_first[d]`` to ``s_last[d]`` px
    along the outward normal.

    Returns ``base`` (D, N, 2) ellipse points, ``nrm`` (D, N, 2) unit outward normals, ``cos_t``, ``sin_t`` (D, N),
    ``inside`` (D, N): both ends of the profile within the box ``boxes[d]`` (x0, y0, x1, y1; one pixel in from x0,
    y0 and two from the exclusive ends), and ``ext`` (D, 4) ``xmin, ymin, xmax, ymax`` of the ends of the profiles
    to be sampled (those ``inside`` when ``inside_only``, else all; NaN when none).
    """
    D = len(n)
    base = np.zeros((D, N, 2))
    nrm = np.zeros((D, N, 2))
    cos_t = np.zeros((D, N))
    sin_t = np.zeros((D, N))
    inside = np.zeros((D, N), np.bool_)
    ext = np.full((D, 4), np.nan)
    for d in range(D):
        if n[d] == 0:
            continue
        w = 2.0 * np.pi / n[d]
        ca, sa = np.cos(ang[d]), np.sin(ang[d])
        Q = conics[d]
        sg = -1.0 if Q[0, 0] + Q[1, 1] < 0 else 1.0
        xlo, ylo, xhi, yhi = boxes[d, 0] + 1, boxes[d, 1] + 1, boxes[d, 2] - 2, boxes[d, 3] - 2
        emin_x = emin_y = np.inf
        emax_x = emax_y = -np.inf
        for j in range(n[d]):
            t = j * w
            ct, st = np.cos(t), np.sin(t)
            cos_t[d, j], sin_t[d, j] = ct, st
            ex, ey = a[d] * ct, b[d] * st
            bx = c[d, 0] + ca * ex - sa * ey
            by = c[d, 1] + sa * ex + ca * ey
            gx = sg * (bx * Q[0, 0] + by * Q[0, 1] + Q[0, 2])
            gy = sg * (bx * Q[1, 0] + by * Q[1, 1] + Q[1, 2])
            gn = np.sqrt(gx * gx + gy * gy)
            base[d, j, 0], base[d, j, 1] = bx, by
            if not gn > 0:  # (no normal: only at a degenerate conic's centre; the profile is not measured)
                continue
            nx, ny = gx / gn, gy / gn
            nrm[d, j, 0], nrm[d, j, 1] = nx, ny
            ax, ay = bx + s_first[d] * nx, by + s_first[d] * ny
            zx, zy = bx + s_last[d] * nx, by + s_last[d] * ny
            ins = (xlo <= ax <= xhi and ylo <= ay <= yhi and xlo <= zx <= xhi and ylo <= zy <= yhi)
            inside[d, j] = ins
            if ins or not inside_only:
                emin_x = min(emin_x, ax, zx)
                emin_y = min(emin_y, ay, zy)
                emax_x = max(emax_x, ax, zx)
                emax_y = max(emax_y, ay, zy)
        if emin_x <= emax_x:
            ext[d, 0], ext[d, 1], ext[d, 2], ext[d, 3] = emin_x, emin_y, emax_x, emax_y
    return base, nrm, cos_t, sin_t, inside, ext


@njit(cache=True, nogil=True, inline="always")
def _bspline3_weights(t: float) -> tuple[float, float, float, float]:
    """Cubic B-spline weights of the 4 coefficients around a point at fraction ``t`` in [0, 1) past the second."""
    u = 1.0 - t
    return (u * u * u / 6.0, (t * t * (t - 2.0) * 3.0 + 4.0) / 6.0, (u * u * (u - 2.0) * 3.0 + 4.0) / 6.0,
            t * t * t / 6.0)


@njit(cache=True, nogil=True, inline="always")
def _mirror(i: int, n: int) -> int:
    """Index ``i`` reflected into [0, n) about the end samples (scipy's "mirror"; clamped beyond one reflection, so
    no index ever leaves the array)."""
    if i < 0:
        i = -i
    if i >= n:
        i = 2 * (n - 1) - i
    return min(max(i, 0), n - 1)


@njit(cache=True, nogil=True)
def _spline_at(atlas: np.ndarray, r: float, c: float) -> float:
    """Cubic B-spline with coefficients ``atlas`` (float32 (R, C)) at row ``r``, column ``c``: the value of
    ``scipy.ndimage.map_coordinates(atlas, [[r], [c]], order=3, mode="mirror", prefilter=False)`` (the mirror is
    never reached for points inside their crop's box)."""
    R, C = atlas.shape
    if not (np.isfinite(r) and np.isfinite(c)):
        return np.nan
    fr, fc = np.floor(r), np.floor(c)
    wr = _bspline3_weights(r - fr)
    wc = _bspline3_weights(c - fc)
    ir, ic = int(fr) - 1, int(fc) - 1
    out = 0.0
    for i in range(4):
        row = _mirror(ir + i, R)
        acc = 0.0
        for j in range(4):
            acc += wc[j] * atlas[row, _mirror(ic + j, C)]
        out += wr[i] * acc
    return out


@njit(cache=True, nogil=True)
def _crossings_kernel(atlas, rows, org, base, nrm, S, n_iv, rank, todo, plane, halfk, k_out, fa_out, fb_out,
                      found_out):
    """Nearest up-crossing of the half level on each profile ``(d, j)`` where ``todo``.

    Profile samples at ``base[d, j] + S[d, k] nrm[d, j]`` (smoothed image from ``atlas`` rows ``rows[d]`` +, crop
    origin ``org[d]``) minus the half level ``halfk[d] plane[d] @ (x, y, 1)``; intervals ``(k, k + 1)`` examined in
    the order ``rank[d, :n_iv[d]]`` (nearest to the boundary first), each sample computed once when first needed.
    Writes the interval ``k_out``, the values at its ends ``fa_out``, ``fb_out`` and ``found_out``.
    """
    D, N = todo.shape
    F = np.empty(S.shape[1])
    have = np.zeros(S.shape[1], np.bool_)
    for d in range(D):
        p0, p1, p2 = plane[d, 0], plane[d, 1], plane[d, 2]
        hk = halfk[d]
        r0, ox, oy = rows[d], org[d, 0], org[d, 1]
        for j in range(N):
            if not todo[d, j]:
                continue
            bx, by, nx, ny = base[d, j, 0], base[d, j, 1], nrm[d, j, 0], nrm[d, j, 1]
            have[:] = False
            for r in range(n_iv[d]):
                kk = rank[d, r]
                for q in (kk, kk + 1):
                    if not have[q]:
                        px = bx + S[d, q] * nx
                        py = by + S[d, q] * ny
                        F[q] = _spline_at(atlas, (py - oy) + r0, px - ox) - (px * p0 + py * p1 + p2) * hk
                        have[q] = True
                if F[kk] < 0 and F[kk + 1] >= 0:
                    k_out[d, j] = kk
                    fa_out[d, j] = F[kk]
                    fb_out[d, j] = F[kk + 1]
                    found_out[d, j] = True
                    break


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
    c, axes, ang, _ = conic_params_batch(np.asarray(Q, np.float64)[None])
    return _curvature_shift_batch(c, axes[:, 0], axes[:, 1], ang, np.asarray(points, np.float64)[None],
                                  np.array([sigma_t]))[0]


def _curvature_shift_batch(c: np.ndarray, a: np.ndarray, b: np.ndarray, ang: np.ndarray, points: np.ndarray,
                           sigma_t: np.ndarray) -> np.ndarray:
    """(D, M) :func:`_curvature_shift` for D ellipses (centres (D, 2), semi-axes a, b (D,), angles (D,)), points
    (D, M, 2) and blur scales (D,)."""
    d = points - c[:, None, :]
    ca, sa = np.cos(ang)[:, None], np.sin(ang)[:, None]
    x = ca * d[..., 0] + sa * d[..., 1]
    y = -sa * d[..., 0] + ca * d[..., 1]
    t = np.arctan2(y / b[:, None], x / a[:, None])
    return _curvature_shift_param(a, b, np.cos(t), np.sin(t), sigma_t)


def _curvature_shift_param(a: np.ndarray, b: np.ndarray, cos_t: np.ndarray, sin_t: np.ndarray,
                           sigma_t: np.ndarray) -> np.ndarray:
    """(D, M) :func:`_curvature_shift` at the points ``(a cos t, b sin t)`` (ellipse frame) of D ellipses with
    semi-axes a, b (D,) px, given ``cos t``, ``sin t`` (D, M), and blur scales ``sigma_t`` (D,) px."""
    global _SHIFT_TABLE
    if _SHIFT_TABLE is None:
        _SHIFT_TABLE = _U_TABLE - _half_level_radius(_U_TABLE)
    a, b = a[:, None], b[:, None]
    q = (a * sin_t) ** 2 + (b * cos_t) ** 2
    rho = q * np.sqrt(q) / (a * b)  # radius of curvature
    u = rho / sigma_t[:, None]
    shift = np.where(u > _U_TABLE[-1], 0.5 / np.maximum(u, 1e-9),
                     np.interp(u, _U_TABLE, _SHIFT_TABLE, left=_SHIFT_TABLE[0]))
    # the osculating-circle model fails where the curvature changes within the blur (tight ends of thin
    # ellipses): no correction below u = 1.5, full above 2.5
    return sigma_t[:, None] * shift * np.clip(u - 1.5, 0.0, 1.0)
