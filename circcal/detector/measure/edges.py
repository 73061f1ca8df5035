"""Sub-pixel edge points of dark dots on a bright board (:func:`subpixel_edge_points_batch`).

Along the normals of each dot's current ellipse the image (lightly Gaussian-smoothed, cubic-spline interpolated:
:class:`~circcal.detector.measure.smoothing.SmoothedImage`) is sampled, and the point where the profile crosses the local
half level between the dot's dark level and the board's bright level (fitted as a plane around the dot,
:mod:`circcal.detector.measure.levels`, so an illumination gradient does not move the edges) is interpolated. For any
symmetric blur of a straight edge this crossing is the edge itself (and it is where the gradient magnitude along the
normal peaks); with a smoothing scale matched to the edge width it is the efficient (Cramer-Rao) estimator of the
edge position, which the gradient-peak location is not. On a curved edge the half-level contour lies slightly inside
the edge: each point is moved out by the shift of :mod:`circcal.detector.measure.curvature`.

All dots are measured at once; the per-pixel work is compiled (numba, cached on disk): the profile geometry
(:func:`_profiles_kernel`) and the nearest crossing of each profile (:func:`_crossings_kernel`: intervals examined
nearest the current boundary first, each spline sample (:func:`_spline_at`) computed once when first needed; the
nearest crossing is the same as with the whole profile sampled), and the points with their curvature shift
(:func:`_edge_points_kernel`). The compiled functions call each other and the kernels of the modules in
:data:`KERNEL_IMPORTS` (robust's selection, curvature's per-point shift, ellipse's parameters).

Pixel convention: OpenCV's (integer coordinates are pixel centres). Arrays: ``(M, 2)`` points as ``(x, y)``.
"""

from __future__ import annotations

import functools

import numpy as np

from circcal.detector.kernels.jit import njit
from circcal.detector.measure.curvature import U_TABLE, _shift_table, shift_at
from circcal.detector.measure.ellipse import _conic_params_kernel, perimeter
from circcal.detector.measure.levels import dot_levels_from_params
from circcal.detector.measure.robust import _median_of
from circcal.detector.measure.smoothing import SmoothedImage

KERNEL_IMPORTS = (
    "circcal.detector.measure.robust",
    "circcal.detector.measure.curvature",
    "circcal.detector.measure.ellipse",
)
"""Kernel modules whose kernels this module's kernels call (:mod:`circcal.detector.kernels.jit`)."""

__all__ = ["PROFILE_SPACING_PX", "PROFILE_STEP_PX", "subpixel_edge_points_batch"]

PROFILE_SPACING_PX = 1.0
"""One profile per this many px of the ellipse's perimeter (about one per boundary pixel: neighbouring profiles
then see mostly different pixels)."""
MIN_PROFILES = 24
"""... and at least this many profiles per dot, however small."""
PROFILE_STEP_PX = 0.2
"""Samples along a profile are this far apart (px); the crossing is interpolated linearly between two of them."""
PROFILE_HALF_PER_MINOR = 0.8
"""A profile runs from ``-h`` to ``+h`` px across the current ellipse, ``h = PROFILE_HALF_PER_MINOR * b`` (b: minor
semi-axis) clipped to [:data:`PROFILE_HALF_MIN_PX`, :data:`PROFILE_HALF_MAX_PX`]: far enough to hold the edge of a
rough starting ellipse, short of a small dot's centre and of the neighbouring dots."""
PROFILE_HALF_MIN_PX = 1.0
PROFILE_HALF_MAX_PX = 3.0
ROI_PAD_SIGMAS = 3.0
"""A dot's region of interest extends beyond its ellipse by the profile half length, this many smoothing sigmas
(the smoothing's reach) and :data:`ROI_PAD_PX` (room for the bright ring of the levels)."""
ROI_PAD_PX = 4.0
MIN_ROI_SIDE_PX = 4
"""A dot whose region of interest (clipped to the image) is narrower than this is not measured."""
PIXEL_BOX_VARIANCE = 1.0 / 12.0
"""Variance (px^2) of a pixel's unit box: the blur that area sampling adds to every edge, whatever the optics."""


