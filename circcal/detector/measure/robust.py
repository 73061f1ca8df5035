"""Robust statistics the detector shares: row medians of masked data and the MAD -> sigma factor."""

from __future__ import annotations

import numpy as np

from circcal.detector.kernels.jit import njit

__all__ = ["MAD_TO_SIGMA", "mad_inliers", "median", "row_medians"]

MAD_TO_SIGMA = 1.4826
"""Standard deviation of a normal distribution per unit of its median absolute deviation (1 / Phi^-1(3/4))."""
_XORSHIFT_MASK = (1 << 60) - 1
"""The pivot draws' state stays below 2^60 (non-negative in int64)."""
BAND_SELECT_FROM = 256
"""Medians of at least this many values select within a sampled band (:func:`_band_median_of`: 13-22 % faster on
300 to 1,400 values, measured); on fewer, the sample and the extra pass cost about what they save."""
BAND_SAMPLE = 31
"""Values sampled (evenly spread) to bound the band ..."""
BAND_HALF_WIDTH = 6
"""... which reaches this many sample steps either side of the median's (the median's rank in a sample of 31 varies
by ~2.8 steps: 6 misses it with a probability of ~3 %, and then all values are searched; wider bands and larger
samples measured slower)."""


def row_medians(values: np.ndarray) -> np.ndarray:
    """The median of each row of a 2-D array, NaN entries left out: ``np.nanmedian(values, axis=1)``.

    Per row, the values left in are selected in place (compiled quickselect, :func:`_row_medians_kernel`): equal to
    numpy's (tested), without its masked-array path (~1 ms a call) or a sort of every row, and no all-NaN warning is
    raised (a warning filter would be process-wide state, and images run in threads).

    Parameters
    ----------
    values : numpy.ndarray
        (D, P), any real dtype (read as float64; further axes are flattened into P); NaN marks the entries left
        out.

    Returns
    -------
    numpy.ndarray
        (D,) float64: each row's median (the mean of the two middle values for an even count); NaN for a row
        without values.

    Examples
    --------
    >>> row_medians(np.array([[3.0, 1.0, 2.0], [4.0, np.nan, 1.0], [np.nan, np.nan, np.nan]]))
    array([2. , 2.5, nan])
    """
    values = np.ascontiguousarray(np.asarray(values, np.float64).reshape(len(values), -1))
    out = np.full(len(values), np.nan)
    if len(values) and values.shape[1]:
        _row_medians_kernel(values, out)
    return out


def median(values: np.ndarray) -> float:
    """The median of all entries of an array, NaN entries left out (as :func:`row_medians` does).

    The compiled selection, ~20x faster than ``np.median`` on the few hundred values of a detection (numpy's generic
    path costs ~40-190 us a call).

    Parameters
    ----------
    values : numpy.ndarray
        Any shape, any real dtype (read as float64); all entries are used.

    Returns
    -------
    float
        ``np.median`` of the non-NaN entries; NaN when there are none.

    Examples
    --------
    >>> median(np.array([[5.0, 1.0], [np.nan, 3.0]]))
    3.0
    """
    return float(row_medians(np.asarray(values, np.float64).reshape(1, -1))[0])


