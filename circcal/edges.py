"""Pre-processing, segmentation, candidate dots and sub-pixel edge points of dark dots on a bright board.

Pipeline pieces used by :mod:`circcal.detect`:

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
one crop per dot, all crops filtered by one OpenCV call (:class:`SmoothedImage`), the profiles of all dots sampled
together with ``map_coordinates`` (first only the interval nearest the current boundary, the rest of a profile only
where no crossing is found there: the nearest crossing is the same), the levels of all dots estimated together
(medians of uint8 images from histograms). :func:`subpixel_edge_points` is the one-dot form.

Pixel convention: OpenCV's (integer coordinates are pixel centres). Arrays: ``(M, 2)`` points as ``(x, y)``.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from .ellipse import conic_from_params, conic_params_batch

__all__ = ["Candidate", "to_gray", "as_gray", "normalise_u8", "segmentations", "find_candidates",
           "subpixel_edge_points", "subpixel_edge_points_batch", "SmoothedImage", "dot_levels", "dot_levels_batch",
           "guided_filter"]


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


def as_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3|4) BGR(A) image of dtype uint8, uint16 or float -> (H, W) grey in its own dtype (colour
    converted by ``cv2.cvtColor``; float64 colour via float32 as in :func:`to_gray`). Raises ``ValueError`` for other
    shapes or dtypes, and for NaN/inf."""
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
    if np.issubdtype(img.dtype, np.floating) and not np.all(np.isfinite(img)):
        raise ValueError("image contains NaN or inf")
    return img


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3|4) BGR(A) image of dtype uint8, uint16 or float -> (H, W) float64 grey, same scale as
    the input values. Raises ``ValueError`` for other shapes or dtypes."""
    return as_gray(image).astype(np.float64)


def normalise_u8(gray: np.ndarray) -> np.ndarray:
    """Stretch the 0.5-99.5 percentile range of ``gray`` (H, W) to uint8 (for thresholding only). Integer images
    (uint8/uint16, e.g. from :func:`as_gray`) go through a lookup table of the same formula (identical result)."""
    sub = gray[::4, ::4] if gray.size > 400_000 else gray
    lo, hi = np.percentile(sub if sub.dtype in (np.uint8, np.uint16) else sub.astype(np.float64), [0.5, 99.5])
    if hi <= lo:
        hi = lo + 1e-9
    scale = 255.0 / (hi - lo)
    if gray.dtype in (np.uint8, np.uint16):
        lut = np.clip((np.arange(np.iinfo(gray.dtype).max + 1, dtype=np.float64) - lo) * scale, 0, 255)
        lut = lut.astype(np.uint8)
        return cv2.LUT(gray, lut) if gray.dtype == np.uint8 else lut[gray]
    return np.clip((gray.astype(np.float64) - lo) * scale, 0, 255).astype(np.uint8)


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


def _segment_median(vals: np.ndarray, seg: np.ndarray, nseg: int) -> np.ndarray:
    """(nseg,) median of ``vals[seg == k]`` for each k (as ``np.median``: the mean of the two middle values for an
    even count; NaN for an empty segment). ``seg`` (M,) int must be sorted ascending (as ``np.nonzero`` gives)."""
    m = np.bincount(seg, minlength=nseg)
    width = int(max(1, m.max(initial=0)))
    packed = np.full((nseg, width), np.inf)
    start = np.cumsum(m) - m
    packed.reshape(-1)[seg * width + (np.arange(len(seg)) - start[seg])] = vals
    packed.sort(axis=1)
    rows = np.arange(nseg)
    lo = np.clip((m - 1) // 2, 0, width - 1)
    hi = np.clip(m // 2, 0, width - 1)
    out = 0.5 * (packed[rows, lo] + packed[rows, hi])
    return np.where(m > 0, out, np.nan)


def _masked_median(vals: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(D,) median of ``vals[d][mask[d]]`` per row of (D, P) arrays (NaN for an empty row; the values of
    :func:`_segment_median` of the masked values, sorted in place of packing)."""
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

    A crop extends :attr:`margin` px beyond its box (clipped to the image): the Gaussian's radius, the half length of
    the spline prefilter and the spline's own support, so samples inside the box equal those of smoothing the whole
    image. The prefilter is the exact recursive B-spline filter written as its (symmetric, exponentially decaying)
    impulse response truncated at :data:`PREFILTER_HALF_LENGTH` taps (a 5e-8 share of its weight is left out). Both
    filters run in float32 (values good to ~1e-7 relative, edge points to ~1e-7 px): the crops inside the image as
    one separable filter (Gaussian and prefilter convolved) on all of them stacked (``cv2.sepFilter2D``), crops at
    the image border each on their own with the border reflections (``cv2.GaussianBlur`` then the prefilter). The
    coefficients of all crops are sampled from one stacked atlas (``map_coordinates``). A later box reuses the crop
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
        """Pixels a crop extends beyond its box: Gaussian radius + prefilter half length + spline support."""
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

    def sample(self, crop: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Smoothed image at points (x, y) px (1-D arrays) from the crops ``crop`` (same length, indices from
        :meth:`crops_for`; the points must lie inside their crop's box), cubic B-spline."""
        if self._atlas is None:
            self._atlas = self._sheets[0] if len(self._sheets) == 1 else _stacked(self._sheets)
            first = np.cumsum([0] + [s.shape[0] for s in self._sheets])
            self._rows = np.array([first[s] + r0 for s, r0 in self._place], int)
        crop = np.asarray(crop, int)
        org = np.array(self.crops, np.float64)[crop]
        coords = np.empty((2, len(crop)))
        np.subtract(y, org[:, 1], out=coords[0])
        coords[0] += self._rows[crop]
        np.subtract(x, org[:, 0], out=coords[1])
        return ndimage.map_coordinates(self._atlas, coords, order=3, mode="mirror", prefilter=False,
                                       output=np.float64)


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


@functools.lru_cache(maxsize=8)
def _combined_kernel(sigma: float) -> np.ndarray:
    """(2 (r + L) + 1,) float32: OpenCV's Gaussian kernel of ``sigma`` (radius r, none for 0) convolved with the FIR
    prefilter (half length L): smoothing and prefiltering in one separable filter (away from the image borders)."""
    k = _prefilter_kernel().astype(np.float64)
    r = _gauss_radius(sigma)
    if r:
        k = np.convolve(k, cv2.getGaussianKernel(2 * r + 1, sigma, cv2.CV_64F)[:, 0])
    return k.astype(np.float32)


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


def _segment_median_int(vals: np.ndarray, seg: np.ndarray, nseg: int, nbins: int) -> np.ndarray:
    """:func:`_segment_median` for integer ``vals`` (M,) in ``[0, nbins)`` by per-segment histograms (O(M), no
    sort; the same values: the mean of the two middle values for an even count, NaN for an empty segment)."""
    hist = np.bincount(seg * nbins + vals, minlength=nseg * nbins).reshape(nseg, nbins)
    cum = np.cumsum(hist, axis=1)
    m = cum[:, -1]
    # the value of sorted element i is the number of bins whose cumulative count is <= i
    lo = np.count_nonzero(cum <= ((m - 1) // 2)[:, None], axis=1)
    hi = np.count_nonzero(cum <= (m // 2)[:, None], axis=1)
    return np.where(m > 0, 0.5 * (lo.astype(np.float64) + hi), np.nan)


def dot_levels_batch(gray: np.ndarray, conics: np.ndarray, boxes: np.ndarray, edge_px: float = 2.0
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dark level inside each dot and the bright level around it as a plane, for all dots at once.

    ``gray``: (H, W) image; ``conics``: (D, 3, 3) ellipses (px); ``boxes``: (D, 4) int ROIs ``x0, y0, x1, y1``
    (exclusive ends) whose pixels are used. Dark: median inside the ellipse shrunk by ``edge_px`` (the 3 pixels
    nearest the centre for tiny dots); bright: plane fitted (least squares, refitted once without >4 robust-sigma
    residuals) to the ring ``edge_px`` .. ``edge_px + max(2, b/2)`` px outside, keeping only pixels brighter than
    halfway between the dark level and the ring median (drops neighbouring dots). Returns ``(dark (D,),
    plane (D, 3), ok (D,) bool)``: bright(x, y) = plane @ (x, y, 1) in image pixels; ``ok`` false where the ring has
    too few pixels. The medians of a uint8 image come from per-dot histograms (same values as sorting).
    """
    conics = np.asarray(conics, np.float64)
    D = len(conics)
    c, axes, ang, okc = conic_params_batch(conics)
    boxes = np.asarray(boxes, int).reshape(D, 4)
    dark = np.full(D, np.nan)
    plane = np.full((D, 3), np.nan)
    ok = np.zeros(D, bool)
    if D == 0:
        return dark, plane, ok
    bw = np.maximum(boxes[:, 2] - boxes[:, 0], 0)
    bh = np.maximum(boxes[:, 3] - boxes[:, 1], 0)
    Wm, Hm = int(max(1, bw.max())), int(max(1, bh.max()))
    hist_bins = 256 if gray.dtype == np.uint8 else 0
    # pixel values of each ROI (padded, in the image's dtype); coordinates NaN outside a ROI so no mask selects them
    vals = np.zeros((D, Hm, Wm), gray.dtype if hist_bins else np.float64)
    for d, x0, y0, h, w in zip(np.nonzero(okc)[0].tolist(), boxes[okc, 0].tolist(), boxes[okc, 1].tolist(),
                               bh[okc].tolist(), bw[okc].tolist()):
        vals[d, :h, :w] = gray[y0:y0 + h, x0:x0 + w]
    jj = np.arange(Wm, dtype=np.float64)
    ii = np.arange(Hm, dtype=np.float64)
    xs = np.where(jj[None, :] < bw[:, None], boxes[:, 0:1] + jj[None, :], np.nan)   # (D, Wm)
    ys = np.where(ii[None, :] < bh[:, None], boxes[:, 1:2] + ii[None, :], np.nan)   # (D, Hm)
    xs[~okc] = np.nan
    # normalised radius rho (1 on the ellipse) from the separable quadratic form
    # rho^2 = A dx^2 + B dx dy + C dy^2 (3 operations per pixel)
    a, b = axes[:, 0], axes[:, 1]
    ca, sa = np.cos(ang), np.sin(ang)
    ia2, ib2 = 1.0 / (a * a), 1.0 / (b * b)
    qa = ca * ca * ia2 + sa * sa * ib2
    qb = 2.0 * ca * sa * (ia2 - ib2)
    qc = sa * sa * ia2 + ca * ca * ib2
    dx = xs - c[:, 0:1]
    dy = ys - c[:, 1:2]
    with np.errstate(invalid="ignore"):
        rho2 = (qb[:, None] * dx)[:, None, :] * dy[:, :, None]
        rho2 += (qa[:, None] * dx * dx)[:, None, :]
        rho2 += (qc[:, None] * dy * dy)[:, :, None]
        t_in = 1.0 - edge_px / b
        t_in = np.where(t_in > 0, t_in * t_in, -1.0)
        t_lo = (1.0 + edge_px / b) ** 2
        t_hi = (1.0 + (edge_px + np.maximum(2.0, 0.5 * b)) / b) ** 2
        inner = rho2 < t_in[:, None, None]
        ring = (rho2 > t_lo[:, None, None]) & (rho2 < t_hi[:, None, None])
    vflat = vals.reshape(-1)
    P = Hm * Wm
    # the inner pixels' values per dot (flat, grouped by dot)
    fi = np.flatnonzero(inner)
    idd = fi // P
    n_in = np.bincount(idd, minlength=D)
    dk = (_segment_median_int(vflat[fi], idd, D, hist_bins) if hist_bins else
          _segment_median(vflat[fi], idd, D))
    for d in np.nonzero((n_in < 3) & okc)[0]:  # tiny dot: the 3 pixels nearest the centre (as argsort of the ROI)
        r2 = rho2[d, :bh[d], :bw[d]]
        v2 = vals[d, :bh[d], :bw[d]].astype(np.float64)
        dk[d] = float(np.median(v2.ravel()[np.argsort(r2, axis=None)[:3]]))
    # the ring's pixels (flat, grouped by dot), coordinates centred on the dot (conditioning of the plane fit)
    fr = np.flatnonzero(ring)
    grow, col = np.divmod(fr, Wm)          # global row (d * Hm + i) and column of each ring pixel
    rd = grow // Hm
    rv_raw = vflat[fr]
    rv = rv_raw.astype(np.float64)
    rx = dx.reshape(-1)[rd * Wm + col]
    ry = dy.reshape(-1)[grow]
    n_ring = np.bincount(rd, minlength=D)
    ring_med = (_segment_median_int(rv_raw, rd, D, hist_bins) if hist_bins else _segment_median(rv, rd, D))
    mid = 0.5 * (dk + ring_med)
    keep = rv > mid[rd]
    n_keep = np.bincount(rd[keep], minlength=D)
    good = okc & (n_ring >= 8) & (n_keep >= 6)

    seg_start = np.cumsum(n_ring) - n_ring
    has = n_ring > 0

    def fit(wmask):
        # the normal equations' sums per dot, over contiguous segments of the flat ring arrays
        rows = np.empty((9, len(rv)))
        w = rows[5]
        w[:] = wmask
        wx, wy = np.multiply(w, rx, out=rows[2]), np.multiply(w, ry, out=rows[4])
        np.multiply(wx, rx, out=rows[0])
        np.multiply(wx, ry, out=rows[1])
        np.multiply(wy, ry, out=rows[3])
        np.multiply(wx, rv, out=rows[6])
        np.multiply(wy, rv, out=rows[7])
        np.multiply(w, rv, out=rows[8])
        sums = np.zeros((9, D))
        if rows.shape[1]:
            sums[:, has] = np.add.reduceat(rows, seg_start[has], axis=1)
        sxx, sxy, sx, syy, sy, s1, sxv, syv, sv = sums
        AtA = np.stack([np.stack([sxx, sxy, sx], 1), np.stack([sxy, syy, sy], 1), np.stack([sx, sy, s1], 1)], 1)
        Atb = np.stack([sxv, syv, sv], axis=1)
        AtA[~good] = np.eye(3)
        return np.linalg.solve(AtA, Atb[..., None])[..., 0]

    p = fit(keep)
    res = np.abs(rv - (p[rd, 0] * rx + p[rd, 1] * ry + p[rd, 2]))
    s = 1.4826 * _segment_median(res[keep], rd[keep], D) + 1e-12
    okr = keep & (res < 4 * s[rd])
    n_ok = np.bincount(rd[okr], minlength=D)
    refit = good & (n_ok >= 6) & (n_ok < n_keep)
    if np.any(refit):
        p = np.where(refit[:, None], fit(np.where(refit[rd], okr, keep)), p)
    dark[good] = dk[good]
    plane[good] = np.stack([p[:, 0], p[:, 1], p[:, 2] - p[:, 0] * c[:, 0] - p[:, 1] * c[:, 1]], axis=1)[good]
    ok[good] = True
    return dark, plane, ok


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
    windows: tuple[float, ...] = (0.0, 0.15, 0.35, 0.95),
) -> tuple[np.ndarray, np.ndarray, list[str | None]]:
    """Sub-pixel boundary points of many dots at once: :func:`subpixel_edge_points` for each ellipse of
    ``conics`` (D, 3, 3) on ``src`` (the image and its smoothing scale).

    Each dot keeps its own region of interest (the pixels its levels come from and the box its profiles must stay
    inside, as in the one-dot form). For the level method the samples of the intervals within ``windows[0]`` px of
    the current boundary are interpolated first (a window of 0: the nearest interval alone); a profile is sampled
    further (to the next window, then whole) only while it has no crossing yet: the crossing nearest to the boundary
    is the same as with the whole profile sampled.

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
    jn = np.arange(N)
    prof_ok = jn[None, :] < n[:, None]                                   # (D, N)
    t = jn[None, :] * (2.0 * np.pi / np.maximum(n, 1))[:, None]
    ca, sa = np.cos(ang)[:, None], np.sin(ang)[:, None]
    cos_t, sin_t = np.cos(t), np.sin(t)
    ex = a_[:, None] * cos_t
    ey = b_[:, None] * sin_t
    base = np.stack([c[:, 0:1] + ca * ex - sa * ey, c[:, 1:2] + sa * ex + ca * ey], axis=2)  # (D, N, 2)
    g = base @ conics[:, :2, :2].transpose(0, 2, 1) + conics[:, None, :2, 2]
    g = np.where((conics[:, 0, 0] + conics[:, 1, 1] < 0)[:, None, None], -g, g)
    nrm = g / np.sqrt(g[..., 0] * g[..., 0] + g[..., 1] * g[..., 1])[..., None]   # (reductions over a tiny last
    # axis are slow in numpy; the same sum, written out)
    # profile offsets (one array per distinct half length, as np.arange gives them)
    svecs = [_profile_offsets(h, step) for h in hw]
    K = max(len(v) for v in svecs)
    S = np.full((D, K), np.nan)
    for d, v in enumerate(svecs):
        S[d, :len(v)] = v
    klen = np.array([len(v) for v in svecs])
    s_first = S[:, 0]
    s_last = S[np.arange(D), klen - 1]
    # profiles entirely inside the ROI (a segment is inside a box iff both its ends are)
    inside = prof_ok.copy()
    ends = [base + sv[:, None, None] * nrm for sv in (s_first, s_last)]
    for e in ends:
        inside &= ((e[..., 0] >= (x0 + 1)[:, None]) & (e[..., 0] <= (x1 - 2)[:, None])
                   & (e[..., 1] >= (y0 + 1)[:, None]) & (e[..., 1] <= (y1 - 2)[:, None]))
    # the smoothed image around the profiles that may be sampled, one crop per dot
    sampled = live[:, None] & (inside if method == "level" else prof_ok)                   # (D, N)
    s2 = np.concatenate([sampled, sampled], axis=1)
    ext = np.stack([f(np.where(s2, np.concatenate([e[..., i] for e in ends], axis=1), fill), axis=1)
                    for f, fill in ((np.min, np.inf), (np.max, -np.inf)) for i in (0, 1)], axis=1)    # (D, 4)
    ext[~sampled.any(axis=1)] = np.nan
    crop = src.crops_for(ext)

    def pts_at(sel_d, sel_j, sel_k):
        s_ = S[sel_d, sel_k]
        return (base[sel_d, sel_j, 0] + s_ * nrm[sel_d, sel_j, 0], base[sel_d, sel_j, 1] + s_ * nrm[sel_d, sel_j, 1])

    if method == "gradient":
        prof = np.full((D, N, K), np.nan)
        sd, sj, sk = np.nonzero(live[:, None, None] & prof_ok[:, :, None] & (np.arange(K)[None, None, :] <
                                                                             klen[:, None, None]))
        px, py = pts_at(sd, sj, sk)
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
    dark, plane, okl = dot_levels_batch(src.gray, conics, np.stack([x0, y0, x1, y1], 1))
    bright_c = plane[:, 0] * c[:, 0] + plane[:, 1] * c[:, 1] + plane[:, 2]
    with np.errstate(invalid="ignore"):
        okl &= live & (bright_c > dark)
    ratio = np.where(okl, dark / np.where(okl, bright_c, 1.0), 0.0)
    halfk = 0.5 * (1.0 + ratio)
    F = np.full((D, N, K), np.nan)   # profile minus half level, filled where sampled
    mid_dist = np.abs(0.5 * (S[:, :-1] + S[:, 1:]))  # (D, K-1), NaN past a profile's end
    todo = okl[:, None] & inside
    # the usual case: every measured dot has the same offsets, so a window's samples form a dense block
    tdots = np.nonzero(todo.any(axis=1))[0]
    k0 = int(klen[tdots[0]]) if len(tdots) else 0
    uniform = len(tdots) > 0 and bool(np.all(klen[tdots] == k0) and np.all(S[tdots, :k0] == S[tdots[0], :k0]))

    def fill(rd_, rj_, cols):
        """Sample the profiles (rd_[i], rj_[i]) at the offsets k where cols[d, k]."""
        if uniform:
            ks = np.nonzero(cols[tdots[0]])[0]
            if len(ks) == 0:
                return
            sv = S[tdots[0], ks][None, :]
            px = base[rd_, rj_, 0][:, None] + sv * nrm[rd_, rj_, 0][:, None]
            py = base[rd_, rj_, 1][:, None] + sv * nrm[rd_, rj_, 1][:, None]
            prof = src.sample(np.repeat(crop[rd_], px.shape[1]), px.ravel(), py.ravel()).reshape(px.shape)
            pl = plane[rd_]
            half = (px * pl[:, 0:1] + py * pl[:, 1:2] + pl[:, 2:3]) * halfk[rd_, None]
            F[rd_[:, None], rj_[:, None], ks[None, :]] = prof - half
            return
        rows = np.zeros((D, N), bool)
        rows[rd_, rj_] = True
        sd, sj, sk = np.nonzero(rows[:, :, None] & cols[:, None, :])
        px, py = pts_at(sd, sj, sk)
        prof = src.sample(crop[sd], px, py)
        half = (px * plane[sd, 0] + py * plane[sd, 1] + plane[sd, 2]) * halfk[sd]
        F[sd, sj, sk] = prof - half

    # the samples of the intervals within each window of the current boundary, widening only for the profiles
    # without a crossing yet: intervals outside a window are all further than those inside, so the nearest
    # crossing found inside one is the nearest of the whole profile. The nearest up-crossing of a profile just
    # sampled is searched among the intervals of the window (the others are not sampled yet).
    found = np.zeros((D, N), bool)
    k = np.zeros((D, N), int)
    prev = np.zeros((D, K), bool)
    in_prof = np.arange(K)[None, :] < klen[:, None]
    rd_, rj_ = np.nonzero(todo)
    for w in (*windows, np.inf):
        if len(rd_) == 0:
            break
        with np.errstate(invalid="ignore"):
            win_iv = mid_dist <= w                                       # (D, K-1)
        if w == 0:  # the nearest interval alone (the first of equally near ones: the one argmin picks)
            win_iv = np.zeros_like(win_iv)
            has = np.any(np.isfinite(mid_dist), axis=1)
            win_iv[np.nonzero(has)[0], np.nanargmin(np.where(has[:, None], mid_dist, 0.0)[has], axis=1)] = True
        win_s = np.zeros((D, K), bool)
        win_s[:, :-1] |= win_iv
        win_s[:, 1:] |= win_iv
        win_s &= in_prof
        fill(rd_, rj_, win_s & ~prev)
        span = np.nonzero(win_iv.any(axis=0))[0]
        lo, hi = (int(span[0]), int(span[-1]) + 1) if len(span) else (0, 0)
        Fw = F[rd_, rj_, lo:hi + 1]
        with np.errstate(invalid="ignore"):
            up = (Fw[:, :-1] < 0) & (Fw[:, 1:] >= 0)
        score = np.where(up, mid_dist[rd_, lo:hi], np.inf)
        kw = np.argmin(score, axis=1) if hi > lo else np.zeros(len(rd_), int)
        fw = np.isfinite(score[np.arange(len(rd_)), kw]) if hi > lo else np.zeros(len(rd_), bool)
        k[rd_, rj_] = np.where(fw, kw + lo, 0)
        found[rd_, rj_] = fw
        rd_, rj_ = rd_[~fw], rj_[~fw]
        prev = win_s
    ok = found & todo
    fa = np.take_along_axis(F, k[..., None], axis=2)[..., 0]
    fb = np.take_along_axis(F, (k + 1)[..., None], axis=2)[..., 0]
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
