"""The direct least-squares ellipse fit: conic matrices (:mod:`circcal.detector.measure.ellipse`) through points.

Fitzgibbon's direct ellipse-specific least squares in the numerically stable form of Halir & Flusser (1998), on
coordinates normalised to zero mean and unit RMS radius (Hartley-style) and mapped back exactly; the batched
:func:`fit_ellipses_direct` (compiled, one ellipse per row, error codes) and the single :func:`fit_ellipse_direct`
that calls it. Pixels: OpenCV's convention (integer coordinates are pixel centres).
"""

from __future__ import annotations

import numpy as np

from circcal.detector.kernels.jit import njit

__all__ = ["FIT_ERRORS", "fit_ellipse_direct", "fit_ellipses_direct"]


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
    >>> from circcal.detector.measure.ellipse import conic_centre
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
