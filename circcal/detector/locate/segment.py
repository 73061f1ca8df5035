"""Segmentation: binary masks of the dark dots that survive uneven, strong and weak illumination, and the image
scales they are made at (a shrunk copy first; the edges are always measured at full resolution).

Masks are (H, W) uint8, 255 where the image is dark. Pixel convention: OpenCV's (integer coordinates are pixel
centres).
"""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np

from circcal.detector.image import count_into, histogram_u8
from circcal.detector.kernels.jit import njit

KERNEL_IMPORTS = ("circcal.detector.image",)
"""Kernel modules whose kernels this module's kernels call (:mod:`circcal.detector.kernels.jit`)."""

__all__ = [
    "SHRINK_MIN_SIDE",
    "SHRUNK_MIN_RADIUS",
    "guided_filter",
    "otsu_threshold",
    "segmentation_scales",
    "segmentations",
    "shrink",
    "noise_sigma_u8",
    "speckled",
]

GUIDED_RADIUS_DIVISOR = 400
"""Guided-filter radius = the shorter image side / this (px): ~1 px of smoothing per 400 px, a fraction of the smallest
dots a sensor of that size resolves, so their edges stay."""
GUIDED_MIN_RADIUS = 2
"""... and at least this (px): below it the filter does not denoise."""
GUIDED_EPS = 0.02**2
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


def segmentations(
    gray_u8: np.ndarray, noise_sigma: float | None = None, hist: np.ndarray | None = None
) -> Iterator[tuple[str, np.ndarray]]:
    """Masks of the dark dots of ``gray_u8``, 255 where the image is dark (dot candidates), in the order worth trying.

    1. ``otsu``: Otsu's threshold of the image as it is (global illumination). Its threshold lies between the dots'
       dark and the board's white, about half the contrast from either (~100 grey levels after the stretch; the
       noise of an image worth segmenting is below :data:`MAX_STRETCHED_NOISE`, 25), so noise moves only the edge
       pixels of this mask, and those only seed the edge fit.
    2. ``guided-otsu``: on a noisy image (noise above :data:`GUIDED_MIN_NOISE`, or not known), Otsu on the
       guided-filtered image (:func:`guided_filter`: edge-preserving denoise): where uneven light brings the board's
       white near the global threshold, noise crosses it in the plain image.
    3. Adaptive-mean thresholds (of the filtered image, on a noisy one) with windows of 1/8, 1/3 and 1/16 of the
       shorter image side (:data:`ADAPTIVE_WINDOW_DIVISORS`: uneven illumination, shadows, weak contrast); the offset
       is :data:`ADAPTIVE_OFFSET` (8 %) of the full contrast, 20 grey levels: there noise does cross the threshold
       unless filtered. Named ``adaptive<window px>``.

    Parameters
    ----------
    gray_u8 : numpy.ndarray
        (H, W) uint8, contrast-stretched.
    noise_sigma : float or None, optional
        The image's noise (grey levels, :func:`noise_sigma_u8`), when known: an image whose noise is at most
        :data:`GUIDED_MIN_NOISE` is not filtered at all (the filter would change no flat pixel's side of any
        threshold).
    hist : numpy.ndarray or None, optional
        (256,) int64 the counts of ``gray_u8``'s values when the caller has them
        (:func:`~circcal.detector.image.normalise_u8` gives them), for Otsu's threshold.

    Yields
    ------
    name : str
        ``"otsu"``, ``"guided-otsu"`` or ``"adaptive<window px>"``.
    mask : numpy.ndarray
        (H, W) uint8, 255 where dark.

    Examples
    --------
    >>> img = np.full((40, 40), 200, np.uint8)
    >>> img[10:20, 10:20] = 30
    >>> [name for name, mask in segmentations(img)]
    ['otsu', 'guided-otsu', 'adaptive5', 'adaptive13', 'adaptive3']
    """
    H, W = gray_u8.shape
    counts = histogram_u8(gray_u8) if hist is None else hist
    _, otsu = cv2.threshold(gray_u8, otsu_threshold(counts), 255, cv2.THRESH_BINARY_INV)
    yield "otsu", otsu
    if noise_sigma is not None and noise_sigma <= GUIDED_MIN_NOISE:
        f8 = gray_u8
    else:
        radius = max(GUIDED_MIN_RADIUS, int(round(min(H, W) / GUIDED_RADIUS_DIVISOR)))
        filtered = np.zeros(256, np.int64)
        f8 = guided_filter(gray_u8, radius, GUIDED_EPS, filtered)
        _, otsu = cv2.threshold(f8, otsu_threshold(filtered), 255, cv2.THRESH_BINARY_INV)
        yield "guided-otsu", otsu
    for divisor in ADAPTIVE_WINDOW_DIVISORS:
        block = _odd_window(min(H, W) / divisor)
        yield (
            f"adaptive{block}",
            cv2.adaptiveThreshold(
                f8, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, block, 255 * ADAPTIVE_OFFSET
            ),
        )


