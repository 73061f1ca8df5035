"""OpenCV's pinhole distortion polynomial (Brown-Conrady, rational, thin prism), written once: value, Jacobians and
the inverse.

``dist`` is OpenCV's distortion vector; its length chooses the model, exactly as in ``cv2.projectPoints``:

* 5 ``[k1, k2, p1, p2, k3]`` (circcal's ``opencv5``),
* 8 ``[k1, k2, p1, p2, k3, k4, k5, k6]`` (``rational``, OpenCV's ``CALIB_RATIONAL_MODEL``),
* 12 ``[k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4]`` (``thin-prism``, ``CALIB_THIN_PRISM_MODEL``).

On undistorted normalised coordinates ``x = X/Z, y = Y/Z`` (coefficients absent from the vector are 0)::

    r2 = x^2 + y^2
    radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
    xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2) + s1 r2 + s2 r2^2
    yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y + s3 r2 + s4 r2^2

(OpenCV's calib3d documentation, "Detailed description"; tested against ``cv2.projectPoints`` to 1e-9 px).
"""

from __future__ import annotations

from typing import Literal, overload

import numpy as np

__all__ = ["N_COEFFS", "check_dist", "distort", "distort_jacobian", "undistort", "denominator_minimum"]

#: The distortion-vector lengths this module implements (OpenCV's 5, 8 and 12; not its 4 or the tilted 14).
N_COEFFS = (5, 8, 12)

#: A Newton step of :func:`undistort` that does not lower a point's residual is halved, at most this many times
#: before the point is declared beyond the lens's fold (NaN).
_MAX_STEP_HALVINGS = 40
#: A point whose Newton step, however halved, no longer lowers its residual has reached the rounding floor of
#: evaluating the distortion (large rational coefficients, |k| ~ 10-100, put it above ``tol``: 1-3e-15): it is
#: converged when that residual is within this multiple of ``tol`` (1e-12 normalised: ~1e-9 px at f = 1000 px).
_ROUNDING_FLOOR_FACTOR = 1e3


def check_dist(dist: np.ndarray) -> np.ndarray:
    """``dist`` as a float64 vector of a length this module implements.

    Parameters
    ----------
    dist : array_like
        5, 8 or 12 coefficients in OpenCV's order (any shape; raveled).

    Returns
    -------
    ndarray
        (n,) float64, n in :data:`N_COEFFS`.

    Raises
    ------
    ValueError
        Another number of coefficients.
    """
    d = np.asarray(dist, dtype=np.float64).ravel()
    if d.size not in N_COEFFS:
        raise ValueError(f"a pinhole distortion vector holds 5, 8 or 12 coefficients (OpenCV's order), got {d.size}")
    return d


def denominator_minimum(dist: np.ndarray, r_max: float) -> tuple[float, float]:
    """The smallest value of the rational model's denominator ``1 + k4 r^2 + k5 r^4 + k6 r^6`` out to ``r_max``.

    A lens's denominator stays near its value on the axis (1). A fit whose k1..k6 trade off (numerator and
    denominator nearly cancelling) can take it to zero (a pole) or close to it inside the field: there projection is
    nearly singular and :func:`undistort` may find no inverse or another root.

    Parameters
    ----------
    dist : array_like
        5, 8 or 12 coefficients in OpenCV's order.
    r_max : float
        The largest ideal normalised radius ``|(x, y)| / z`` of interest (the observed field's).

    Returns
    -------
    value : float
        The minimum (1.0 for 5 coefficients); <= 0 where the denominator vanishes within ``r_max``.
    r : float
        The radius where it is reached; where the denominator first vanishes when it does.

    Raises
    ------
    ValueError
        ``dist`` of another length.

    Examples
    --------
    >>> [round(v, 12) for v in denominator_minimum([0.1, 0, 0, 0, 0, -4.0, 0, 0], 0.4)]  # 1 - 4 r^2
    [0.36, 0.4]
    """
    d = check_dist(dist)
    if d.size < 8:
        return 1.0, 0.0
    k4, k5, k6 = d[5:8]
    s_max = float(r_max) ** 2
    crit = np.roots([3.0 * k6, 2.0 * k5, k4])  # d den / d s = 0, in s = r^2
    crit = crit[np.abs(crit.imag) <= 1e-12 * np.maximum(1.0, np.abs(crit))].real
    s = np.concatenate([[0.0, s_max], crit[(crit > 0) & (crit < s_max)]])
    den = 1.0 + s * (k4 + s * (k5 + s * k6))
    k = int(np.argmin(den))
    if den[k] > 0:
        return float(den[k]), float(np.sqrt(s[k]))
    zeros = np.roots([k6, k5, k4, 1.0])
    zeros = zeros[np.abs(zeros.imag) <= 1e-12 * np.maximum(1.0, np.abs(zeros))].real
    return float(den[k]), float(np.sqrt(np.min(zeros[(zeros > 0) & (zeros <= s_max)], initial=s[k])))