def subpixel_edge_points_batch(
    src: SmoothedImage,
    conics: np.ndarray,
    with_slack: bool = False,
    spacing_px: float = PROFILE_SPACING_PX,
    level_stride: int = 1,
    half_max_px: float = PROFILE_HALF_MAX_PX,
) -> tuple[np.ndarray, ...]:
    """Sub-pixel boundary points of the dark dots near the given ellipses.

    Profiles along the ellipse normals, one per ``spacing_px`` px of perimeter (at least :data:`MIN_PROFILES`),
    sampled every :data:`PROFILE_STEP_PX` px; the edge point of a profile is its up-crossing of the dot's half level
    nearest to the current ellipse (see the module docstring), moved outwards by the exact shift of the half-level
    contour of a blurred disk with the ellipse's local radius of curvature (the level set of a blurred convex shape
    lies inside it by ~ sigma_t^2 / (2 rho); sigma_t measured from the edge slope, :func:`_edge_blur`). Each dot keeps
    its own region of interest (the pixels its levels come from and the box its profiles must stay inside). Each
    profile's intervals are examined nearest to the current boundary first (:func:`_crossings_kernel`), sampling the
    image only where needed: the first up-crossing met is the nearest one of the whole profile, found from a few
    samples.

    Parameters
    ----------
    src : SmoothedImage
        The image and its smoothing scale ``sigma`` (px).
    conics : numpy.ndarray
        (D, 3, 3) float64: the dots' current ellipses as conic matrices, px.
    with_slack : bool
        Also return ``slack`` (below).
    spacing_px : float
        px of perimeter per profile.
    level_stride : int
        The dots' levels from every this many rows and columns of their pixels
        (:func:`~circcal.detector.measure.levels.dot_levels_from_params`; for a pass that only steers the next).

    Returns
    -------
    points : numpy.ndarray
        (D, Nmax, 2) float64 px ``(x, y)``: the boundary points of dot ``d`` are ``points[d][mask[d]]``.
    mask : numpy.ndarray
        (D, Nmax) bool; profiles without a clear edge are left out (there may be few: the caller decides).
    errors : list of (str or None)
        (D,): ``None``, or why dot ``d`` gave no points at all.
    slack : numpy.ndarray
        Only with ``with_slack``: (D, Nmax) float64 px, the curvature shift left uncorrected at each point where the
        osculating-circle model fades out (:func:`~circcal.detector.measure.curvature.shift_at`; 0 elsewhere): how
        far that point may lie off the true edge without being an outlier.
    """
    conics = np.ascontiguousarray(conics, np.float64)
    D = len(conics)
    H, W = src.shape
    c, ab, ang, okc, hw, boxes, live, n = _pass_geometry(
        conics, float(src.sigma), H, W, float(spacing_px), float(half_max_px)
    )
    errors: list[str | None] = [None if k else "conic is not a real ellipse" for k in okc.tolist()]
    N = int(n.max()) if D else 0
    if N == 0:
        empty = (np.zeros((D, 0, 2)), np.zeros((D, 0), bool), errors)
        return (*empty, np.zeros((D, 0))) if with_slack else empty
    a_, b_ = np.ascontiguousarray(ab[:, 0]), np.ascontiguousarray(ab[:, 1])
    S, klen, rank = _offset_table(hw, PROFILE_STEP_PX)
    # base points and outward normals, profiles entirely inside the ROI, the extent of those to be sampled
    base, nrm, cos_t, sin_t, inside, ext = _profiles_kernel(
        c, a_, b_, ang, conics, n, N, S[:, 0], S[np.arange(D), klen - 1], boxes
    )
    crop = src.crops_for(ext)
    dark, plane, okl = dot_levels_from_params(src.gray, c, ab, ang, okc, boxes, level_stride)
    bright_c = plane[:, 0] * c[:, 0] + plane[:, 1] * c[:, 1] + plane[:, 2]
    with np.errstate(invalid="ignore"):
        okl &= live & (bright_c > dark)
    ratio = np.where(okl, dark / np.where(okl, bright_c, 1.0), 0.0)
    halfk = 0.5 * (1.0 + ratio)
    todo = okl[:, None] & inside
    atlas, rows, org = src.coefficient_atlas(crop)
    off = np.zeros((D, N))
    at = np.zeros((D, N, 2))
    rise = np.zeros((D, N))
    found = np.zeros((D, N), bool)
    _crossings_kernel(atlas, rows, org, base, nrm, S, klen - 1, rank, todo, plane, halfk, off, at, rise, found)
    ok = found & todo
    sigma_t = _edge_blur(at, rise, plane, ratio, ok, src.sigma)
    pts = np.empty((D, N, 2))
    slack = np.empty((D, N))
    _edge_points_kernel(base, nrm, off, ok, a_, b_, cos_t, sin_t, sigma_t, U_TABLE, _shift_table(), pts, slack)
    if with_slack:
        return pts, ok, errors, slack
    return pts, ok, errors


