"""Ellipses as conic matrices: the direct least-squares fit and conversions.

A conic is a symmetric (3, 3) matrix ``Q`` with ``x^T Q x = 0`` for homogeneous image points ``x = (u, v, 1)``
(pixels, OpenCV convention: integer coordinates are pixel centres). Scale and sign of ``Q`` are arbitrary unless
stated. The single-conic functions have batched twins working on stacks ``(D, 3, 3)`` of conics at once
(:func:`fit_ellipses_direct`, :func:`conic_params_batch`, :func:`conic_centres`); the single versions call them, so
the math exists once.

The fit is Fitzgibbon's direct ellipse-specific least squares in the numerically stable form of Halir & Flusser
(1998), on coordinates normalised to zero mean and unit RMS radius (Hartley-style) and mapped back exactly.
"""

from __future__ import annotations

import numpy as np

from circcal.detector.kernels.jit import njit

__all__ = [
    "fit_ellipse_direct",
    "fit_ellipses_direct",
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


FIT_ERRORS = {
    1: "an ellipse fit needs at least 5 points",
    2: "ellipse fit: points contain NaN or inf",
    3: "ellipse fit: points are degenerate (collinear)",
    4: "ellipse fit: no elliptic solution (points may lie on a line or hyperbola)",
}
"""Messages for the error codes of :func:`fit_ellipses_direct` (0 = fitted)."""


def fit_ellipse_direct(points: np.ndarray) -> np.ndarray:
    """The direct least-squares ellipse through a set of points (Halir-Flusser, normalised).

    Minimises the algebraic distance subject to ``4AC - B^2 = 1`` (in normalised coordinates), so the result is
    always an ellipse.

    Parameters
    ----------
    points : numpy.ndarray
        (M, 2) px ``(x, y)``, M >= 5.

    Returns
    -------
    numpy.ndarray
        (3, 3) float64 conic in pixel coordinates, scaled to unit Frobenius norm with negative value at the centre
        (``x^T Q x < 0`` inside).

    Raises
    ------
    ValueError
        Fewer than 5 points, or degenerate input (NaN or inf, collinear, no elliptic solution: :data:`FIT_ERRORS`).

    Examples
    --------
    >>> t = np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False)
    >>> Q = fit_ellipse_direct(np.column_stack([10 + 5 * np.cos(t), 20 + 3 * np.sin(t)]))
    >>> np.round(conic_centre(Q), 9) + 0.0
    array([10., 20.])
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    Q, err = fit_ellipses_direct(p[None], None)
    if err[0]:
        msg = FIT_ERRORS[int(err[0])]
        raise ValueError(f"{msg}, got {len(p)}" if err[0] == 1 else msg)
    return Q[0]


def fit_ellipses_direct(points: np.ndarray, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Batched :func:`fit_ellipse_direct`: one ellipse per row of points, errors as codes instead of raising.

    Each fit is the same normalised Halir-Flusser solve as the single version, compiled and in closed form
    (:func:`_direct_solves`: ~7x faster than stacked LAPACK solves and eigen-decompositions, the same conics to
    ~1e-12); it never raises for a bad row.

    Parameters
    ----------
    points : numpy.ndarray
        (D, M, 2) px ``(x, y)``.
    mask : numpy.ndarray or None
        (D, M) bool: the points used (all when ``None``; masked-out points may hold anything, NaN included).

    Returns
    -------
    Q : numpy.ndarray
        (D, 3, 3) float64 conics as in :func:`fit_ellipse_direct`; NaN where ``err != 0``.
    err : numpy.ndarray
        (D,) int64 error codes: 0 fitted; otherwise a key of :data:`FIT_ERRORS`.

    Raises
    ------
    ValueError
        ``points`` is not (D, M, 2).
    """
    p = np.ascontiguousarray(points, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 2:
        raise ValueError(f"points must be (D, M, 2), got shape {p.shape}")
    D = p.shape[0]
    m = np.ones(p.shape[:2], bool) if mask is None else np.ascontiguousarray(mask, bool)
    err = np.zeros(D, np.int64)
    Q = np.empty((D, 3, 3))
    _fit_kernel(p, m, Q, err)
    return Q, err


@njit(cache=True, nogil=True)
def _fit_kernel(p, m, Q, err):
    """:func:`fit_ellipses_direct` of ``p`` (D, M, 2) where ``m`` (D, M): writes ``Q`` (D, 3, 3) and ``err`` (D,)
    (zeros on entry): code 2 for a row with a non-finite point in ``m``, 1 (overriding it) for fewer than 5 points,
    the others by :func:`_direct_solves` on the scatter of the finite points (:func:`_normalised_scatter`); NaN
    conics where ``err != 0``."""
    D, M = m.shape
    use = np.empty((D, M), np.bool_)
    for d in range(D):
        cnt = 0
        bad = False
        for i in range(M):
            fin = np.isfinite(p[d, i, 0]) and np.isfinite(p[d, i, 1])
            if m[d, i]:
                cnt += 1
                bad |= not fin
            use[d, i] = m[d, i] and fin
        if bad:
            err[d] = 2
        if cnt < 5:
            err[d] = 1
    mean, s, S1, S2, S3 = _normalised_scatter(p, use)
    Q[:] = np.nan
    _direct_solves(S1, S2, S3, mean, s, err, Q)


@njit(cache=True, nogil=True)
def _direct_solves(S1, S2, S3, mean, s, err, Q):
    """The Halir-Flusser solve of each row ``d`` with ``err[d] == 0``, in closed form: writes the conic (3, 3) px into
    ``Q[d]`` (unit Frobenius norm, upper-left block positive definite) or an error code into ``err[d]`` (3:
    ``S3`` singular or the reduced matrix not finite; 4: no elliptic solution).

    ``T = -S3^-1 S2^T`` (:func:`_solve3`), ``M = C1^-1 (S1 + S2 T)``; the ellipse is the eigenvector of M's largest
    eigenvalue (Fitzgibbon et al. 1999: the reduced scatter is positive semi-definite and the constraint
    ``4AC - B^2`` has one positive direction, so exactly one eigenvalue is >= 0, the ellipse's, and the other two
    are <= 0; for the points of a circle those two coincide, which is why it is found by its eigenvalue, not by
    testing the constraint on all three eigenvectors), taken from the characteristic cubic (trigonometric roots,
    two Newton steps) and the largest cross product of two rows of ``M - lambda I``, refined
    (:func:`_refined_eigenvector`); the linear part is ``T a1``.
    The conic is mapped back from the normalised coordinates ``s (p - mean)``."""
    for d in range(len(err)):
        if err[d] != 0:
            continue
        T = np.empty((3, 3))  # -S3^-1 S2^T, by Gaussian elimination with partial pivoting (as LAPACK's solve:
        if not _solve3(S3[d], S2[d], T):  # the adjugate's inverse lost ~1e-7 of a thin ellipse's axes)
            err[d] = 3
            continue
        R = np.empty((3, 3))  # S1 + S2 T
        for i in range(3):
            for j in range(3):
                acc = S1[d, i, j]
                for k in range(3):
                    acc += S2[d, i, k] * T[k, j]
                R[i, j] = acc
        M = np.empty((3, 3))  # C1^-1 R
        for j in range(3):
            M[0, j], M[1, j], M[2, j] = R[2, j] / 2.0, -R[1, j], R[0, j] / 2.0
        if not np.all(np.isfinite(M)):
            err[d] = 3
            continue
        lam = _largest_eigenvalue(M)
        # eigenvector: the largest cross product of two rows of M - lam I
        best = -1.0
        v0 = v1 = v2 = 0.0
        for i, j in ((0, 1), (0, 2), (1, 2)):
            ax, ay, az = M[i, 0] - (lam if i == 0 else 0.0), M[i, 1] - (lam if i == 1 else 0.0), M[i, 2]
            bx, by, bz = M[j, 0], M[j, 1] - (lam if j == 1 else 0.0), M[j, 2] - (lam if j == 2 else 0.0)
            cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
            nn = cx * cx + cy * cy + cz * cz
            if nn > best:
                best, v0, v1, v2 = nn, cx, cy, cz
        if best > 0.0:
            v0, v1, v2 = _refined_eigenvector(M, lam, v0, v1, v2)
        if not (best > 0.0 and 4.0 * v0 * v2 - v1 * v1 > 0.0):
            err[d] = 4
            continue
        A, B, C = v0, v1, v2
        Dd = T[0, 0] * v0 + T[0, 1] * v1 + T[0, 2] * v2
        E = T[1, 0] * v0 + T[1, 1] * v1 + T[1, 2] * v2
        F = T[2, 0] * v0 + T[2, 1] * v1 + T[2, 2] * v2
        # back to pixels: x_n = s (x - mean), so Q = N^T Qn N with N = [[s, 0, -s mx], [0, s, -s my], [0, 0, 1]]
        sc, mx, my = s[d], mean[d, 0], mean[d, 1]
        q00, q01, q11 = A * sc * sc, 0.5 * B * sc * sc, C * sc * sc
        l0, l1 = 0.5 * Dd * sc, 0.5 * E * sc
        q02 = -(q00 * mx + q01 * my) + l0
        q12 = -(q01 * mx + q11 * my) + l1
        q22 = ((A * mx + B * my) * mx + C * my * my) * sc * sc - 2.0 * (l0 * mx + l1 * my) + F
        nrm = np.sqrt(q00 * q00 + q11 * q11 + q22 * q22 + 2.0 * (q01 * q01 + q02 * q02 + q12 * q12))
        if q00 + q11 < 0:
            nrm = -nrm
        Q[d, 0, 0], Q[d, 1, 1], Q[d, 2, 2] = q00 / nrm, q11 / nrm, q22 / nrm
        Q[d, 0, 1] = Q[d, 1, 0] = q01 / nrm
        Q[d, 0, 2] = Q[d, 2, 0] = q02 / nrm
        Q[d, 1, 2] = Q[d, 2, 1] = q12 / nrm


@njit(cache=True, nogil=True)
def _solve_augmented(L, X):
    """Solves the augmented system ``L = [A | R]`` ((n, n + k): ``A X = R``) by Gaussian elimination with partial
    pivoting, as LAPACK's ``gesv``, writing ``X`` (n, k); ``L`` is overwritten. False (``X`` unwritten) where ``A``
    is singular or not finite."""
    n, w = L.shape
    for c in range(n):
        piv = c
        for r in range(c + 1, n):
            if abs(L[r, c]) > abs(L[piv, c]):
                piv = r
        if not (np.isfinite(L[piv, c]) and L[piv, c] != 0.0):
            return False
        if piv != c:
            for j in range(w):
                L[c, j], L[piv, j] = L[piv, j], L[c, j]
        for r in range(c + 1, n):
            f = L[r, c] / L[c, c]
            for j in range(c, w):
                L[r, j] -= f * L[c, j]
    for j in range(w - n):
        for i in range(n - 1, -1, -1):
            acc = L[i, n + j]
            for k in range(i + 1, n):
                acc -= L[i, k] * X[k, j]
            X[i, j] = acc / L[i, i]
    return True


@njit(cache=True, nogil=True)
def _solve3(A, B, T):
    """Writes ``T = -A^-1 B^T`` for (3, 3) ``A``, ``B`` (:func:`_solve_augmented`); False where ``A`` is singular or
    not finite."""
    L = np.empty((3, 6))
    for i in range(3):
        for j in range(3):
            L[i, j] = A[i, j]
            L[i, 3 + j] = -B[j, i]
    return _solve_augmented(L, T)


@njit(cache=True, nogil=True)
def _refined_eigenvector(M, lam, v0, v1, v2):
    """The eigenvector of the (3, 3) ``M`` near ``(v0, v1, v2)`` for the simple eigenvalue near ``lam``, refined by
    two Newton steps on ``(M - lam I) v = 0, |v| = 1`` (the bordered system ``[[M - lam I, -v], [v^T, 0]]``, solved
    by :func:`_solve_augmented`): the cross product alone is the null vector of ``M - lam I``
    with ``lam`` rounded, ~1e-7 off on a thin ellipse of 2 x 0.2 px; refined, it is the eigenvector of ``M`` to
    rounding, as LAPACK's."""
    n = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    v = np.array([v0 / n, v1 / n, v2 / n])
    B = np.empty((4, 5))
    x = np.empty((4, 1))
    for _ in range(2):
        for i in range(3):
            r = -(M[i, 0] * v[0] + M[i, 1] * v[1] + M[i, 2] * v[2] - lam * v[i])
            for j in range(3):
                B[i, j] = M[i, j] - (lam if i == j else 0.0)
            B[i, 3] = -v[i]
            B[i, 4] = r
        B[3, 0], B[3, 1], B[3, 2], B[3, 3], B[3, 4] = v[0], v[1], v[2], 0.0, 0.0
        if not _solve_augmented(B, x):
            break  # (not a simple eigenvalue: the vector so far stands)
        v[0] += x[0, 0]
        v[1] += x[1, 0]
        v[2] += x[2, 0]
        lam += x[3, 0]
        n = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        v /= n
    return v[0], v[1], v[2]


@njit(cache=True, nogil=True)
def _largest_eigenvalue(M):
    """The largest real eigenvalue of the real (3, 3) matrix ``M``: the largest root of its characteristic cubic
    (trigonometric form when all three roots are real, Cardano's otherwise), polished by two Newton steps."""
    tr = M[0, 0] + M[1, 1] + M[2, 2]
    c2 = (
        (M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0])
        + (M[0, 0] * M[2, 2] - M[0, 2] * M[2, 0])
        + (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
    )
    dt = (
        M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
        - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
        + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0])
    )
    # lam^3 - tr lam^2 + c2 lam - dt = 0; lam = t + tr / 3: t^3 + p t + q = 0
    sh = tr / 3.0
    p = c2 - tr * tr / 3.0
    q = -2.0 * tr * tr * tr / 27.0 + tr * c2 / 3.0 - dt
    if p < 0.0 and 4.0 * p * p * p + 27.0 * q * q <= 0.0:
        r = np.sqrt(-p / 3.0)
        arg = min(1.0, max(-1.0, 3.0 * q / (2.0 * p * r)))
        t = 2.0 * r * np.cos(np.arccos(arg) / 3.0)
    else:
        disc = np.sqrt(max(q * q / 4.0 + p * p * p / 27.0, 0.0))
        t = np.cbrt(-q / 2.0 + disc) + np.cbrt(-q / 2.0 - disc)
    lam = t + sh
    for _ in range(2):
        f = ((lam - tr) * lam + c2) * lam - dt
        g = (3.0 * lam - 2.0 * tr) * lam + c2
        if g != 0.0:
            lam -= f / g
    return lam


