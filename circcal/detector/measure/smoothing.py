"""The image the edge profiles are sampled from: Gaussian-smoothed and turned into cubic B-spline coefficients, one
crop around each dot (:class:`SmoothedImage`), all crops filtered by one OpenCV call.

Pixel convention: OpenCV's (integer coordinates are pixel centres).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from circcal.detector.kernels.jit import njit

__all__ = ["COMBINED_TAIL", "PREFILTER_HALF_LENGTH", "SPLINE_SUPPORT", "SmoothedImage"]

PREFILTER_HALF_LENGTH = 13
"""Taps on either side of the FIR form of the cubic B-spline prefilter (the recursive filter's impulse response
sqrt(3) z^|k|, z = sqrt(3) - 2, is below 1e-8 of its peak beyond 13 taps; the left-out tail is 5e-8 of its weight)."""
COMBINED_TAIL = 2e-6
"""Share of the combined (Gaussian * prefilter) kernel's weight its truncation may leave out: for sigma 1.5 its half
length falls from 19 to 8 taps (17 in all; 5e-8, the prefilter's own share, kept 23, and the filtering took 1.8x as
long). The kernel stays symmetric and is renormalised, so a straight edge's half-level crossing does not move; the
samples differ from the exact smoothing by <= ~1e-6 of the grey range (tested; ~5e-6 px at an edge), the centres by
~3e-8 px (median over 234 views)."""
SPLINE_SUPPORT = 3
"""Pixels a crop reaches beyond its filters for the cubic B-spline evaluation (4 coefficients around a sample point:
one below its pixel, two above, and one of slack)."""


class SmoothedImage:
    """A grey image and its Gaussian smoothing as cubic B-spline coefficients, in one crop per dot, for sampling edge
    profiles.

    The smoothing (``sigma`` px, reflected borders) and the spline coefficients (mirror boundary) are computed on
    demand in one crop per requested box (one box per dot, :meth:`crops_for`). A crop extends beyond its box (clipped
    to the image) by the reach of its filters plus the spline's own support, so samples inside the box equal those of
    smoothing the whole image. A later box reuses the crop made for the same dot (a crop holding the box, centred
    within :attr:`REUSE_PX` px of it), so a dot's samples depend on that dot alone: measuring all dots at once gives
    the same points as one at a time.

    Parameters
    ----------
    gray : numpy.ndarray
        (H, W) grey image, any real dtype.
    sigma : float
        The Gaussian smoothing's standard deviation, px (0: none).

    Attributes
    ----------
    gray : numpy.ndarray
        (H, W) the image, as given.
    sigma : float
        The smoothing scale, px.
    crops : numpy.ndarray
        (C, 4) int64: ``x0, y0, x1, y1`` px (exclusive ends) of each crop made so far.
    shape : tuple of int
        (H, W) of the image.
    margin : int
        Pixels a crop inside the image extends beyond its box.
    border_margin : int
        Pixels a crop at the image border extends beyond its box.
    SLACK : int
        Pixels a new crop extends beyond what its box needs.
    REUSE_PX : float
        px: how near a crop's centre must be to a box's for the box to reuse it.

    Notes
    -----
    The prefilter is the exact recursive B-spline filter written as its (symmetric, exponentially decaying) impulse
    response truncated at :data:`PREFILTER_HALF_LENGTH` taps (a 5e-8 share of its weight is left out). Both filters
    run in float32 (values good to ~1e-6 of the grey range, edge points to ~1e-5 px): the crops inside the image as
    one separable filter (Gaussian and prefilter convolved, the product's tails truncated, :data:`COMBINED_TAIL`:
    :func:`_combined_kernel`, reach :attr:`margin` - :data:`SPLINE_SUPPORT`) on all of them stacked
    (``cv2.sepFilter2D``), crops at the image border each on their own with the border reflections
    (``cv2.GaussianBlur`` then the prefilter, reach :attr:`border_margin` - :data:`SPLINE_SUPPORT`). The coefficients
    of all crops are held in one stacked atlas (:meth:`coefficient_atlas`, sampled by the compiled cubic B-spline
    evaluation of :mod:`circcal.detector.measure.edges`). Where the crops inside the image overlap (the dots of a
    board seen small: the crops of a 640x480 paper view cover its board ~3.5 times over), they are filtered as one
    window, their bounding box, when that has fewer pixels than their stack (0.3x the filtering time there), and a
    later box inside that window reuses it; the values are those of each crop filtered alone to float32 rounding
    (OpenCV's vectorised and scalar loops round a pixel alike only to ~1e-7: the paper's 640x480 views' centres move
    by < 1e-7 px).
    """

    SLACK = 4
    """Pixels a new crop extends beyond what its box needs, so the dot's next, slightly moved ellipse fits in it."""
    REUSE_PX = 4.0
    """A box reuses a crop that holds it and whose centre is within this many px of the box's (the same dot)."""

    def __init__(self, gray: np.ndarray, sigma: float):
        self.gray = gray
        self.sigma = float(sigma)
        self.crops = np.zeros((0, 4), np.int64)  # x0, y0, x1, y1 (exclusive) of each crop
        self._sheets: list[np.ndarray] = []  # float32 coefficients of crops stacked top to bottom
        self._place = np.zeros((0, 2), np.int64)  # (sheet, first row) of each crop
        self._shared = np.zeros(0, bool)  # whether each crop is a window shared by several boxes
        self._atlas: np.ndarray | None = None  # all sheets stacked
        self._rows = np.zeros(0, np.int64)  # first atlas row of each crop

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the image."""
        return self.gray.shape

    @property
    def margin(self) -> int:
        """Pixels a crop inside the image extends beyond its box: combined filter half length + spline support."""
        return len(_combined_kernel(self.sigma)) // 2 + SPLINE_SUPPORT

    @property
    def border_margin(self) -> int:
        """Pixels a crop at the image border extends beyond its box: Gaussian radius + prefilter half length +
        spline support."""
        return _gauss_radius(self.sigma) + PREFILTER_HALF_LENGTH + SPLINE_SUPPORT

    def crops_for(self, boxes: np.ndarray) -> np.ndarray:
        """The crop that serves each box, making the crops that are missing.

        Which crop serves which box is one compiled pass (:func:`_match_crops`: the measuring pass's boxes all lie in
        the steering pass's crops, ~12 against ~90 us of numpy calls for a 640x480 paper view).

        Parameters
        ----------
        boxes : numpy.ndarray
            (D, 4) float ``x0, y0, x1, y1`` px: the extent of the points to be sampled for each dot.

        Returns
        -------
        numpy.ndarray
            (D,) int64 crop index (into :attr:`crops`) for each box; -1 for a row with a NaN or infinite coordinate.
        """
        H, W = self.gray.shape
        m = self.margin
        boxes = np.ascontiguousarray(boxes, np.float64).reshape(-1, 4)
        out = np.empty(len(boxes), np.int64)
        need = np.empty((len(boxes), 4), np.int64)
        _match_crops(boxes, self.crops, self._shared, m, W, H, 2.0 * self.REUSE_PX, need, out)
        idx = np.nonzero(out == _NEW)[0]
        out[idx] = -1
        if not len(idx):
            return out
        need = need[idx]
        sl = self.SLACK
        new = np.column_stack(
            [
                np.maximum(0, need[:, 0] - sl),
                np.maximum(0, need[:, 1] - sl),
                np.minimum(W, need[:, 2] + sl),
                np.minimum(H, need[:, 3] + sl),
            ]
        )
        grow = self.border_margin - m  # crops that reach the border are filtered in two steps, reaching further
        inner = (new[:, 0] > 0) & (new[:, 1] > 0) & (new[:, 2] < W) & (new[:, 3] < H)
        b = ~inner
        new[b] = np.column_stack(
            [
                np.maximum(0, new[b, 0] - grow),
                np.maximum(0, new[b, 1] - grow),
                np.minimum(W, new[b, 2] + grow),
                np.minimum(H, new[b, 3] + grow),
            ]
        )
        # crops inside the image are filtered together, stacked in one array (the filters reach less than the margin,
        # so each crop's box only sees its own pixels; a pixel's arithmetic does not depend on where its crop sits);
        # crops at the image border each on their own, with the borders' reflections
        place = np.zeros((len(new), 2), np.int64)
        shared = np.zeros(len(new), bool)
        ii = np.nonzero(inner)[0]
        if len(ii):
            k1 = _combined_kernel(self.sigma)
            box = new[ii]
            u0, v0 = box[:, :2].min(axis=0).tolist()
            u1, v1 = box[:, 2:].max(axis=0).tolist()
            stacked_px = int(np.sum(box[:, 3] - box[:, 1])) * int(np.max(box[:, 2] - box[:, 0]))
            if len(ii) > 1 and (u1 - u0) * (v1 - v0) < stacked_px:  # one window holding them all
                win = self.gray[v0:v1, u0:u1]
                if win.dtype != np.uint8:
                    win = win.astype(np.float32)
                self._sheets.append(cv2.sepFilter2D(win, cv2.CV_32F, k1, k1, borderType=cv2.BORDER_REFLECT_101))
                new[ii] = (u0, v0, u1, v1)
                place[ii] = (len(self._sheets) - 1, 0)
                shared[ii] = True
            else:
                stack = _stacked([self.gray[c[1] : c[3], c[0] : c[2]] for c in box.tolist()])
                self._sheets.append(cv2.sepFilter2D(stack, cv2.CV_32F, k1, k1, borderType=cv2.BORDER_REFLECT_101))
                place[ii, 0] = len(self._sheets) - 1
                place[ii, 1] = np.cumsum(box[:, 3] - box[:, 1]) - (box[:, 3] - box[:, 1])
        for k in np.nonzero(b)[0].tolist():
            c = new[k].tolist()
            self._sheets.append(_spline_coefficients(self.gray[c[1] : c[3], c[0] : c[2]], self.sigma))
            place[k] = (len(self._sheets) - 1, 0)
        out[idx] = len(self.crops) + np.arange(len(new))
        self.crops = np.concatenate([self.crops, new])
        self._place = np.concatenate([self._place, place])
        self._shared = np.concatenate([self._shared, shared])
        self._atlas = None
        return out

    def coefficient_atlas(self, crop: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The spline coefficients of all crops stacked, and where the given crops lie in them.

        Parameters
        ----------
        crop : numpy.ndarray
            (D,) int: crop indices from :meth:`crops_for`; -1 gives zeros.

        Returns
        -------
        atlas : numpy.ndarray
            (R, C) float32: the coefficients of all crops stacked.
        rows : numpy.ndarray
            (D,) int64: each crop's first atlas row.
        origin : numpy.ndarray
            (D, 2) float64 ``x0, y0`` px: each crop's origin in the image. The coefficient of image pixel (x, y) of
            crop k is ``atlas[rows[k] + y - y0, x - x0]``.
        """
        if self._atlas is None:
            if not self._sheets:  # (no crop made: every box was empty)
                self._atlas = np.zeros((1, 1), np.float32)
            else:
                self._atlas = self._sheets[0] if len(self._sheets) == 1 else _stacked(self._sheets)
            first = np.cumsum([0] + [s.shape[0] for s in self._sheets])
            self._rows = first[self._place[:, 0]] + self._place[:, 1]
        crop = np.asarray(crop, np.int64)
        valid = crop >= 0
        k = np.where(valid, crop, 0)
        if not len(self.crops):
            return self._atlas, np.zeros(len(crop), np.int64), np.zeros((len(crop), 2))
        rows = np.where(valid, self._rows[k], 0)
        org = np.where(valid[:, None], self.crops[k, :2].astype(np.float64), 0.0)
        return self._atlas, rows, org


_NEW = -2
""":func:`_match_crops`' mark of a box that needs a new crop."""


@njit(cache=True, nogil=True)
def _match_crops(boxes, have, shared, margin, W, H, reuse, need, out):
    """For each box of ``boxes`` (D, 4) float ``x0, y0, x1, y1``: writes into ``need`` (D, 4) int the pixels its
    samples need (the box's floor, grown by ``margin`` px, clipped to the ``W`` x ``H`` image, exclusive ends) and
    into ``out`` (D,) the first crop of ``have`` (C, 4) that serves it: one that holds ``need`` and is ``shared`` (a
    window filtered for several boxes) or whose centre lies within ``reuse / 2`` px of need's in x and y (the same
    dot); -1 for a box with a NaN or infinite coordinate, :data:`_NEW` where no crop serves."""
    D = len(boxes)
    for d in range(D):
        if not (
            np.isfinite(boxes[d, 0])
            and np.isfinite(boxes[d, 1])
            and np.isfinite(boxes[d, 2])
            and np.isfinite(boxes[d, 3])
        ):
            out[d] = -1
            continue
        n0 = max(0, np.int64(np.floor(boxes[d, 0])) - margin)
        n1 = max(0, np.int64(np.floor(boxes[d, 1])) - margin)
        n2 = min(W, np.int64(np.floor(boxes[d, 2])) + 1 + margin)
        n3 = min(H, np.int64(np.floor(boxes[d, 3])) + 1 + margin)
        need[d, 0], need[d, 1], need[d, 2], need[d, 3] = n0, n1, n2, n3
        out[d] = _NEW
        for c in range(len(have)):
            if not (have[c, 0] <= n0 and have[c, 1] <= n1 and have[c, 2] >= n2 and have[c, 3] >= n3):
                continue
            if shared[c] or (
                abs(np.float64((have[c, 0] + have[c, 2]) - (n0 + n2))) <= reuse
                and abs(np.float64((have[c, 1] + have[c, 3]) - (n1 + n3))) <= reuse
            ):
                out[d] = c
                break


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
    """(2 h + 1,) float32: OpenCV's Gaussian kernel of ``sigma`` (radius r, none for 0) convolved with the FIR
    prefilter (half length L): smoothing and prefiltering in one separable filter (away from the image borders).
    The product's tails decay like the prefilter's; they are cut where at most :data:`COMBINED_TAIL` of the weight
    is left out (h = 8 instead of r + L = 19 for sigma 1.5: 17 taps, not 39) and the rest renormalised to a sum of 1.
    """
    k = _prefilter_kernel().astype(np.float64)
    r = _gauss_radius(sigma)
    if r:
        k = np.convolve(k, cv2.getGaussianKernel(2 * r + 1, sigma, cv2.CV_64F)[:, 0])
    n = len(k) // 2
    tail = np.cumsum(np.abs(k[::-1][:n]))[::-1] * 2.0 / np.abs(k).sum()  # tail[j]: weight beyond half length j
    h = next((j for j in range(1, n) if tail[j] <= COMBINED_TAIL), n)
    k = k[n - h : n + h + 1]
    return (k / k.sum()).astype(np.float32)


def _stacked(rois: list[np.ndarray]) -> np.ndarray:
    """The images ``rois`` (each (h_k, w_k)) stacked top to bottom, left-aligned, zero-padded on the right, as one
    (sum h_k, max w_k) array (uint8 kept, other dtypes as float32)."""
    dt = np.uint8 if all(r.dtype == np.uint8 for r in rois) else np.float32
    out = np.zeros((sum(r.shape[0] for r in rois), max(r.shape[1] for r in rois)), dt)
    r0 = 0
    for r in rois:
        out[r0 : r0 + r.shape[0], : r.shape[1]] = r
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