@njit(cache=True, nogil=True)
def _edge_points_kernel(base, nrm, off, ok, a, b, cos_t, sin_t, sigma_t, u_table, table, pts, slack):
    """The edge points ``pts`` (D, N, 2): ``base + (off + shift) nrm`` where ``ok``, ``base`` elsewhere, with the
    curvature shift of each point (:func:`~circcal.detector.measure.curvature.shift_at`), and ``slack`` (D, N) its
    unmodelled part where ``ok`` (0 elsewhere): numpy's expressions in numpy's order."""
    D, N = ok.shape
    for d in range(D):
        for j in range(N):
            o = 0.0
            sl = 0.0
            if ok[d, j]:
                sh, rest = shift_at(a[d], b[d], cos_t[d, j], sin_t[d, j], sigma_t[d], u_table, table)
                o = off[d, j] + sh
                sl = rest
            pts[d, j, 0] = base[d, j, 0] + o * nrm[d, j, 0]
            pts[d, j, 1] = base[d, j, 1] + o * nrm[d, j, 1]
            slack[d, j] = sl


def _edge_blur(
    at: np.ndarray, rise: np.ndarray, plane: np.ndarray, ratio: np.ndarray, ok: np.ndarray, sigma: float
) -> np.ndarray:
    """(D,) blur scale sigma_t (px) of each dot's edge, from the slope of its profiles at their crossings.

    A Gaussian-blurred step of height A has slope A / (sqrt(2 pi) sigma_t) at its half level: per profile ``A`` is
    the bright level at ``at`` (D, N, 2) (the sample before the crossing; ``plane`` (D, 3)) times ``1 - ratio``
    ((D,) dark / bright), the slope ``rise`` (D, N) (the difference of the samples around the crossing) over
    :data:`PROFILE_STEP_PX`; ``ok`` (D, N) the profiles with a crossing. Per dot the median, never below what the pixel
    box and the smoothing ``sigma`` alone give (and that where no profile gives a value)."""
    out = np.empty(len(plane))
    _edge_blur_kernel(
        np.ascontiguousarray(at, np.float64),
        np.ascontiguousarray(rise, np.float64),
        np.ascontiguousarray(plane, np.float64),
        np.ascontiguousarray(ratio, np.float64),
        np.ascontiguousarray(ok, np.bool_),
        float(np.sqrt(sigma * sigma + PIXEL_BOX_VARIANCE)),
        out,
    )
    return out


@njit(cache=True, nogil=True)
def _edge_blur_kernel(at, rise, plane, ratio, ok, nominal, out):
    """Writes :func:`_edge_blur` into ``out`` (D,): per dot the median of ``sigma_t = A / (sqrt(2 pi) slope)`` over
    its profiles where ``ok`` and the value is finite and positive (``A = (plane . (at, 1)) (1 - ratio)``, ``slope =
    rise / PROFILE_STEP_PX``, numpy's expressions in numpy's order), at least ``nominal``; ``nominal`` without any."""
    D, N = rise.shape
    buf = np.empty(N)
    root = np.sqrt(2.0 * np.pi)
    for d in range(D):
        p0, p1, p2, w = plane[d, 0], plane[d, 1], plane[d, 2], 1.0 - ratio[d]
        n = 0
        for i in range(N):
            if not ok[d, i]:
                continue
            den = root * (rise[d, i] / PROFILE_STEP_PX)
            if den == 0.0:  # (numpy's division gives +-inf or NaN there: never a value)
                continue
            st = ((at[d, i, 0] * p0 + at[d, i, 1] * p1) + p2) * w / den
            if np.isfinite(st) and st > 0:
                buf[n] = st
                n += 1
        out[d] = max(nominal, _median_of(buf, n)) if n else nominal


