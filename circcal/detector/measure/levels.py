"""The grey levels of each dot: its dark level inside and the board's bright level around it, fitted as a plane (so
an illumination gradient does not move the half level the edges are measured at).

All dots at once, one compiled pass over each dot's pixels (:func:`_levels_kernel`; numba, cached on disk; the
medians of uint8 images from histograms, others by quickselect: the same values as sorting). Pixel convention:
OpenCV's (integer coordinates are pixel centres).
"""

from __future__ import annotations

import numpy as np

from circcal.detector.kernels.jit import njit
from circcal.detector.measure.ellipse import conic_params_batch
from circcal.detector.measure.robust import MAD_TO_SIGMA, _median_of

KERNEL_IMPORTS = ("circcal.detector.measure.robust",)
"""Kernel modules whose kernels this module's kernels call (:mod:`circcal.detector.kernels.jit`)."""

__all__ = ["EDGE_GAP_PX", "dot_levels_batch", "dot_levels_from_params"]

# (the compiled kernels read the constants of this module when they are compiled, and numba's cache sees only this
# file: values they need from elsewhere are passed as arguments)
EDGE_GAP_PX = 2.0
"""Pixels left out on either side of the boundary (the blurred edge's transition): the dark level comes from inside
the ellipse shrunk by this, the bright ring starts this far outside."""
RING_MIN_WIDTH_PX = 2.0
"""The bright ring is ``max(RING_MIN_WIDTH_PX, RING_WIDTH_PER_MINOR * b)`` px wide (b: minor semi-axis): wide enough
for a plane fit, narrow enough to stay between the dots."""
RING_WIDTH_PER_MINOR = 0.5
DARK_MIN_PIXELS = 3
"""The dark level is the median of the pixels inside; a dot with fewer inside takes the median of its this many
pixels nearest the centre."""
RING_MIN_PIXELS = 8
"""A ring with fewer pixels gives no bright level (the dot is not measured)."""
PLANE_MIN_PIXELS = 6
"""The plane is fitted to at least this many bright ring pixels (3 parameters, twice over), else no bright level."""
PLANE_OUTLIER_SIGMAS = 4.0
"""Ring pixels further than this many robust sigmas from the first plane are left out of the refit."""
SURE_MARGIN_PX = 2
"""Columns of a row this far inside the inner ellipse's real roots are taken as inside without testing each
(the compiled pass's shortcut; pixels nearer the roots are tested: the same pixels either way)."""
STRIDE_MIN_MINOR_PX = 8.0
"""A stride s > 1 (:func:`dot_levels_from_params`) applies to the dots whose minor semi-axis is at least this many px
times s / 2: their inside keeps >= ~30 and their ring >= ~80 of the pixels at every s-th row and column (smaller dots
use every pixel)."""
_HIST_BINS_U8 = 256