@overload
def _brown(x: np.ndarray, y: np.ndarray, d: np.ndarray, jacobian: Literal[False]) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def _brown(x: np.ndarray, y: np.ndarray, d: np.ndarray, jacobian: Literal[True]) -> tuple[np.ndarray, ...]: ...


def _brown(x: np.ndarray, y: np.ndarray, d: np.ndarray, jacobian: bool) -> tuple[np.ndarray, ...]:
    """The distortion polynomial: ``(xd, yd)`` of normalised ``(x, y)`` (same-shape arrays); with ``jacobian`` also
    ``radial``, the denominator ``den`` (1.0 for 5 coefficients), the 2x2 Jacobian ``d(xd, yd)/d(x, y)`` as
    ``(a, b, e, c)`` = ``[[a, b], [e, c]]`` (symmetric, b = e, without thin prism), and the shared terms ``r2``,
    ``xy2 = 2 x y``, ``tx = r2 + 2 x^2``, ``ty = r2 + 2 y^2`` (for :func:`_coefficient_jacobian`). Squares are
    formed once (``2 x^2`` is exact from ``x^2``: the same numbers as ``2.0 * x * x``)."""
    n = d.size
    k1, k2, p1, p2, k3 = d[:5]
    xx, yy = x * x, y * y
    r2 = xx + yy
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    if n >= 8:
        k4, k5, k6 = d[5:8]
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        radial = num / den
    else:
        den = 1.0
        radial = num
    xy2 = 2.0 * x * y
    xx2, yy2 = 2.0 * xx, 2.0 * yy
    tx, ty = r2 + xx2, r2 + yy2
    xd = x * radial + p1 * xy2 + p2 * tx
    yd = y * radial + p1 * ty + p2 * xy2
    if n == 12:
        s1, s2, s3, s4 = d[8:12]
        xd = xd + r2 * (s1 + s2 * r2)
        yd = yd + r2 * (s3 + s4 * r2)
    if not jacobian:
        return xd, yd
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d num / d r2
    if n >= 8:
        dradial = (dradial - radial * (k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2))) / den
    a = radial + xx2 * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    b = xy2 * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    c = radial + yy2 * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    e = b
    if n == 12:
        gx = 2.0 * (s1 + 2.0 * s2 * r2)  # d (s1 r2 + s2 r2^2) / d r2, times 2 (d r2 / dx = 2x)
        gy = 2.0 * (s3 + 2.0 * s4 * r2)
        a = a + gx * x
        b = b + gx * y
        e = e + gy * x
        c = c + gy * y
    return xd, yd, radial, den, a, b, e, c, r2, xy2, tx, ty


