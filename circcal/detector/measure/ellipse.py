"""Ellipses as conic matrices: their parameters, conversions and the points' distances from them.

A conic is a symmetric (3, 3) matrix ``Q`` with ``x^T Q x = 0`` for homogeneous image points ``x = (u, v, 1)``
(pixels, OpenCV convention: integer coordinates are pixel centres). Scale and sign of ``Q`` are arbitrary unless
stated. The single-conic functions have batched twins working on stacks ``(D, 3, 3)`` of conics at once
(:func:`conic_params_batch`, :func:`conic_centres`, :func:`conic_from_params_batch`); the single versions call them,
so the math exists once. The fit of a conic to points: :mod:`circcal.detector.measure.ellipsefit`.
"""

from __future__ import annotations

import numpy as np

from circcal.detector.kernels.jit import njit

__all__ = [
    "conic_params_batch",
    "conic_centres",
    "conic_from_params",
    "conic_from_params_batch",
    "conic_params",
    "conic_centre",
    "sample_ellipse",
    "ellipse_normals",
    "transform_conic",
    "algebraic_distance",
    "sampson_distances",
]


def conic_from_params(centre: np.ndarray, axes: tuple[float, float], angle: float) -> np.ndarray:
    """The conic matrix of an ellipse given by its centre, semi-axes and angle.

    Parameters
    ----------
    centre : numpy.ndarray
        (2,) px ``(x, y)``.
    axes : tuple of float
        ``(a, b)`` semi-axes, px.
    angle : float
        rad: the angle of the ``a`` axis from the image x axis (towards +y).

    Returns
    -------
    numpy.ndarray
        (3, 3) float64, scaled so that ``x^T Q x = -1`` at the centre.

    Examples
    --------
    >>> conic_from_params(np.array([10.0, 20.0]), (5.0, 5.0), 0.0) * 25.0
    array([[  1.,   0., -10.],
           [  0.,   1., -20.],
           [-10., -20., 475.]])
    """
    return conic_from_params_batch(
        np.asarray(centre, dtype=np.float64).reshape(1, 2),
        np.asarray(axes, dtype=np.float64).reshape(1, 2),
        np.array([float(angle)]),
    )[0]


