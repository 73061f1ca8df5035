"""Segmentation: binary masks of the dark dots that survive uneven, strong and weak illumination, and the image
scales they are made at (a shrunk copy first; the edges are always measured at full resolution).

Masks are (H, W) uint8, 255 where the image is dark. Pixel convention: OpenCV's (integer coordinates are pixel
centres).
"""
from __future__ import annotations

import threading
from collections.abc import Iterator

import cv2
import numpy as np

from circcal.detector.image import HIST_EXACT_COUNT
from circcal.detector.jit import njit

__all__ = ["SHRINK_MIN_SIDE", "SHRUNK_MIN_RADIUS", "guided_filter", "segmentation_scales", "segmentations", "shrink",
           "noise_sigma_u8", "speckled"]

GUIDED_RADIUS_DIVISOR = 400
"""Guided-filter radius = the shorter image side / this (px): ~1 px of smoothing per 400 px, a fraction of the smallest
dots a sensor of that size resolves, so their edges stay."""
GUIDED_MIN_RADIUS = 2
"""... and at least this (px): below it the filter does not denoise."""
GUIDED_EPS = 0.02 ** 2
"""Guided-filter regularisation, in units of the [0, 1] intensity range squared: variations below ~2 % of the
range (noise) are smoothed, the dot-to-board contrast (tens of %) is kept as an edge."""
ADAPTIVE_WINDOW_DIVISORS = (8.0, 3.0, 16.0)
"""Adaptive-mean windows, as divisors of the shorter image side, in the order tried: 1/8 (a few dots wide: follows
uneven light, still sees a dot against its surround), 1/3 (large dots close up), 1/16 (steep light gradients)."""
ADAPTIVE_OFFSET = 0.08
"""A pixel is dark when it is this share of the full contrast (after the stretch to 0..255) below its window's mean:
above the noise of a weak-light image, below the dot-to-board contrast."""
MIN_WINDOW = 3
"""The smallest adaptive window (px; OpenCV needs an odd size of at least 3)."""
SHRINK_MIN_SIDE = 360
"""Segmentation starts on the image shrunk by the largest integer factor that leaves its shorter side at least this
many pixels (factor 2 from 720 px, 3 from 1080 px, ...; none below 720 px)."""
SHRUNK_MIN_RADIUS = 3.0
"""Dots smaller than this (px, in the shrunk image) are segmented again at a finer scale."""
MAX_TRANSITIONS = 0.35
"""A mask in which more than this share of horizontally neighbouring pixels differ is speckle (noise stretched to the
full range, a dense texture), not dots: a board of dots 6 px across at a pitch of 7 px, filling the frame, has
~0.3; noise thresholded at its median ~0.5. Its contour search would take seconds to minutes on a large frame
(850,000 contours in a 12 MP mask: 40 s), so it is skipped (:func:`speckled`)."""


def segmentations(gray_u8: np.ndarray) -> Iterator[tuple[str, np.ndarray]]:
    """Yield ``(name, mask)`` for ``gray_u8`` (H, W) uint8 (contrast-stretched): masks, 255 where the image is dark
    (dot candidates), in the order worth trying.

    1. Otsu on the guided-filtered image (:func:`guided_filter`: edge-preserving denoise; global illumination).
    2. Adaptive-mean thresholds of the same filtered image with windows of 1/8, 1/3 and 1/16 of the shorter image
       side (:data:`ADAPTIVE_WINDOW_DIVISORS`: uneven illumination, shadows, weak contrast); the offset is
       :data:`ADAPTIVE_OFFSET` (8 %) of the full contrast. Named ``adaptive<window px>``.
    """
    H, W = gray_u8.shape
    radius = max(GUIDED_MIN_RADIUS, int(round(min(H, W) / GUIDED_RADIUS_DIVISOR)))
    f8 = guided_filter(gray_u8, radius, GUIDED_EPS)
    _, otsu = cv2.threshold(f8, 0, 255, cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)
    yield "otsu", otsu
    for divisor in ADAPTIVE_WINDOW_DIVISORS:
        block = _odd_window(min(H, W) / divisor)
        yield f"adaptive{block}", cv2.adaptiveThreshold(f8, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV,
                                                        block, 255 * ADAPTIVE_OFFSET)


MAX_STRETCHED_NOISE = 25.0
"""Grey levels (of 255): an image whose noise, after the contrast stretch, is larger than this (a tenth of the range)
shows nothing but noise (a board's contrast is tens of noise sigmas: the weak-light and very noisy fixtures measure
5-13 levels); it is not segmented (its masks would be speckle: a 48 MP frame of noise took minutes)."""