GUIDED_MIN_NOISE = 255 * ADAPTIVE_OFFSET / 5.0
"""Grey levels (~4.1): the guided filter runs on images whose noise (:func:`noise_sigma_u8`) exceeds this, once
their plain Otsu mask has shown no whole board (:func:`segmentations`). Below it a pixel of a flat area crosses none
of the thresholds (the adaptive ones lie :data:`ADAPTIVE_OFFSET` of the range, 20 levels, below their window's
mean: a 5-sigma excursion; Otsu's between the board's white and the dots' dark), so the filter would move only edge
pixels, by a fraction of a pixel, and the contours only seed the edge fit. The filter costs ~1.4 ms of a 640x480
detection; clean and lightly noisy images (renders, most photographs in good light) never run it, nor do noisy ones
whose board Otsu's plain threshold shows (the paper's weak-light views, 10-12 levels: their plain and filtered Otsu
masks are the same)."""
MAX_STRETCHED_NOISE = 25.0
"""Grey levels (of 255): an image whose noise, after the contrast stretch, is larger than this (a tenth of the range)
is not segmented at that scale (its masks would be speckle: a 48 MP frame of noise took minutes). The weak-light and
very noisy fixtures measure 5-13 levels; a board only a few noise sigmas deep (a dim photograph at high gain)
measures more and is segmented at a coarser scale, whose block means hold less noise
(:data:`circcal.detector.locate.search.NOISY_MIN_SIDE`); noise alone measures ~50 at every scale."""