def dot_levels_batch(
    gray: np.ndarray, conics: np.ndarray, boxes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dark level inside each dot and the bright level around it as a plane, for all dots at once.

    Dark: the median inside the ellipse shrunk by :data:`EDGE_GAP_PX` (the :data:`DARK_MIN_PIXELS` pixels nearest the
    centre for tiny dots). Bright: a plane fitted (least squares, refitted once without > :data:`PLANE_OUTLIER_SIGMAS`
    robust-sigma residuals) to the ring :data:`EDGE_GAP_PX` .. ``EDGE_GAP_PX + max(2, b/2)`` px outside (b: minor
    semi-axis), keeping only pixels brighter than halfway between the dark level and the ring median (drops
    neighbouring dots).

    Parameters
    ----------
    gray : numpy.ndarray
        (H, W) grey image: uint8, uint16, float32 or float64 (other dtypes are read as float64).
    conics : numpy.ndarray
        (D, 3, 3) float64: the dots' ellipses as conic matrices, px.
    boxes : numpy.ndarray
        (D, 4) int: the regions of interest ``x0, y0, x1, y1`` px (exclusive ends) whose pixels are used.

    Returns
    -------
    dark : numpy.ndarray
        (D,) float64, in the image's grey units; NaN where not ``ok``.
    plane : numpy.ndarray
        (D, 3) float64: bright(x, y) = ``plane @ (x, y, 1)`` in image pixels; NaN where not ``ok``.
    ok : numpy.ndarray
        (D,) bool: false where the ring has too few pixels (:data:`RING_MIN_PIXELS`, :data:`PLANE_MIN_PIXELS` bright
        ones) or they are collinear, or the conic is not a real ellipse.
    """
    return dot_levels_from_params(gray, *conic_params_batch(np.asarray(conics, np.float64)), boxes)


def dot_levels_from_params(
    gray: np.ndarray,
    c: np.ndarray,
    axes: np.ndarray,
    ang: np.ndarray,
    okc: np.ndarray,
    boxes: np.ndarray,
    stride: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`dot_levels_batch` from the ellipses' parameters, optionally from a subsample of the pixels.

    The parameters are as :func:`~circcal.detector.measure.ellipse.conic_params_batch` gives them.

    Parameters
    ----------
    gray : numpy.ndarray
        (H, W) grey image: uint8, uint16, float32 or float64 (other dtypes are read as float64).
    c : numpy.ndarray
        (D, 2) float64: the ellipses' centres ``(x, y)``, px.
    axes : numpy.ndarray
        (D, 2) float64: their semi-axes ``(a, b)``, px.
    ang : numpy.ndarray
        (D,) float64: their angles, rad.
    okc : numpy.ndarray
        (D,) bool: which ellipses are valid (the others are not measured).
    boxes : numpy.ndarray
        (D, 4) int: the regions of interest ``x0, y0, x1, y1`` px (exclusive ends) whose pixels are used.
    stride : int
        s > 1: the dots of minor semi-axis >= :data:`STRIDE_MIN_MINOR_PX` s / 2 px use only the pixels of every s-th
        row and column of their box (from its corner): ~1/s^2 of the work, levels ~s times noisier (for
        measurements that only steer a later one).

    Returns
    -------
    dark : numpy.ndarray
        (D,) float64, in the image's grey units; NaN where not ``ok``.
    plane : numpy.ndarray
        (D, 3) float64: bright(x, y) = ``plane @ (x, y, 1)`` in image pixels; NaN where not ``ok``.
    ok : numpy.ndarray
        (D,) bool: false where ``okc`` is, or the ring has too few pixels (:data:`RING_MIN_PIXELS`,
        :data:`PLANE_MIN_PIXELS` bright ones) or they are collinear.
    """
    D = len(okc)
    dark = np.full(D, np.nan)
    plane = np.full((D, 3), np.nan)
    ok = np.zeros(D, bool)
    if D == 0:
        return dark, plane, ok
    gray = np.ascontiguousarray(gray)
    if gray.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        gray = gray.astype(np.float64)
    # (numpy's cos and sin, whose SIMD loops may round differently from the C library's the kernels call)
    _levels_kernel(
        gray,
        np.ascontiguousarray(c, np.float64),
        np.ascontiguousarray(axes, np.float64),
        np.cos(ang),
        np.sin(ang),
        np.ascontiguousarray(boxes, np.int64).reshape(D, 4),
        int(stride),
        np.ascontiguousarray(okc, np.bool_),
        _HIST_BINS_U8 if gray.dtype == np.uint8 else 0,
        MAD_TO_SIGMA,
        dark,
        plane,
        ok,
    )
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


@njit(cache=True, nogil=True, inline="always")
def _row_span(dy, cx, qa, qb, qc, t_hi, x0, x1):
    """``(xa, xb)``: the columns of the row ``dy`` px from the centre ``cx`` inside the outer ellipse
    ``qa dx^2 + qb dx dy + qc dy^2 < t_hi``, with a pixel of slack either side (a pixel beyond it is neither inside
    nor in the ring; the per-pixel test decides), clipped to ``[x0, x1)``; ``xa >= xb`` for a row that misses it."""
    disc = (qb * dy) ** 2 - 4.0 * qa * (qc * dy * dy - t_hi)
    if disc < 0:
        return x0, x0
    half = np.sqrt(disc) / (2.0 * qa)
    mid = cx - qb * dy / (2.0 * qa)
    return max(x0, int(np.floor(mid - half)) - 1), min(x1, int(np.ceil(mid + half)) + 2)


@njit(cache=True, nogil=True, inline="always")
def _on_grid(x, x0, st):
    """The first column at or after ``x`` on the grid ``x0 + k st`` (``x`` itself for ``st`` 1)."""
    return x0 + ((x - x0 + st - 1) // st) * st


@njit(cache=True, nogil=True)
def _nearest_median(gray, cx, cy, qa, qb, qc, t_hi, x0, y0, x1, y1, near_r, near_v):
    """Median grey level of the :data:`DARK_MIN_PIXELS` pixels of the box ``x0, y0, x1, y1`` nearest the centre
    ``cx, cy`` in ``rho^2 = qa dx^2 + qb dx dy + qc dy^2`` (among those of the rows' spans inside ``rho^2 < t_hi``,
    as :func:`_levels_kernel` visits them; ties: the first visited): the dark level of a dot too small to have an
    inside. NaN when there is no such pixel. ``near_r``, ``near_v``: scratch of that length."""
    n_near = 0
    for y in range(y0, y1):
        dy = y - cy
        xa, xb = _row_span(dy, cx, qa, qb, qc, t_hi, x0, x1)
        for x in range(xa, xb):
            dx = x - cx
            rho2 = (qb * dx) * dy + (qa * dx) * dx + (qc * dy) * dy
            if n_near < DARK_MIN_PIXELS or rho2 < near_r[n_near - 1]:  # kept sorted by rho^2
                i = min(n_near, DARK_MIN_PIXELS - 1)
                while i > 0 and near_r[i - 1] > rho2:
                    near_r[i], near_v[i] = near_r[i - 1], near_v[i - 1]
                    i -= 1
                near_r[i], near_v[i] = rho2, gray[y, x]
                n_near = min(n_near + 1, DARK_MIN_PIXELS)
    return np.median(near_v[:n_near]) if n_near else np.nan


@njit(cache=True, nogil=True)
def _levels_kernel(gray, c, axes, cos_a, sin_a, boxes, stride, okc, nbins, mad_to_sigma, dark, plane, ok):
    """The per-pixel work of :func:`dot_levels_batch`, one dot at a time; writes ``dark``, ``plane``, ``ok``.

    ``c`` (D, 2) centres, ``axes`` (D, 2) semi-axes, ``cos_a``, ``sin_a`` (D,) of the angles, ``boxes`` (D, 4) the
    pixels to visit (clipped to the image here); per dot the ellipse as ``rho^2 = q0 dx^2 + q1 dx dy + q2 dy^2``
    (1 on the boundary) and the ``rho^2`` bounds of the inside and of the ring (the numpy expressions of
    :func:`dot_levels_from_params` before, in their order); ``stride`` s: the pixels of every s-th row and column
    from the box's corner for the dots of minor semi-axis >= :data:`STRIDE_MIN_MINOR_PX` s / 2; ``nbins`` histogram
    bins for the medians (0: by selection), ``mad_to_sigma`` the robust scale factor."""
    D = len(c)
    H, W = gray.shape
    q = np.empty((D, 3))
    t = np.empty((D, 3))
    st_ = np.empty(D, np.int64)
    bx = np.empty((D, 4), np.int64)
    cc = np.empty((D, 2))
    for d in range(D):
        a, b = (axes[d, 0], axes[d, 1]) if okc[d] else (1.0, 1.0)
        ca, sa = cos_a[d], sin_a[d]
        ia2, ib2 = 1.0 / (a * a), 1.0 / (b * b)
        q[d, 0] = ca * ca * ia2 + sa * sa * ib2
        q[d, 1] = 2.0 * ca * sa * (ia2 - ib2)
        q[d, 2] = sa * sa * ia2 + ca * ca * ib2
        t_in = 1.0 - EDGE_GAP_PX / b
        t[d, 0] = t_in * t_in if t_in > 0 else -1.0
        t[d, 1] = (1.0 + EDGE_GAP_PX / b) ** 2
        t[d, 2] = (1.0 + (EDGE_GAP_PX + max(RING_MIN_WIDTH_PX, RING_WIDTH_PER_MINOR * b)) / b) ** 2
        st_[d] = stride if b >= STRIDE_MIN_MINOR_PX * 0.5 * stride else 1
        for k, top in ((0, W), (1, H), (2, W), (3, H)):  # (the pass reads only inside the image)
            bx[d, k] = min(max(boxes[d, k], 0), top)
        cc[d, 0], cc[d, 1] = (c[d, 0], c[d, 1]) if okc[d] else (0.0, 0.0)
    npx = 1
    for d in range(D):
        npx = max(npx, max(bx[d, 2] - bx[d, 0], 0) * max(bx[d, 3] - bx[d, 1], 0))
    inner = np.empty(npx)
    rx = np.empty(npx)
    ry = np.empty(npx)
    rv = np.empty(npx)
    keep = np.zeros(npx, np.bool_)
    okr = np.zeros(npx, np.bool_)
    res = np.empty(npx)
    hist = np.zeros(nbins, np.int64)  # empty: values are not uint8, medians by selection
    hist_ring = np.zeros(nbins, np.int64)
    counted = nbins > 0
    near_r = np.empty(DARK_MIN_PIXELS)
    near_v = np.empty(DARK_MIN_PIXELS)
    for d in range(D):
        if not okc[d]:
            continue
        x0, y0, x1, y1 = bx[d, 0], bx[d, 1], bx[d, 2], bx[d, 3]
        cx, cy = cc[d, 0], cc[d, 1]
        qa, qb, qc = q[d, 0], q[d, 1], q[d, 2]
        t_in, t_lo, t_hi = t[d, 0], t[d, 1], t[d, 2]
        n_in = 0
        n_ring = 0
        if counted:
            hist[:] = 0
            hist_ring[:] = 0
        st = st_[d]
        for y in range(y0, y1, st):
            dy = y - cy
            xa, xb = _row_span(dy, cx, qa, qb, qc, t_hi, x0, x1)
            xa = _on_grid(xa, x0, st)
            if xa >= xb:
                continue
            mid = cx - qb * dy / (2.0 * qa)
            # the columns certainly inside (rho^2 < t_in): SURE_MARGIN_PX in from the row's real roots, where rho^2
            # is below t_in by ~4 qa (h - 1) px, far beyond rounding; they need no test (the others are tested)
            ia = ib = xb
            disc_in = (qb * dy) ** 2 - 4.0 * qa * (qc * dy * dy - t_in)
            if t_in > 0 and disc_in > 0:
                h_in = np.sqrt(disc_in) / (2.0 * qa)
                if h_in > SURE_MARGIN_PX + 1.0:
                    ia = max(xa, int(np.ceil(mid - h_in)) + SURE_MARGIN_PX)
                    ib = max(ia, min(xb, int(np.floor(mid + h_in)) - SURE_MARGIN_PX + 1))
            ia = _on_grid(ia, x0, st)
            x = xa
            while x < xb:
                if x == ia:
                    m = len(range(ia, ib, st))
                    if counted:  # (uint8: the values counted as they are met, the histogram gives the median)
                        if st == 1:  # (the unit-step loop compiles tighter)
                            for xx in range(ia, ib):
                                hist[int(gray[y, xx])] += 1
                        else:
                            for xx in range(ia, ib, st):
                                hist[int(gray[y, xx])] += 1
                    else:
                        for i in range(m):
                            inner[n_in + i] = gray[y, ia + i * st]
                    n_in += m
                    x = ia + m * st
                    if x >= xb:
                        break
                dx = x - cx
                rho2 = (qb * dx) * dy + (qa * dx) * dx + (qc * dy) * dy
                v = gray[y, x]
                if rho2 < t_in:
                    if counted:
                        hist[int(v)] += 1
                    else:
                        inner[n_in] = v
                    n_in += 1
                elif t_lo < rho2 < t_hi:
                    rx[n_ring] = dx
                    ry[n_ring] = dy
                    rv[n_ring] = v
                    if counted:
                        hist_ring[int(v)] += 1
                    n_ring += 1
                x += st
        if n_in >= DARK_MIN_PIXELS:
            dk = _median_hist(hist, n_in) if counted else _median_of(inner, n_in)  # (inner: reordered)
        else:
            dk = _nearest_median(gray, cx, cy, qa, qb, qc, t_hi, x0, y0, x1, y1, near_r, near_v)
        if n_ring < RING_MIN_PIXELS:
            continue
        if counted:
            ring_med = _median_hist(hist_ring, n_ring)
        else:  # (rv stays in step with rx, ry: a copy is reordered)
            res[:n_ring] = rv[:n_ring]
            ring_med = _median_of(res, n_ring)
        mid = 0.5 * (dk + ring_med)
        n_keep = 0
        for i in range(n_ring):
            keep[i] = rv[i] > mid
            n_keep += keep[i]
        if n_keep < PLANE_MIN_PIXELS:
            continue
        p0, p1, p2 = _plane_fit(rx, ry, rv, keep, n_ring)
        m = 0
        for i in range(n_ring):
            if keep[i]:
                res[i] = abs(rv[i] - (p0 * rx[i] + p1 * ry[i] + p2))
                inner[m] = res[i]  # (the inner values are used up: the buffer holds the kept residuals)
                m += 1
        s = mad_to_sigma * _median_of(inner, m) + 1e-12  # (+ a tiny floor: an exact plane has no residuals)
        n_ok = 0
        for i in range(n_ring):
            okr[i] = keep[i] and res[i] < PLANE_OUTLIER_SIGMAS * s
            n_ok += okr[i]
        if PLANE_MIN_PIXELS <= n_ok < n_keep:
            p0, p1, p2 = _plane_fit(rx, ry, rv, okr, n_ring)
        if not (np.isfinite(p0) and np.isfinite(p1) and np.isfinite(p2)):  # collinear ring pixels
            continue
        dark[d] = dk
        plane[d, 0], plane[d, 1], plane[d, 2] = p0, p1, p2 - p0 * cx - p1 * cy
        ok[d] = True