def noise_sigma_u8(img: np.ndarray) -> float:
    """Robust noise sigma (grey levels) of ``img`` (H, W) uint8 from the median absolute difference of horizontal
    neighbours on every 4th row (``median / (0.6745 sqrt 2)``; 0 on noiseless renders, whose flat areas dominate)."""
    rows = img[::4]
    if rows.shape[1] < 2:
        return 0.0
    diff = cv2.absdiff(rows[:, 1:], rows[:, :-1])
    if diff.size < HIST_EXACT_COUNT:
        counts = cv2.calcHist([diff], [0], None, [256], [0, 256]).reshape(-1).astype(np.int64)
    else:
        counts = np.bincount(diff.ravel(), minlength=256)
    median = int(np.searchsorted(np.cumsum(counts), (counts.sum() + 1) // 2))
    return median / (0.6745 * np.sqrt(2.0))


def speckled(mask: np.ndarray) -> bool:
    """Whether ``mask`` (H, W) uint8 is speckle rather than blobs (:data:`MAX_TRANSITIONS`; every 4th row counted)."""
    rows = mask[::4]
    if rows.shape[1] < 2:
        return False
    changes = np.count_nonzero(rows[:, 1:] != rows[:, :-1])
    return changes > MAX_TRANSITIONS * rows.shape[0] * (rows.shape[1] - 1)


def _odd_window(n: float) -> int:
    """``n`` px rounded to an odd window size of at least :data:`MIN_WINDOW`."""
    return max(MIN_WINDOW, int(round(n)) | 1)


WORKSPACE_MAX_PX = 1 << 20
"""Images of up to this many pixels are guided-filtered in work planes each thread keeps (:func:`_work_planes`;
4 float32 planes, 16 MiB at most per thread). Segmentation runs on images of ~0.2-1 MP at every frame size (the
shrunk scales, the board's windows), so nearly every call reuses them; larger ones allocate afresh."""

_workspace = threading.local()


def _work_planes(shape: tuple[int, int], n: int) -> list[np.ndarray]:
    """``n`` float32 (H, W) planes, contiguous, whose values are garbage: views of a buffer this thread keeps while
    ``H W <= WORKSPACE_MAX_PX`` (grown when a larger image comes), else fresh arrays. Fresh planes cost the process
    new pages on every call under glibc's default malloc (buffers of ~1 MB go back to the system when freed and
    fault in again when touched: at 640x480 the guided filter took 5.3 ms instead of 1.7 ms, ~1,700 page faults);
    kept, they fault once. One buffer per thread: detection runs images in threads (:mod:`circcal.detector.files`)."""
    size = int(shape[0]) * int(shape[1])
    if size > WORKSPACE_MAX_PX:
        return [np.empty(shape, np.float32) for _ in range(n)]
    buf = getattr(_workspace, "planes", None)
    if buf is None or buf.shape[0] < n or buf.shape[1] < size:
        buf = np.empty((n, size if buf is None else max(size, buf.shape[1])), np.float32)
        _workspace.planes = buf
    return [buf[i, :size].reshape(shape) for i in range(n)]


def guided_filter(gray_u8: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """Self-guided filter (He, Sun & Tang 2013) of a uint8 image (H, W) on ``g = gray_u8 / 255`` (``radius`` px, ``eps``
    in units of the [0, 1] intensity range squared), rounded back to uint8: the edge-preserving denoise the paper
    uses before segmentation. The steps of ``cv2.ximgproc.guidedFilter(g, g, radius, eps)`` (float32, box means with
    reflected borders) written out with ``cv2.boxFilter`` and in-place float32 arithmetic in this thread's work
    planes (:func:`_work_planes`): ximgproc's generic multi-channel code takes ~1.6x as long for one grey channel.
    The same values but for float32 rounding: at most one grey level apart, on ~1e-4 of a board image's pixels
    (0.6 % of pure noise's; tests/test_detect.py)."""
    k = (2 * int(radius) + 1, 2 * int(radius) + 1)

    def box(x: np.ndarray, out: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(x, cv2.CV_32F, k, dst=out, normalize=True, borderType=cv2.BORDER_REFLECT)

    g, mean, t, cov = _work_planes(gray_u8.shape, 4)
    np.multiply(gray_u8, np.float32(1.0 / 255.0), out=g, dtype=np.float32)
    mean = box(g, mean)
    np.multiply(g, g, out=t)
    cov = box(t, cov)                                 # mean of g^2, then the variance
    np.multiply(mean, mean, out=t)
    np.subtract(cov, t, out=cov)
    np.add(cov, np.float32(eps), out=t)
    np.divide(np.float32(1.0), t, out=t)
    a = np.multiply(cov, t, out=cov)                  # a = var / (var + eps)
    np.multiply(a, mean, out=t)
    b = np.subtract(mean, t, out=mean)                # b = mean (1 - a)
    q = box(a, t)
    q *= g
    q += box(b, a)                                    # (a is spent: its plane takes the box mean of b)
    return cv2.convertScaleAbs(q, alpha=255.0)


def segmentation_scales(height: int, width: int) -> tuple[int, ...]:
    """Image scales (1 = full, s = shrunk s times) to segment the whole image at, in order: the working scale
    ``min(H, W) // SHRINK_MIN_SIDE`` first (when at least 2; pixel-area averaging; ~ s^2 fewer pixels to filter),
    then halving it (rounded up) down to 2 (a grid of small dots in a large image); full resolution only for an image
    too small to shrink. At scale 2 a dot 6 px across is 3 px and still a candidate: a board recognised with dots
    smaller than :data:`SHRUNK_MIN_RADIUS` at its scale is segmented again at the coarsest scale where they are not,
    in its own window (:mod:`circcal.detector.find`), never the whole frame (a 48 MP frame of noise alone took
    minutes). The edges are always measured at full resolution, starting from these contours: only the starting
    ellipses differ between scales (on the fixtures the centres move by ~1e-4 px, up to ~1e-2 px on strongly
    blurred images, where the two-pass refinement still depends slightly on its start, with the same accuracy
    against the truth). Setting ``SHRINK_MIN_SIDE`` above any image size restores full-resolution segmentation
    everywhere."""
    s = min(height, width) // SHRINK_MIN_SIDE
    if s < 2:
        return (1,)
    out = [s]
    while s > 2:
        s = (s + 1) // 2
        out.append(s)
    return tuple(out)


def shrink(gray: np.ndarray, scale: int) -> np.ndarray:
    """(H // s, W // s) averages of the s x s pixel blocks of ``gray`` (H, W), ``s = scale`` (uint8, uint16 and
    float32 kept; other dtypes via float32, as :func:`~circcal.detector.image.as_gray` converts float64 colour).

    ``cv2.resize(..., INTER_AREA)``'s values; for uint8 and ``s >= 3`` computed by :func:`_block_means_u8` (the same
    values, ~3x faster: OpenCV has a fast path for 2x only, its general area loop took ~1.5 ms of a 1080p frame)."""
    H, W = gray.shape
    g = gray[:H // scale * scale, :W // scale * scale]
    if g.dtype == np.uint8 and scale >= 3 and W // scale and H // scale:
        return _block_means_u8(np.ascontiguousarray(g), int(scale), np.empty((H // scale, W // scale), np.uint8))
    if g.dtype not in (np.uint8, np.uint16, np.float32):
        g = g.astype(np.float32)
    return cv2.resize(g, (W // scale, H // scale), interpolation=cv2.INTER_AREA)


@njit(cache=True, nogil=True)
def _block_means_u8(g, s, out):
    """Writes into ``out`` (H, W) uint8 the means of the ``s`` x ``s`` blocks of ``g`` (H s, W s) uint8, rounded
    as OpenCV's area resize rounds them (float32 product with 1 / s^2, half to even; equal to
    ``cv2.resize(g, (W, H), interpolation=cv2.INTER_AREA)`` for s >= 3, tested); returns ``out``. The s rows of a
    block row are summed first, then the s columns of each block, each pass a contiguous loop that vectorises
    (summing each block's columns in an inner loop of s did not: 0.75 against 0.47 ms for a 1080p frame)."""
    H, W = out.shape
    inv = np.float32(1.0) / np.float32(s * s)
    wide = W * s
    acc = np.zeros(wide, np.int32)
    tot = np.zeros(W, np.int32)
    for y in range(H):
        first = g[y * s]
        for x in range(wide):
            acc[x] = np.int32(first[x])
        for r in range(1, s):
            row = g[y * s + r]
            for x in range(wide):
                acc[x] += np.int32(row[x])
        for x in range(W):
            tot[x] = acc[x * s]
        for k in range(1, s):
            for x in range(W):
                tot[x] += acc[x * s + k]
        for x in range(W):
            out[y, x] = np.uint8(np.rint(np.float32(tot[x]) * inv))
    return out