def _coefficient_jacobian(
    x: np.ndarray,
    y: np.ndarray,
    r2: np.ndarray,
    xy2: np.ndarray,
    tx: np.ndarray,
    ty: np.ndarray,
    radial: np.ndarray,
    den: np.ndarray | float,
    n: int,
    out: np.ndarray,
    scale: tuple[float, float] | None = None,
) -> None:
    """Fill ``out`` (..., 2, n) with d (xd, yd) / d dist (columns in ``dist``'s order) at normalised ``(x, y)``, from
    :func:`_brown`'s ``r2``, ``xy2``, ``tx``, ``ty``, ``radial`` and ``den``; with ``scale = (sx, sy)`` row 0 times
    sx and row 1 times sy (the focal lengths: d uv / d dist). Every column is one contiguous product written into its
    strided place (numpy's broadcasting over the small (2, n) trailing axes runs 3-5x slower, measured), from the
    shared powers r^2, r^4, r^6."""
    mul = np.multiply
    r4 = r2 * r2
    r6 = r4 * r2
    xo, yo = (x, y) if n == 5 else (x / den, y / den)  # d radial / d k_i = r^(2i) / den for k1, k2, k3
    if scale is not None:
        xo, yo = xo * scale[0], yo * scale[1]
    mul(xo, r2, out=out[..., 0, 0])
    mul(xo, r4, out=out[..., 0, 1])
    mul(xo, r6, out=out[..., 0, 4])
    mul(yo, r2, out=out[..., 1, 0])
    mul(yo, r4, out=out[..., 1, 1])
    mul(yo, r6, out=out[..., 1, 4])
    if scale is None:  # p1, p2: [[2xy, r2 + 2x^2], [r2 + 2y^2, 2xy]]
        out[..., 0, 2] = xy2
        out[..., 1, 3] = xy2
        out[..., 0, 3] = tx
        out[..., 1, 2] = ty
    else:
        mul(xy2, scale[0], out=out[..., 0, 2])
        mul(xy2, scale[1], out=out[..., 1, 3])
        mul(tx, scale[0], out=out[..., 0, 3])
        mul(ty, scale[1], out=out[..., 1, 2])
    if n >= 8:  # d radial / d k_{4,5,6} = -radial r^(2i) / den
        nrad = -radial
        xr, yr = xo * nrad, yo * nrad
        mul(xr, r2, out=out[..., 0, 5])
        mul(xr, r4, out=out[..., 0, 6])
        mul(xr, r6, out=out[..., 0, 7])
        mul(yr, r2, out=out[..., 1, 5])
        mul(yr, r4, out=out[..., 1, 6])
        mul(yr, r6, out=out[..., 1, 7])
    if n == 12:  # s1, s2 move xd by r2, r4; s3, s4 move yd
        sx, sy = (1.0, 1.0) if scale is None else scale
        mul(r2, sx, out=out[..., 0, 8])
        mul(r4, sx, out=out[..., 0, 9])
        mul(r2, sy, out=out[..., 1, 10])
        mul(r4, sy, out=out[..., 1, 11])
        out[..., 0, 10:12] = 0.0
        out[..., 1, 8:10] = 0.0