def conic_from_params_batch(centres: np.ndarray, axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Batched :func:`conic_from_params`: the conic matrices of ellipses given by centres, semi-axes and angles.

    Parameters
    ----------
    centres : numpy.ndarray
        (D, 2) px ``(x, y)``.
    axes : numpy.ndarray
        (D, 2) semi-axes ``(a, b)``, px.
    angles : numpy.ndarray
        (D,) rad: the angles of the ``a`` axes from the image x axis (towards +y).

    Returns
    -------
    numpy.ndarray
        (D, 3, 3) float64 conics, each scaled so that ``x^T Q x = -1`` at its centre.
    """
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    ax = np.asarray(axes, dtype=np.float64).reshape(-1, 2)
    ang = np.asarray(angles, dtype=np.float64).reshape(-1)
    co, si = np.cos(ang), np.sin(ang)
    R = np.stack([np.stack([co, -si], axis=1), np.stack([si, co], axis=1)], axis=1)  # (D, 2, 2)
    M = (R / ax[:, None, :] ** 2) @ R.transpose(0, 2, 1)  # R diag(1/a^2, 1/b^2) R^T
    Mc = (M @ c[:, :, None])[:, :, 0]
    Q = np.empty((len(c), 3, 3))
    Q[:, :2, :2] = M
    Q[:, :2, 2] = Q[:, 2, :2] = -Mc
    Q[:, 2, 2] = c[:, 0] * Mc[:, 0] + c[:, 1] * Mc[:, 1] - 1.0
    return Q


def conic_centre(Q: np.ndarray) -> np.ndarray:
    """The centre of an ellipse conic.

    Parameters
    ----------
    Q : numpy.ndarray
        (3, 3) conic matrix, px.

    Returns
    -------
    numpy.ndarray
        (2,) float64 px ``(x, y)``.

    Raises
    ------
    numpy.linalg.LinAlgError
        The conic has no centre (its upper-left 2x2 block is singular: a parabola or degenerate conic).
    """
    return np.linalg.solve(Q[:2, :2], -Q[:2, 2])


def conic_centres(Q: np.ndarray) -> np.ndarray:
    """The centres of a stack of ellipse conics (closed-form 2x2 solve, :func:`conic_params_batch`'s).

    Parameters
    ----------
    Q : numpy.ndarray
        (D, 3, 3) conic matrices, px.

    Returns
    -------
    numpy.ndarray
        (D, 2) float64 px ``(x, y)``; NaN for a conic that is no real ellipse.
    """
    return conic_params_batch(Q)[0]


def conic_params(Q: np.ndarray) -> tuple[np.ndarray, tuple[float, float], float]:
    """The centre, semi-axes and angle of an ellipse conic: the inverse of :func:`conic_from_params`.

    Parameters
    ----------
    Q : numpy.ndarray
        (3, 3) conic matrix, px (any scale and sign).

    Returns
    -------
    centre : numpy.ndarray
        (2,) float64 px ``(x, y)``.
    axes : tuple of float
        ``(a, b)`` semi-axes, px, with ``a >= b``.
    angle : float
        rad, in (-pi/2, pi/2]: the angle of the ``a`` axis from the image x axis.

    Raises
    ------
    ValueError
        ``Q`` is not a real ellipse.

    Examples
    --------
    >>> c, (a, b), ang = conic_params(conic_from_params(np.array([10.0, 20.0]), (3.0, 5.0), 0.0))
    >>> c.round(9) + 0.0, round(a, 9), round(b, 9), round(ang, 9)
    (array([10., 20.]), 5.0, 3.0, 1.570796327)
    """
    c, axes, ang, ok = conic_params_batch(np.asarray(Q, dtype=np.float64).reshape(1, 3, 3))
    if not ok[0]:
        raise ValueError("conic is not a real ellipse")
    return c[0], (float(axes[0, 0]), float(axes[0, 1])), float(ang[0])


def conic_params_batch(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Batched :func:`conic_params`: rows that are not real ellipses are flagged instead of raising.

    Closed form: the centre from a 2x2 solve, axes and angle from the closed-form eigen-decomposition of the
    symmetric 2x2 block; one compiled pass (:func:`_conic_params_kernel`; the numpy expressions it replaced took ~35
    array operations, ~0.1 ms a call, four calls per image).

    Parameters
    ----------
    Q : numpy.ndarray
        (D, 3, 3) conic matrices, px (any scale and sign).

    Returns
    -------
    centres : numpy.ndarray
        (D, 2) float64 px ``(x, y)``.
    axes : numpy.ndarray
        (D, 2) float64 semi-axes ``(a, b)``, px, with ``a >= b``.
    angles : numpy.ndarray
        (D,) float64 rad, in (-pi/2, pi/2]: the angles of the ``a`` axes.
    ok : numpy.ndarray
        (D,) bool: false (and NaN values) for rows that are not real ellipses.
    """
    Q = np.ascontiguousarray(Q, dtype=np.float64).reshape(-1, 3, 3)
    D = len(Q)
    c, axes, ang, ok = np.empty((D, 2)), np.empty((D, 2)), np.empty(D), np.empty(D, bool)
    _conic_params_kernel(Q, c, axes, ang, ok)
    return c, axes, ang, ok


@njit(cache=True, nogil=True)
def _conic_params_kernel(Q, c, axes, ang, ok):
    """Writes :func:`conic_params_batch` of ``Q`` (D, 3, 3) into ``c``, ``axes``, ``ang``, ``ok``: numpy's
    expressions in numpy's order, per conic. The centre ``(r u - q v, p v - q u) / det`` of the 2x2 block; the value
    at the centre as the full quadratic (stationary there: an error in c enters squared; the linear form g.c + F
    loses ~1e-7 relative for small ellipses far from the origin); the eigenvalues of the normalised block, the small
    one as ``det / l_big`` (no cancellation); the a axis at ``0.5 atan2(-2q, r - p)``. Where a division would be by
    zero the conic is no real ellipse (numpy's infinities and NaNs end in ``ok`` false all the same): NaN."""
    for d in range(len(Q)):
        Q00, Q01, Q02, Q11, Q12, Q22 = Q[d, 0, 0], Q[d, 0, 1], Q[d, 0, 2], Q[d, 1, 1], Q[d, 1, 2], Q[d, 2, 2]
        good = False
        det = Q00 * Q11 - Q01 * Q01
        if det != 0.0:
            u, v = -Q02, -Q12
            cx = (Q11 * u - Q01 * v) / det
            cy = (Q00 * v - Q01 * u) / det
            f0 = (Q00 * cx + 2.0 * Q01 * cy) * cx + Q11 * cy * cy + 2.0 * (Q02 * cx + Q12 * cy) + Q22
            if f0 != 0.0:
                p, q, r = Q00 / -f0, Q01 / -f0, Q11 / -f0
                h = 0.5 * (p - r)
                disc = np.hypot(h, q)
                mid = 0.5 * (p + r)
                l_big = mid + disc
                if l_big != 0.0:
                    l_small = (p * r - q * q) / l_big
                    good = np.isfinite(l_small) and np.isfinite(l_big) and l_small > 0 and l_big > 0
        ok[d] = good
        if good:
            c[d, 0], c[d, 1] = cx, cy
            axes[d, 0], axes[d, 1] = 1.0 / np.sqrt(l_small), 1.0 / np.sqrt(l_big)
            t = 0.5 * np.arctan2(-2.0 * q, r - p)
            ang[d] = t + np.pi if t <= -np.pi / 2 else (t - np.pi if t > np.pi / 2 else t)
        else:
            c[d, 0] = c[d, 1] = axes[d, 0] = axes[d, 1] = ang[d] = np.nan


def sample_ellipse(Q: np.ndarray, n: int) -> np.ndarray:
    """Points on an ellipse at equally spaced parameter angles.

    Parameters
    ----------
    Q : numpy.ndarray
        (3, 3) ellipse conic, px.
    n : int
        Number of points.

    Returns
    -------
    numpy.ndarray
        (n, 2) float64 px ``(x, y)``: ``centre + R(angle) (a cos t, b sin t)``, t = 2 pi k / n.

    Raises
    ------
    ValueError
        ``Q`` is not a real ellipse.
    """
    c, (a, b), ang = conic_params(Q)
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    ca, sa = np.cos(ang), np.sin(ang)
    x = a * np.cos(t)
    y = b * np.sin(t)
    return np.column_stack([c[0] + ca * x - sa * y, c[1] + sa * x + ca * y])


def ellipse_normals(Q: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The unit outward normals of a conic's level sets at given points (the gradient of ``x^T Q x``).

    Parameters
    ----------
    Q : numpy.ndarray
        (3, 3) conic matrix, px (any sign: outward is away from the centre of an ellipse).
    points : numpy.ndarray
        (M, 2) px ``(x, y)``.

    Returns
    -------
    numpy.ndarray
        (M, 2) float64 unit vectors (NaN where the gradient vanishes, at an ellipse's centre).
    """
    p = np.asarray(points, dtype=np.float64)
    g = p @ Q[:2, :2].T + Q[:2, 2]
    if Q[0, 0] + Q[1, 1] < 0:
        g = -g
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def transform_conic(Q: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The conic of the image of a conic under a point homography: ``T^-T Q T^-1``.

    Parameters
    ----------
    Q : numpy.ndarray
        (3, 3) conic matrix.
    T : numpy.ndarray
        (3, 3) homography taking points ``x`` to ``T x``.

    Returns
    -------
    numpy.ndarray
        (3, 3) float64 conic in the target coordinates.

    Raises
    ------
    numpy.linalg.LinAlgError
        ``T`` is singular.
    """
    Ti = np.linalg.inv(T)
    return Ti.T @ Q @ Ti


def algebraic_distance(Q: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The algebraic distance ``x^T Q x`` of points from a conic (the scale and sign of ``Q`` as given).

    Parameters
    ----------
    Q : numpy.ndarray
        (3, 3) conic matrix, px.
    points : numpy.ndarray
        (M, 2) px ``(x, y)``.

    Returns
    -------
    numpy.ndarray
        (M,) float64, with ``x = (x, y, 1)``.
    """
    p = np.asarray(points, dtype=np.float64)
    h = np.column_stack([p, np.ones(len(p))])
    return np.einsum("ij,jk,ik->i", h, Q, h)


def sampson_distances(points: np.ndarray, conics: np.ndarray) -> np.ndarray:
    """The first-order (Sampson) signed distances of points from conics, one conic per row of points.

    ``x^T Q x / |grad_(u,v) x^T Q x|``, the sign and scale of ``Q`` as given. One compiled pass
    (:func:`_sampson_kernel`; numpy took ~10 array passes, ~0.2-0.4 ms for a 7x7 board).

    Parameters
    ----------
    points : numpy.ndarray
        (D, M, 2) px ``(x, y)``.
    conics : numpy.ndarray
        (D, 3, 3) conic matrices, px.

    Returns
    -------
    numpy.ndarray
        (D, M) float64 px; NaN where a point or conic is NaN or where the gradient vanishes at a point on the conic,
        +-inf where it vanishes off it (numpy's division).

    Examples
    --------
    >>> Q = conic_from_params(np.array([0.0, 0.0]), (5.0, 5.0), 0.0)
    >>> sampson_distances(np.array([[[6.0, 0.0], [0.0, -4.0]]]), Q[None])  # first order: the true ones are +-1
    array([[ 0.91666667, -1.125     ]])
    """
    P = np.ascontiguousarray(points, np.float64).reshape(len(points), -1, 2)
    Q = np.ascontiguousarray(conics, np.float64).reshape(len(P), 3, 3)
    out = np.empty(P.shape[:2])
    if out.size:
        _sampson_kernel(P, Q, out)
    return out


@njit(cache=True, nogil=True)
def _sampson_kernel(P, Q, out):
    """Writes :func:`sampson_distances` of ``P`` (D, M, 2) from ``Q`` (D, 3, 3) into ``out`` (D, M)
    (:func:`sampson_at` per point)."""
    D, M = out.shape
    for d in range(D):
        for m in range(M):
            out[d, m] = sampson_at(Q[d], P[d, m, 0], P[d, m, 1])


@njit(cache=True, nogil=True, inline="always")
def perimeter(a, b):
    """The perimeter of an ellipse: Ramanujan's second approximation.

    Relative error 5e-10 at an axis ratio of 1:2, 2.5e-7 at 1:4, 1.2e-5 at 1:10, against the complete elliptic
    integral. Compiled (inlined into the edge kernels).

    Parameters
    ----------
    a, b : float
        Semi-axes, px.

    Returns
    -------
    float
        px.
    """
    hab = ((a - b) / max(a + b, 1e-12)) ** 2
    return np.pi * (a + b) * (1 + 3 * hab / (10 + np.sqrt(4 - 3 * hab)))


@njit(cache=True, nogil=True, inline="always")
def sampson_at(Q, x, y):
    """The Sampson distance of one point from a conic (compiled, inlined into the kernels).

    ``h Q`` as numpy's matmul sums it (``(x Q0j + y Q1j) + Q2j``), the value ``(hQ0 x + hQ1 y) + hQ2`` over the
    gradient's norm ``|2 (hQ0, hQ1)|``.

    Parameters
    ----------
    Q : numpy.ndarray
        (3, 3) float64 conic matrix, px.
    x, y : float
        The point, px.

    Returns
    -------
    float
        px, signed; where the gradient vanishes NaN on the conic (or for NaN), +-inf off it (numpy's division:
        numba, like Python, would raise on a division by zero).
    """
    h0 = x * Q[0, 0] + y * Q[1, 0] + Q[2, 0]
    h1 = x * Q[0, 1] + y * Q[1, 1] + Q[2, 1]
    h2 = x * Q[0, 2] + y * Q[1, 2] + Q[2, 2]
    num = (h0 * x + h1 * y) + h2
    gx, gy = 2.0 * h0, 2.0 * h1
    g = np.sqrt(gx * gx + gy * gy)
    if g == 0.0:
        return np.nan if (num == 0.0 or np.isnan(num)) else (np.inf if num > 0 else -np.inf)
    return num / g