def mad_inliers(values: np.ndarray, mask: np.ndarray, floor: np.ndarray, sigmas: float) -> np.ndarray:
    """The entries of each row within a robust (MAD-based) band around 0, at least ``floor`` wide.

    Entry (d, i) is kept when ``|values[d, i]| <= max(sigmas * MAD_TO_SIGMA * MAD_d, floor[d, i])``, where ``MAD_d``
    is row d's median absolute deviation from its median, both over the entries where ``mask`` is true (NaN values
    left out). The values of::

        med = row_medians(np.where(mask, values, np.nan))
        sdev = MAD_TO_SIGMA * row_medians(np.where(mask, np.abs(values - med[:, None]), np.nan))
        np.abs(values) <= np.maximum((sigmas * sdev)[:, None], floor)

    in one compiled pass per row (:func:`_mad_inliers_kernel`).

    Parameters
    ----------
    values : numpy.ndarray
        (D, M) float64 (or castable), e.g. residuals in px.
    mask : numpy.ndarray
        (D, M) bool: the entries the median and the MAD are taken over.
    floor : numpy.ndarray
        Broadcastable to (D, M), in the unit of ``values``: the least half-width of the band.
    sigmas : float
        The band's half-width in robust standard deviations.

    Returns
    -------
    numpy.ndarray
        (D, M) bool. A row without masked (non-NaN) entries keeps nothing; entries outside ``mask`` are tested too
        (the caller masks them); NaN values or floors are never kept.

    Examples
    --------
    >>> v = np.array([[0.1, -0.2, 0.15, 3.0]])
    >>> mad_inliers(v, np.ones(v.shape, bool), np.zeros(v.shape), 3.0)
    array([[ True,  True,  True, False]])
    """
    v = np.ascontiguousarray(values, np.float64)
    out = np.zeros(v.shape, bool)
    if v.size:
        _mad_inliers_kernel(
            v,
            np.ascontiguousarray(mask, np.bool_),
            np.ascontiguousarray(np.broadcast_to(floor, v.shape), np.float64),
            float(sigmas),
            MAD_TO_SIGMA,
            out,
        )
    return out


@njit(cache=True, nogil=True)
def _select_inplace(a, n, k):
    """The ``k``-th smallest (0-based) of ``a[:n]`` (no NaN), reordering ``a[:n]`` so that none before index k is
    larger and none after it smaller. Quickselect with branch-free three-way partitions (values below the pivot,
    equal to it, above it: ~3x faster than a Hoare partition on the noisy ring residuals of a dot, whose
    comparisons the CPU cannot predict, and linear on ties), the pivot the median of three positions drawn by a
    xorshift (so sorted input is no worse than random). The value is the order statistic, whatever the pivots."""
    lo, hi = 0, n - 1
    r = 88172645463325252
    while hi > lo:
        w = hi - lo + 1
        r ^= (r << 13) & _XORSHIFT_MASK
        r ^= r >> 7
        r ^= (r << 17) & _XORSHIFT_MASK
        x, y, z = a[lo + r % w], a[lo + (r >> 20) % w], a[lo + (r >> 40) % w]
        if x > y:
            x, y = y, x
        if y > z:
            y = z
        pivot = x if x > y else y
        s = lo
        for i in range(lo, hi + 1):  # below the pivot to the front
            v = a[i]
            a[i] = a[s]
            a[s] = v
            s += v < pivot
        if k < s:
            hi = s - 1
            continue
        e = s
        for i in range(s, hi + 1):  # then those equal to it
            v = a[i]
            a[i] = a[e]
            a[e] = v
            e += v == pivot
        if k < e:
            return pivot
        lo = e
    return a[k]


@njit(cache=True, nogil=True)
def _median_of(a, n):
    """Median of ``a[:n]`` (``n >= 1``, no NaN; the mean of the two middle values for even n), reordering ``a[:n]``:
    the lower middle value by :func:`_select_inplace`, the upper one (even counts) the smallest value above it. From
    :data:`BAND_SELECT_FROM` values the selection runs on the band of values around the median that a sample of
    them bounds (:func:`_band_median_of`); the same order statistics either way."""
    k = (n - 1) // 2
    if n >= BAND_SELECT_FROM:
        return _band_median_of(a, n, k)
    m = _select_inplace(a, n, k)
    if n % 2 == 1:
        return m
    return 0.5 * (m + _min_of(a, k + 1, n))


@njit(cache=True, nogil=True)
def _min_of(a, lo, hi):
    """The smallest of ``a[lo:hi]`` (``lo < hi``)."""
    m = a[lo]
    for i in range(lo + 1, hi):
        if a[i] < m:
            m = a[i]
    return m