def distort(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply the distortion to normalised coordinates.

    Parameters
    ----------
    xn : ndarray
        (..., 2) undistorted normalised coordinates (unitless).
    dist : ndarray
        (5,), (8,) or (12,) in OpenCV's order.

    Returns
    -------
    ndarray
        (..., 2) distorted normalised coordinates.

    Raises
    ------
    ValueError
        ``dist`` of another length.

    Examples
    --------
    >>> distort(np.array([0.1, 0.0]), np.array([0.1, 0, 0, 0, 0]))
    array([0.1001, 0.    ])
    """
    xn = np.asarray(xn, dtype=np.float64)
    xd, yd = _brown(xn[..., 0], xn[..., 1], check_dist(dist), False)
    return np.stack([xd, yd], axis=-1)


def _distort_jacobian_into(
    x: np.ndarray, y: np.ndarray, d: np.ndarray, J_d: np.ndarray, scale: tuple[float, float] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`distort_jacobian` on the coordinate arrays ``x``, ``y`` with ``J_d`` written into ``J_d`` (..., 2, n)
    (a view of a caller's array; rows times ``scale``, see :func:`_coefficient_jacobian`). Returns ``(xd, yd, a, b,
    e, c)``: the distorted coordinates and ``d xd / d xn = [[a, b], [e, c]]``."""
    xd, yd, radial, den, a, b, e, c, r2, xy2, tx, ty = _brown(x, y, d, True)
    _coefficient_jacobian(x, y, r2, xy2, tx, ty, radial, den, d.size, J_d, scale)
    return xd, yd, a, b, e, c


def distort_jacobian(xn: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distortion with its derivatives.

    Parameters
    ----------
    xn : ndarray
        (..., 2) undistorted normalised coordinates.
    dist : ndarray
        (n,), n = 5, 8 or 12.

    Returns
    -------
    xd : ndarray
        (..., 2) distorted normalised coordinates.
    J_x : ndarray
        (..., 2, 2): d xd / d xn.
    J_d : ndarray
        (..., 2, n): d xd / d dist, columns in ``dist``'s order.

    Raises
    ------
    ValueError
        ``dist`` of another length.
    """
    xn = np.asarray(xn, dtype=np.float64)
    d = check_dist(dist)
    J_d = np.empty(xn.shape[:-1] + (2, d.size))
    xd, yd, a, b, e, c = _distort_jacobian_into(xn[..., 0], xn[..., 1], d, J_d)
    J_x = np.empty(xn.shape[:-1] + (2, 2))
    J_x[..., 0, 0] = a
    J_x[..., 0, 1] = b
    J_x[..., 1, 0] = e
    J_x[..., 1, 1] = c
    return np.stack([xd, yd], axis=-1), J_x, J_d


def undistort(
    xd: np.ndarray,
    dist: np.ndarray,
    *,
    x0: np.ndarray | None = None,
    tol: float = 1e-15,
    max_iter: int = 60,
) -> np.ndarray:
    """Invert :func:`distort` by a vectorised, damped Newton iteration.

    A step that does not reduce a point's residual is halved (guards strong barrel distortion). A point no step
    improves is converged at its rounding floor when within :data:`_ROUNDING_FLOOR_FACTOR` of ``tol``. Points where the
    model folds over (no unique inverse, far outside a sensible field of view: the radial factor not positive, or the
    map orientation-reversing) come back as NaN rather than a wrong value.

    Parameters
    ----------
    xd : ndarray
        (..., 2) distorted normalised coordinates.
    dist : ndarray
        (5,), (8,) or (12,).
    x0 : ndarray, optional
        (..., 2) initial guess (e.g. a neighbouring solution: two Newton steps then suffice); default ``xd``.
    tol : float
        Stop when every residual ``|distort(x) - xd|`` (max norm, normalised units) is below ``tol`` (relative to
        ``|xd|`` beyond 1); 1e-15 normalised is ~1e-11 px for f up to 10^4 px.
    max_iter : int
        Newton iterations at most; points not converged by then are NaN.

    Returns
    -------
    ndarray
        (..., 2) undistorted normalised coordinates, NaN where there is no inverse.

    Raises
    ------
    ValueError
        ``dist`` of another length.
    """
    xd = np.asarray(xd, dtype=np.float64)
    d = check_dist(dist)
    if not np.any(d):
        return xd.copy()
    shape = xd.shape
    t = xd.reshape(-1, 2)
    out = t.copy() if x0 is None else np.asarray(x0, dtype=np.float64).reshape(-1, 2).copy()
    idx = np.arange(t.shape[0])  # points still iterating
    tx, ty = t[:, 0].copy(), t[:, 1].copy()
    x, y = out[:, 0].copy(), out[:, 1].copy()
    thr = tol * np.maximum(1.0, np.maximum(np.abs(tx), np.abs(ty)))
    fx, fy, _, _, a, b, e, c, *_ = _brown(x, y, d, True)
    rx, ry = fx - tx, fy - ty
    err = np.maximum(np.abs(rx), np.abs(ry))
    floor = np.zeros(err.shape, dtype=bool)  # the last full step did not lower the residual: rounding level
    for _ in range(max_iter):
        done = (err <= thr) | (floor & (err <= _ROUNDING_FLOOR_FACTOR * thr))
        if done.any():
            out[idx[done], 0] = x[done]
            out[idx[done], 1] = y[done]
            keep = ~done
            idx, tx, ty, x, y, thr, a, b, e, c, rx, ry, err, floor = (
                v[keep] for v in (idx, tx, ty, x, y, thr, a, b, e, c, rx, ry, err, floor)
            )
        if idx.size == 0:
            break
        det = a * c - b * e
        det = np.where(np.abs(det) < 1e-300, 1e-300, det)
        sx = (c * rx - b * ry) / det
        sy = (a * ry - e * rx) / det
        lam = np.ones_like(x)
        for _ in range(_MAX_STEP_HALVINGS):
            nx, ny = x - lam * sx, y - lam * sy
            fx, fy, _, _, na, nb, ne, nc, *_ = _brown(nx, ny, d, True)
            nrx, nry = fx - tx, fy - ty
            nerr = np.maximum(np.abs(nrx), np.abs(nry))
            worse = ~(nerr <= err)  # also catches NaN
            if not worse.any():
                break
            lam = np.where(worse, 0.5 * lam, lam)
        floor = nerr >= err  # no step, however short, lowered it
        x, y, a, b, e, c, rx, ry, err = nx, ny, na, nb, ne, nc, nrx, nry, nerr
        if worse.any():  # no descent even after every halving: no inverse here (the model folds over)
            out[idx[worse]] = np.nan
            keep = ~worse
            idx, tx, ty, x, y, thr, a, b, e, c, rx, ry, err, floor = (
                v[keep] for v in (idx, tx, ty, x, y, thr, a, b, e, c, rx, ry, err, floor)
            )
    if idx.size:
        out[idx] = np.nan
    # A root on the far side of the fold (radial factor <= 0, or the map locally orientation-reversing) is no
    # inverse of a real lens: report it as NaN. (The rational denominator alone may cross 0 where its numerator
    # does too: a fitted pole-zero pair that cancels is a smooth lens.)
    _, _, radial, _, a, b, e, c, *_ = _brown(out[:, 0], out[:, 1], d, True)
    bad = (radial <= 0) | ((a * c - b * e) <= 0)
    out[bad] = np.nan
    return out.reshape(shape)