@njit(cache=True, nogil=True)
def _normalised_scatter(p: np.ndarray, use: np.ndarray):
    """Halir-Flusser scatter matrices of the points ``p[d][use[d]]`` (D, M, 2) in Hartley-normalised coordinates.

    Returns ``(mean (D, 2), s (D,), S1, S2, S3 (D, 3, 3))``: normalised coordinates are ``(x, y) = s (p - mean)``
    (zero mean, RMS distance sqrt(2) from the origin); with rows ``D1 = (x^2, xy, y^2)`` and ``D2 = (x, y, 1)``,
    ``S1 = D1^T D1``, ``S2 = D1^T D2``, ``S3 = D2^T D2``. Rows without points give zeros.
    """
    D, M = use.shape
    mean = np.zeros((D, 2))
    s = np.ones(D)
    S1 = np.zeros((D, 3, 3))
    S2 = np.zeros((D, 3, 3))
    S3 = np.zeros((D, 3, 3))
    for d in range(D):
        n = 0
        mx = my = 0.0
        for i in range(M):
            if use[d, i]:
                mx += p[d, i, 0]
                my += p[d, i, 1]
                n += 1
        nn = max(n, 1)
        mx /= nn
        my /= nn
        d2 = 0.0
        for i in range(M):
            if use[d, i]:
                d2 += (p[d, i, 0] - mx) ** 2 + (p[d, i, 1] - my) ** 2
        dd = np.sqrt(d2 / nn)
        sc = np.sqrt(2.0) / dd if dd > 0 else 1.0
        mean[d, 0], mean[d, 1], s[d] = mx, my, sc
        # the 15 monomials x^a y^b, a + b <= 4, that the three matrices are made of
        m00 = m10 = m01 = m20 = m11 = m02 = m30 = m21 = m12 = m03 = m40 = m31 = m22 = m13 = m04 = 0.0
        for i in range(M):
            if use[d, i]:
                x = p[d, i, 0] * sc - sc * mx
                y = p[d, i, 1] * sc - sc * my
                xx, xy, yy = x * x, x * y, y * y
                m00 += 1.0
                m10 += x
                m01 += y
                m20 += xx
                m11 += xy
                m02 += yy
                m30 += xx * x
                m21 += xx * y
                m12 += x * yy
                m03 += yy * y
                m40 += xx * xx
                m31 += xx * xy
                m22 += xx * yy
                m13 += xy * yy
                m04 += yy * yy
        S1[d, 0, 0], S1[d, 0, 1], S1[d, 0, 2] = m40, m31, m22
        S1[d, 1, 0], S1[d, 1, 1], S1[d, 1, 2] = m31, m22, m13
        S1[d, 2, 0], S1[d, 2, 1], S1[d, 2, 2] = m22, m13, m04
        S2[d, 0, 0], S2[d, 0, 1], S2[d, 0, 2] = m30, m21, m20
        S2[d, 1, 0], S2[d, 1, 1], S2[d, 1, 2] = m21, m12, m11
        S2[d, 2, 0], S2[d, 2, 1], S2[d, 2, 2] = m12, m03, m02
        S3[d, 0, 0], S3[d, 0, 1], S3[d, 0, 2] = m20, m11, m10
        S3[d, 1, 0], S3[d, 1, 1], S3[d, 1, 2] = m11, m02, m01
        S3[d, 2, 0], S3[d, 2, 1], S3[d, 2, 2] = m10, m01, m00
    return mean, s, S1, S2, S3


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