@njit(cache=True, nogil=True)
def _band_median_of(a, n, k):
    """:func:`_median_of` of ``a[:n]`` (``k = (n - 1) // 2``) for many values: :data:`BAND_SAMPLE` of them, evenly
    spread, sorted, bound a band ``[lo, hi]`` of ranks ~k +- :data:`BAND_HALF_WIDTH` sample steps; one branch-free
    pass moves the values in the band to the front and counts those below it, and where the k-th (and, for even n,
    the next) smallest lies in the band it is selected among the band alone (~40 % of the values; the quickselect
    over all the noisy ring residuals of a dot, whose comparisons the CPU cannot predict, had been ~40 % of the
    levels' pass), otherwise among all values, as :func:`_median_of` does. The order statistics are unique, so the value does not
    depend on the band."""
    samp = np.empty(BAND_SAMPLE)
    for j in range(BAND_SAMPLE):  # insertion sort of the sample
        v = a[((2 * j + 1) * n) // (2 * BAND_SAMPLE)]
        i = j
        while i > 0 and samp[i - 1] > v:
            samp[i] = samp[i - 1]
            i -= 1
        samp[i] = v
    j = (k * (BAND_SAMPLE - 1) + (n - 1) // 2) // (n - 1)
    lo = samp[j - BAND_HALF_WIDTH] if j >= BAND_HALF_WIDTH else -np.inf
    hi = samp[j + BAND_HALF_WIDTH] if j + BAND_HALF_WIDTH < BAND_SAMPLE else np.inf
    s = 0
    below = 0
    for i in range(n):
        v = a[i]
        below += v < lo
        a[i] = a[s]
        a[s] = v
        s += (v >= lo) & (v <= hi)
    even = n % 2 == 0
    if below <= k and k + even < below + s:  # the middle value(s) among the band a[:s]
        m = _select_inplace(a, s, k - below)
        return 0.5 * (m + _min_of(a, k - below + 1, s)) if even else m
    m = _select_inplace(a, n, k)
    return 0.5 * (m + _min_of(a, k + 1, n)) if even else m


@njit(cache=True, nogil=True)
def _gather(row, use, a):
    """Copies the non-NaN entries of ``row`` (P,) where ``use`` (P,) into ``a[:n]``; returns n."""
    n = 0
    for i in range(len(row)):
        v = row[i]
        if use[i] and not np.isnan(v):
            a[n] = v
            n += 1
    return n


@njit(cache=True, nogil=True)
def _row_medians_kernel(values, out):
    """``out[d]``: the median of the non-NaN entries of ``values[d]`` (left as NaN for a row without any), by
    :func:`_median_of` on a copy."""
    D, P = values.shape
    a = np.empty(P)
    every = np.ones(P, np.bool_)
    for d in range(D):
        n = _gather(values[d], every, a)
        if n:
            out[d] = _median_of(a, n)


@njit(cache=True, nogil=True)
def _mad_inliers_kernel(values, mask, floor, sigmas, mad_to_sigma, out):
    """Writes :func:`mad_inliers` into ``out`` (D, M) bool (zeros on entry)."""
    D, M = values.shape
    a = np.empty(M)
    for d in range(D):
        n = _gather(values[d], mask[d], a)
        if n == 0:
            continue
        med = _median_of(a, n)
        n2 = 0
        for i in range(M):
            v = values[d, i]
            if mask[d, i]:
                e = abs(v - med)
                if not np.isnan(e):
                    a[n2] = e
                    n2 += 1
        if n2 == 0:
            continue
        t = sigmas * (mad_to_sigma * _median_of(a, n2))
        for i in range(M):
            f = floor[d, i]
            if np.isnan(t) or np.isnan(f):
                continue
            out[d, i] = abs(values[d, i]) <= (t if t >= f else f)