@njit(cache=True, nogil=True)
def _pass_geometry(conics, sigma, H, W, spacing_px, half_max_px):
    """What a measuring pass needs of the ellipses ``conics`` (D, 3, 3) before it samples the image (H, W) smoothed
    by ``sigma`` px: ``(c (D, 2), ab (D, 2), ang (D,), okc (D,), hw (D,), boxes (D, 4), live (D,), n (D,))``.

    The ellipses' centres, semi-axes (a, b) and angles (:func:`~circcal.detector.measure.ellipse.conic_params_batch`'s
    values; a conic that is no real ellipse: ``okc`` false, centre 0, axes 1, angle 0); the profile half length
    ``hw = clip(PROFILE_HALF_PER_MINOR b, PROFILE_HALF_MIN_PX, PROFILE_HALF_MAX_PX)`` and each dot's region of
    interest ``x0, y0, x1, y1`` int (exclusive ends, clipped to the image): square, the major semi-axis both ways
    (any orientation fits) plus ``hw``, :data:`ROI_PAD_SIGMAS` smoothing sigmas and :data:`ROI_PAD_PX`; ``live``:
    a real ellipse whose region is at least :data:`MIN_ROI_SIDE_PX` wide and high; ``n``: its profiles, one per
    ``spacing_px`` of perimeter (Ramanujan's approximation), at least :data:`MIN_PROFILES` (0 where not ``live``).
    The numpy expressions it replaced, in their order."""
    D = len(conics)
    c = np.empty((D, 2))
    ab = np.empty((D, 2))
    ang = np.empty(D)
    okc = np.empty(D, np.bool_)
    _conic_params_kernel(conics, c, ab, ang, okc)
    hw = np.empty(D)
    boxes = np.empty((D, 4), np.int64)
    live = np.empty(D, np.bool_)
    n = np.empty(D, np.int64)
    for d in range(D):
        if not okc[d]:
            c[d, 0] = c[d, 1] = ang[d] = 0.0
            ab[d, 0] = ab[d, 1] = 1.0
        a, b = ab[d, 0], ab[d, 1]
        h = min(half_max_px, max(PROFILE_HALF_MIN_PX, PROFILE_HALF_PER_MINOR * b))
        pad = h + ROI_PAD_SIGMAS * sigma + ROI_PAD_PX
        hw[d] = h
        x0 = int(max(0.0, np.floor(c[d, 0] - a - pad)))
        x1 = min(W, int(np.ceil(c[d, 0] + a + pad)) + 1)
        y0 = int(max(0.0, np.floor(c[d, 1] - a - pad)))
        y1 = min(H, int(np.ceil(c[d, 1] + a + pad)) + 1)
        boxes[d, 0], boxes[d, 1], boxes[d, 2], boxes[d, 3] = x0, y0, x1, y1
        live[d] = okc[d] and y1 - y0 >= MIN_ROI_SIDE_PX and x1 - x0 >= MIN_ROI_SIDE_PX
        n[d] = int(max(float(MIN_PROFILES), np.ceil(perimeter(a, b) / spacing_px))) if live[d] else 0
    return c, ab, ang, okc, hw, boxes, live, n