def noise_sigma_u8(img: np.ndarray) -> float:
    """Robust noise sigma of ``img`` from the median absolute difference of horizontal neighbours on every 4th row.

    ``median / (0.6745 sqrt 2)``; 0 on noiseless renders, whose flat areas dominate.

    Parameters
    ----------
    img : numpy.ndarray
        (H, W) uint8.

    Returns
    -------
    float
        Noise sigma, grey levels.

    Examples
    --------
    >>> float(noise_sigma_u8(np.zeros((8, 8), np.uint8)))
    0.0
    """
    rows = img[::4]
    if rows.shape[1] < 2:
        return 0.0
    counts = histogram_u8(cv2.absdiff(rows[:, 1:], rows[:, :-1]))
    median = int(np.searchsorted(np.cumsum(counts), (counts.sum() + 1) // 2))
    return median / (0.6745 * np.sqrt(2.0))


def speckled(mask: np.ndarray) -> bool:
    """Whether ``mask`` is speckle rather than blobs (:data:`MAX_TRANSITIONS`; every 4th row counted).

    Parameters
    ----------
    mask : numpy.ndarray
        (H, W) uint8 segmentation.

    Returns
    -------
    bool
        ``True`` when more than :data:`MAX_TRANSITIONS` of horizontally neighbouring pixels differ.

    Examples
    --------
    >>> bool(speckled(np.zeros((8, 8), np.uint8)))
    False
    """
    rows = mask[::4]
    if rows.shape[1] < 2:
        return False
    changes = np.count_nonzero(rows[:, 1:] != rows[:, :-1])
    return changes > MAX_TRANSITIONS * rows.shape[0] * (rows.shape[1] - 1)


def _odd_window(n: float) -> int:
    """``n`` px rounded to an odd window size of at least :data:`MIN_WINDOW`."""
    return max(MIN_WINDOW, int(round(n)) | 1)


def guided_filter(gray_u8: np.ndarray, radius: int, eps: float, hist: np.ndarray | None = None) -> np.ndarray:
    """Self-guided filter (He, Sun & Tang 2013) of a uint8 image on ``g = gray_u8 / 255``, rounded back to uint8.

    The edge-preserving denoise the paper uses before segmentation. The values of
    ``cv2.ximgproc.guidedFilter(g, g, radius, eps)`` (box means with reflected borders, float32) as their steps
    written out with ``cv2.boxFilter`` and float32 arithmetic give them (the same to the bit, tested), in one compiled
    pass over the rows (:func:`_guided_kernel`): the rows in flight are held in small ring buffers, so a frame of any
    size streams through the cache once, where the ten whole-image passes of the written-out filter each went through
    memory (3 MP: ~13 against ~36 ms; 640x480: ~1.3 against ~1.7 ms, one thread). ximgproc's own filter rounds a few
    pixels differently: at most one grey level apart, on ~1e-4 of a board image's pixels (0.3 % of pure noise's;
    tests/detector/test_locate.py).

    Parameters
    ----------
    gray_u8 : numpy.ndarray
        (H, W) uint8.
    radius : int
        Box radius, px.
    eps : float
        Regularisation, in units of the [0, 1] intensity range squared.
    hist : numpy.ndarray or None, optional
        (256,) int64; if given, the counts of the result's values are added to it (in place: what Otsu's threshold
        needs, :func:`otsu_threshold`).

    Returns
    -------
    numpy.ndarray
        (H, W) uint8 filtered image.
    """
    img = np.ascontiguousarray(gray_u8, np.uint8)
    out = np.empty(img.shape, np.uint8)
    counts = np.zeros(256, np.int64) if hist is None else hist
    _guided_kernel(img, int(radius), float(eps), out, counts)
    return out


@njit(cache=True, nogil=True, inline="always")
def _reflect(p, n):
    """Index ``p`` reflected into [0, n) as OpenCV's ``BORDER_REFLECT`` does (``fedcba|abcdefgh|hgfedcb``, repeated
    for reaches beyond one reflection)."""
    if n == 1:
        return 0
    while p < 0 or p >= n:
        p = -p - 1 if p < 0 else 2 * n - 1 - p
    return p


@njit(cache=True, nogil=True, error_model="numpy")
def _guided_kernel(src, r, eps64, out, hist):
    """Writes :func:`guided_filter` of ``src`` (H, W) uint8 (radius ``r``, ``eps64``) into ``out`` (H, W) uint8 and
    adds the counts of its values to ``hist`` (256,).

    The steps of the written-out filter, each box mean ``float32(sum * (1 / (2 r + 1)^2))`` of an exact sum (what
    OpenCV's float32 box filter computes: it sums in float64, exactly for these values), ``g = float32(v) *
    float32(1 / 255)``::

        m = box(g); m2 = box(float32(g g)); cov = m2 - m m; a = cov (1 / (cov + eps)); b = m - a m   (float32)
        q = box(a) g + box(b); out = round(|255 q|) (half to even, at most 255)

    Exact sums from integers: ``g`` is a multiple of 2^-31 and ``g g`` of 2^-39 (the smallest non-zero values'
    ulps), so both are summed as int64 multiples of those. ``a`` and ``b`` are summed as int64 multiples of 2^-40
    (each rounded to one): their box means differ from float64 sums by < 1e-12, which moves a float32 rounding only
    at exact ties. Box sums slide along rows and columns (O(1) per pixel for any radius); a pass keeps its
    column sums over the 2 r + 1 rows of the window, and ``a``, ``b`` of the last 2 r + 2 rows in rings, so the
    second pass (the box means of ``a`` and ``b``) runs r rows behind the first. ``error_model="numpy"``: a float
    division without Python's zero check, which would keep the loop from vectorising (``cov + eps`` > 0 anyway).
    Inner loops index plain views from 0 (an index with an offset makes numba check for negative indices, which
    also stops the vectorisation)."""
    H, W = src.shape
    eps = np.float32(eps64)
    one = np.float32(1.0)
    inv255 = np.float32(1.0 / 255.0)
    k255 = np.float32(255.0)
    s31 = np.float32(2.0**31)
    s39 = np.float32(2.0**39)
    u31 = 2.0**-31
    u39 = 2.0**-39
    s40 = 2.0**40
    u40 = 2.0**-40
    magic = np.float32(8388608.0)  # 2^23: (v + 2^23) - 2^23 rounds 0 <= v < 2^23 half to even
    n = 2 * r + 1
    scale = 1.0 / (n * n)
    K = 2 * r + 2
    ra = np.empty((K, W), np.float32)  # a, b of the last K rows (row y in slot y % K)
    rb = np.empty((K, W), np.float32)
    vg = np.zeros(W + 2 * r, np.int64)  # column sums over the window's rows, r reflected columns each side
    vgg = np.zeros(W + 2 * r, np.int64)
    va = np.zeros(W + 2 * r, np.int64)
    vb = np.zeros(W + 2 * r, np.int64)
    h1 = np.empty(W, np.int64)  # row sums of the column sums: the box sums of one row
    h2 = np.empty(W, np.int64)
    part = np.zeros((8, 256), np.int32)  # partial histograms (image.count_into)
    orow = np.empty(W, np.uint8)  # an output row, copied out whole: stores into ``out`` among the loads of
    # ``src`` slowed the pass by up to 1.5x where the two arrays lie some hundred bytes apart modulo 4 KiB
    xr = np.empty(2 * r, np.int64)  # the columns the reflected margins repeat
    for k in range(r):
        xr[k] = _reflect(k - r, W)
        xr[r + k] = _reflect(W + k, W)
    cg, cgg, ca, cb = vg[r : r + W], vgg[r : r + W], va[r : r + W], vb[r : r + W]
    for y in range(H + r):
        if y < H:  # first pass, row y: a and b
            if y == 0:
                for yy in range(-r, r + 1):
                    row = src[_reflect(yy, H)]
                    for x in range(W):
                        g = np.float32(row[x]) * inv255
                        cg[x] += np.int64(g * s31)
                        cgg[x] += np.int64((g * g) * s39)
            else:
                add, sub = src[_reflect(y + r, H)], src[_reflect(y - r - 1, H)]
                for x in range(W):
                    g = np.float32(add[x]) * inv255
                    z = np.float32(sub[x]) * inv255
                    cg[x] += np.int64(g * s31) - np.int64(z * s31)
                    cgg[x] += np.int64((g * g) * s39) - np.int64((z * z) * s39)
            _slide(vg, vgg, xr, r, h1, h2)
            ar, br = ra[y % K], rb[y % K]
            for x in range(W):
                m = np.float32((h1[x] * u31) * scale)
                m2 = np.float32((h2[x] * u39) * scale)
                cov = m2 - m * m
                a = cov * (one / (cov + eps))
                ar[x] = a
                br[x] = m - a * m
        yo = y - r  # second pass, row yo: its a, b rows up to yo + r are in the rings
        if yo < 0:
            continue
        if yo == 0:
            for yy in range(-r, r + 1):
                aa, bb = ra[_reflect(yy, H) % K], rb[_reflect(yy, H) % K]
                for x in range(W):
                    ca[x] += np.int64(np.float64(aa[x]) * s40 + 0.5)
                    cb[x] += np.int64(np.float64(bb[x]) * s40 + 0.5)
        else:
            s1, s0 = _reflect(yo + r, H) % K, _reflect(yo - r - 1, H) % K
            aa, bb, az, bz = ra[s1], rb[s1], ra[s0], rb[s0]
            for x in range(W):
                ca[x] += np.int64(np.float64(aa[x]) * s40 + 0.5) - np.int64(np.float64(az[x]) * s40 + 0.5)
                cb[x] += np.int64(np.float64(bb[x]) * s40 + 0.5) - np.int64(np.float64(bz[x]) * s40 + 0.5)
        _slide(va, vb, xr, r, h1, h2)
        row = src[yo]
        for x in range(W):
            q = np.float32((h1[x] * u40) * scale) * (np.float32(row[x]) * inv255) + np.float32((h2[x] * u40) * scale)
            orow[x] = np.uint8(min((abs(q * k255) + magic) - magic, k255))
        count_into(orow, part)
        out[yo, :] = orow
    for v in range(256):
        for k in range(8):
            hist[v] += part[k, v]


@njit(cache=True, nogil=True, inline="always")
def _slide(v1, v2, xr, r, h1, h2):
    """Row box sums ``h1``, ``h2`` (W,) of the column sums ``v1``, ``v2`` (W + 2 r,) int64, whose image columns are
    ``v[r:r + W]``: their reflected margins filled from the columns ``xr`` (2 r,) first."""
    W = h1.shape[0]
    n = 2 * r + 1
    for k in range(2 * r):
        j = k if k < r else W + k
        v1[j] = v1[r + xr[k]]
        v2[j] = v2[r + xr[k]]
    s1 = np.int64(0)
    s2 = np.int64(0)
    for k in range(n - 1):
        s1 += v1[k]
        s2 += v2[k]
    p1, p2, m1, m2 = v1[n - 1 : n - 1 + W], v2[n - 1 : n - 1 + W], v1[:W], v2[:W]
    for x in range(W):
        s1 += p1[x]
        s2 += p2[x]
        h1[x] = s1
        h2[x] = s2
        s1 -= m1[x]
        s2 -= m2[x]


def otsu_threshold(hist: np.ndarray) -> int:
    """Otsu's threshold of an 8-bit image from its histogram ``hist``.

    The level ``t`` that maximises the between-class variance of ``<= t`` and ``> t``, as
    ``cv2.threshold(..., THRESH_OTSU)`` computes it (the same value, tested), without its own pass over the pixels
    (:func:`_otsu_kernel`).

    Parameters
    ----------
    hist : numpy.ndarray
        (256,) int counts of the image's values.

    Returns
    -------
    int
        The threshold, grey levels; 0 for an empty histogram.

    Examples
    --------
    >>> hist = np.zeros(256, np.int64)
    >>> hist[20], hist[200] = 100, 300
    >>> otsu_threshold(hist)
    20
    """
    h = np.ascontiguousarray(hist, np.int64)
    return int(_otsu_kernel(h)) if h.sum() > 0 else 0


@njit(cache=True, nogil=True)
def _otsu_kernel(hist):
    """:func:`otsu_threshold` of ``hist`` (256,) int64: OpenCV's float64 arithmetic in its order, classes with a
    share below float32's epsilon skipped, the first maximum kept."""
    scale = 1.0 / hist.sum()
    mu = 0.0
    for i in range(256):
        mu += i * np.float64(hist[i])
    mu *= scale
    mu1 = 0.0
    q1 = 0.0
    max_sigma = 0.0
    best = 0
    eps = 1.1920928955078125e-07  # FLT_EPSILON
    for i in range(256):
        p_i = hist[i] * scale
        mu1 *= q1
        q1 += p_i
        q2 = 1.0 - q1
        if min(q1, q2) < eps or max(q1, q2) > 1.0 - eps:
            continue
        mu1 = (mu1 + i * p_i) / q1
        mu2 = (mu - q1 * mu1) / q2
        sigma = q1 * q2 * (mu1 - mu2) * (mu1 - mu2)
        if sigma > max_sigma:
            max_sigma = sigma
            best = i
    return best


def segmentation_scales(height: int, width: int) -> tuple[int, ...]:
    """Image scales (1 = full, s = shrunk s times) to segment the whole image at, in order.

    The working scale ``min(H, W) // SHRINK_MIN_SIDE`` first (when at least 2; pixel-area averaging; ~ s^2 fewer
    pixels to filter), then halving it (rounded up) down to 2 (a grid of small dots in a large image); full resolution
    only for an image too small to shrink. At scale 2 a dot 6 px across is 3 px and still a candidate: a board
    recognised with dots smaller than :data:`SHRUNK_MIN_RADIUS` at its scale is segmented again at the coarsest scale
    where they are not, in its own window (:mod:`circcal.detector.locate.search`), never the whole frame (a 48 MP
    frame of noise alone took minutes). The edges are always measured at full resolution, starting from these
    contours: only the starting ellipses differ between scales (on the fixtures the centres move by ~1e-4 px, up to
    ~1e-2 px on strongly blurred images, where the two-pass refinement still depends slightly on its start, with the
    same accuracy against the truth). Setting ``SHRINK_MIN_SIDE`` above any image size restores full-resolution
    segmentation everywhere.

    Parameters
    ----------
    height, width : int
        The image's size, px.

    Returns
    -------
    tuple of int
        The scales, coarsest first.

    Examples
    --------
    >>> segmentation_scales(1080, 1920), segmentation_scales(480, 640), segmentation_scales(3000, 4000)
    ((3, 2), (1,), (8, 4, 2))
    """
    s = min(height, width) // SHRINK_MIN_SIDE
    if s < 2:
        return (1,)
    out = [s]
    while s > 2:
        s = (s + 1) // 2
        out.append(s)
    return tuple(out)


def shrink(gray: np.ndarray, scale: int) -> np.ndarray:
    """Averages of the s x s pixel blocks of ``gray``, ``s = scale``.

    ``cv2.resize(..., INTER_AREA)``'s values; for uint8 and ``s >= 3`` computed by :func:`_block_means_u8` (the same
    values, ~3x faster: OpenCV has a fast path for 2x only, its general area loop took ~1.5 ms of a 1080p frame).

    Parameters
    ----------
    gray : numpy.ndarray
        (H, W) image.
    scale : int
        The block side s, px.

    Returns
    -------
    numpy.ndarray
        (H // s, W // s) block means; uint8, uint16 and float32 kept, other dtypes via float32 (as
        :func:`~circcal.detector.image.as_gray` converts float64 colour).

    Examples
    --------
    >>> shrink(np.arange(16, dtype=np.uint8).reshape(4, 4), 2).tolist()
    [[3, 5], [11, 13]]
    """
    H, W = gray.shape
    g = gray[: H // scale * scale, : W // scale * scale]
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