def _offset_table(hw: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sample offsets of each dot's profiles, for half lengths ``hw`` (D,) px and ``step`` px: ``S`` (D, K) px
    (:func:`_profile_offsets`' values, NaN past a dot's end), their counts ``klen`` (D,) and ``rank`` (D, K - 1) the
    intervals in the order :func:`_crossings_kernel` examines them: nearest to the boundary first (ties: the lower
    index), those past the end last. All dots of one half length (most boards: the longest) take one cached row."""
    if len(hw) and np.all(hw == hw[0]):
        row, order = _uniform_offsets(float(hw[0]), step)
        D = len(hw)
        return np.repeat(row[None], D, axis=0), np.full(D, len(row)), np.repeat(order[None], D, axis=0)
    half, which = np.unique(hw, return_inverse=True)
    svecs = [_profile_offsets(float(h), step) for h in half]
    table = np.full((len(svecs), max(len(v) for v in svecs)), np.nan)
    for i, v in enumerate(svecs):
        table[i, : len(v)] = v
    S = table[which.reshape(-1)]
    klen = np.array([len(v) for v in svecs])[which.reshape(-1)]
    return S, klen, _nearest_first(S)


def _nearest_first(S: np.ndarray) -> np.ndarray:
    """(..., K - 1) the intervals of the offsets ``S`` (..., K) by the distance of their midpoints from 0, nearest
    first (a stable sort: ties keep the lower index), NaN ones (past a profile's end) last."""
    mid_dist = np.abs(0.5 * (S[..., :-1] + S[..., 1:]))
    return np.argsort(np.where(np.isfinite(mid_dist), mid_dist, np.inf), axis=-1, kind="stable")


@functools.lru_cache(maxsize=64)
def _uniform_offsets(half_length: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """(K,) :func:`_profile_offsets` and (K - 1,) :func:`_nearest_first` of them, read-only."""
    row = _profile_offsets(half_length, step)
    order = _nearest_first(row)
    order.flags.writeable = False
    return row, order


@functools.lru_cache(maxsize=256)
def _profile_offsets(half_length: float, step: float) -> np.ndarray:
    """(K,) read-only sample offsets (px along the outward normal) of a profile: ``-half_length`` to
    ``half_length`` every ``step`` (the end included; ``np.arange``'s values)."""
    s = np.arange(-half_length, half_length + 1e-9, step)
    s.flags.writeable = False
    return s


@njit(cache=True, nogil=True)
def _profiles_kernel(c, a, b, ang, conics, n, N, s_first, s_last, boxes):
    """Geometry of the edge profiles of D ellipses (centres ``c`` (D, 2), semi-axes ``a``, ``b``, angles ``ang``,
    conics (D, 3, 3)): ``n[d]`` profiles at equal steps of the parameter t, from ``s_first[d]`` to ``s_last[d]`` px
    along the outward normal.

    Returns ``base`` (D, N, 2) ellipse points, ``nrm`` (D, N, 2) unit outward normals, ``cos_t``, ``sin_t`` (D, N),
    ``inside`` (D, N): both ends of the profile within the box ``boxes[d]`` (x0, y0, x1, y1; one pixel in from x0,
    y0 and two from the exclusive ends), and ``ext`` (D, 4) ``xmin, ymin, xmax, ymax`` of the ends of the profiles
    ``inside`` (the extent to be sampled; NaN when none).
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
            ins = xlo <= ax <= xhi and ylo <= ay <= yhi and xlo <= zx <= xhi and ylo <= zy <= yhi
            inside[d, j] = ins
            if ins:
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
    return (
        u * u * u / 6.0,
        (t * t * (t - 2.0) * 3.0 + 4.0) / 6.0,
        (u * u * (u - 2.0) * 3.0 + 4.0) / 6.0,
        t * t * t / 6.0,
    )


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
    if ir >= 0 and ic >= 0 and ir + 3 < R and ic + 3 < C:  # no mirror reached (all samples in their crop's box):
        for i in range(4):  # the same sums without the index reflections
            acc = 0.0
            for j in range(4):
                acc += wc[j] * atlas[ir + i, ic + j]
            out += wr[i] * acc
        return out
    for i in range(4):
        row = _mirror(ir + i, R)
        acc = 0.0
        for j in range(4):
            acc += wc[j] * atlas[row, _mirror(ic + j, C)]
        out += wr[i] * acc
    return out


@njit(cache=True, nogil=True)
def _crossings_kernel(
    atlas, rows, org, base, nrm, S, n_iv, rank, todo, plane, halfk, off_out, at_out, rise_out, found_out
):
    """Nearest up-crossing of the half level on each profile ``(d, j)`` where ``todo``.

    Profile samples at ``base[d, j] + S[d, k] nrm[d, j]`` (smoothed image from ``atlas`` rows ``rows[d]`` +, crop
    origin ``org[d]``) minus the half level ``halfk[d] plane[d] @ (x, y, 1)``; intervals ``(k, k + 1)`` examined in
    the order ``rank[d, :n_iv[d]]`` (nearest to the boundary first), each sample computed once when first needed.
    Where one crosses (``found_out``), with ``fa``, ``fb`` the values at its ends: ``off_out`` the crossing's offset
    along the normal, ``S[d, k] + fa / (fa - fb) PROFILE_STEP_PX`` (linear interpolation), ``at_out`` (D, N, 2) the
    sample point before it and ``rise_out`` ``fb - fa`` (for the edge's slope); elsewhere they are left as given.
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
                    fa, fb, sk = F[kk], F[kk + 1], S[d, kk]
                    off_out[d, j] = sk + (fa / (fa - fb)) * PROFILE_STEP_PX
                    at_out[d, j, 0] = bx + sk * nx
                    at_out[d, j, 1] = by + sk * ny
                    rise_out[d, j] = fb - fa
                    found_out[d, j] = True
                    break
