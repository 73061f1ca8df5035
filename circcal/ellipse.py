"""Ellipses as conic matrices: the direct least-squares fit and conversions.

A conic is a symmetric (3, 3) matrix ``Q`` with ``x^T Q x = 0`` for homogeneous image points ``x = (u, v, 1)``
(pixels, OpenCV convention: integer coordinates are pixel centres). Every function here works on single conics;
scale and sign of ``Q`` are arbitrary unless stated.

The fit is Fitzgibbon's direct ellipse-specific least squares in the numerically stable form of Halir & Flusser
(1998), on coordinates normalised to zero mean and unit RMS radius (Hartley-style) and mapped back exactly.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "fit_ellipse_direct",
    "conic_from_params",
    "conic_params",
    "conic_center",
    "sample_ellipse",
    "ellipse_normals",
    "transform_conic",
    "algebraic_distance",
]


def _normaliser(points: np.ndarray) -> np.ndarray:
    """(3, 3) similarity N taking ``points`` (M, 2) to zero mean and RMS distance sqrt(2) from the origin."""
    m = points.mean(axis=0)
    d = np.sqrt(np.mean(np.sum((points - m) ** 2, axis=1)))
    s = np.sqrt(2.0) / d if d > 0 else 1.0
    return np.array([[s, 0.0, -s * m[0]], [0.0, s, -s * m[1]], [0.0, 0.0, 1.0]])


def fit_ellipse_direct(points: np.ndarray) -> np.ndarray:
    """Direct least-squares ellipse through ``points`` (M, 2) px, M >= 5 (Halir-Flusser, normalised).

    Minimises the algebraic distance subject to ``4AC - B^2 = 1`` (in normalised coordinates), so the result is
    always an ellipse. Returns the (3, 3) conic in pixel coordinates, scaled to unit Frobenius norm with negative
    value at the centre (``x^T Q x < 0`` inside). Raises ``ValueError`` for fewer than 5 points or degenerate input.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(p) < 5:
        raise ValueError(f"an ellipse fit needs at least 5 points, got {len(p)}")
    if not np.all(np.isfinite(p)):
        raise ValueError("ellipse fit: points contain NaN or inf")
    N = _normaliser(p)
    x = p[:, 0] * N[0, 0] + N[0, 2]
    y = p[:, 1] * N[1, 1] + N[1, 2]
    D1 = np.column_stack([x * x, x * y, y * y])
    D2 = np.column_stack([x, y, np.ones_like(x)])
    S1 = D1.T @ D1
    S2 = D1.T @ D2
    S3 = D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
    except np.linalg.LinAlgError as exc:
        raise ValueError("ellipse fit: points are degenerate (collinear)") from exc
    M = S1 + S2 @ T
    M = np.array([M[2] / 2.0, -M[1], M[0] / 2.0])  # C1^-1 M
    w, v = np.linalg.eig(M)
    v = np.real(v)
    cond = 4.0 * v[0] * v[2] - v[1] ** 2
    ok = np.nonzero(cond > 0)[0]
    if len(ok) == 0:
        raise ValueError("ellipse fit: no elliptic solution (points may lie on a line or hyperbola)")
    a1 = v[:, ok[np.argmin(np.abs(np.real(w[ok])))]]
    a = np.concatenate([a1, T @ a1])
    A, B, C, D, E, F = a
    Qn = np.array([[A, B / 2, D / 2], [B / 2, C, E / 2], [D / 2, E / 2, F]])
    Q = N.T @ Qn @ N
    return _canonical(Q)


def _canonical(Q: np.ndarray) -> np.ndarray:
    """Scale Q to unit Frobenius norm, sign chosen so the upper-left block is positive definite."""
    Q = 0.5 * (Q + Q.T)
    Q = Q / np.linalg.norm(Q)
    if Q[0, 0] + Q[1, 1] < 0:
        Q = -Q
    return Q


def conic_from_params(center: np.ndarray, axes: tuple[float, float], angle: float) -> np.ndarray:
    """Conic of the ellipse with ``center`` (2,) px, semi-axes ``axes = (a, b)`` px, and ``angle`` (radians) of the
    ``a`` axis from the image x axis (towards +y). Returned scaled so that ``x^T Q x = -1`` at the centre."""
    c = np.asarray(center, dtype=np.float64).reshape(2)
    a, b = float(axes[0]), float(axes[1])
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    M = R @ np.diag([1.0 / a ** 2, 1.0 / b ** 2]) @ R.T
    Q = np.empty((3, 3))
    Q[:2, :2] = M
    Q[:2, 2] = Q[2, :2] = -M @ c
    Q[2, 2] = c @ M @ c - 1.0
    return Q


def conic_center(Q: np.ndarray) -> np.ndarray:
    """(2,) centre of an ellipse conic."""
    return np.linalg.solve(Q[:2, :2], -Q[:2, 2])


def conic_params(Q: np.ndarray) -> tuple[np.ndarray, tuple[float, float], float]:
    """Inverse of :func:`conic_from_params`: ``(center (2,), (a, b) with a >= b, angle of a in (-pi/2, pi/2])``.

    Raises ``ValueError`` if ``Q`` is not a real ellipse.
    """
    Q = np.asarray(Q, dtype=np.float64)
    c = conic_center(Q)
    f0 = Q[:2, 2] @ c + Q[2, 2]  # value of x^T Q x at the centre
    M = Q[:2, :2] / -f0
    w, v = np.linalg.eigh(M)
    if not np.all(w > 0):
        raise ValueError("conic is not a real ellipse")
    a, b = 1.0 / np.sqrt(w)  # eigh sorts ascending: smallest eigenvalue -> longest axis (a)
    ang = float(np.arctan2(v[1, 0], v[0, 0]))
    if ang <= -np.pi / 2:
        ang += np.pi
    elif ang > np.pi / 2:
        ang -= np.pi
    return c, (float(a), float(b)), ang


def sample_ellipse(Q: np.ndarray, n: int) -> np.ndarray:
    """(n, 2) points on the ellipse at equally spaced parameter angles."""
    c, (a, b), ang = conic_params(Q)
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    ca, sa = np.cos(ang), np.sin(ang)
    x = a * np.cos(t)
    y = b * np.sin(t)
    return np.column_stack([c[0] + ca * x - sa * y, c[1] + sa * x + ca * y])


def ellipse_normals(Q: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(M, 2) unit outward normals of the conic's level sets at ``points`` (M, 2) (gradient of x^T Q x)."""
    p = np.asarray(points, dtype=np.float64)
    g = p @ Q[:2, :2].T + Q[:2, 2]
    if Q[0, 0] + Q[1, 1] < 0:
        g = -g
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def transform_conic(Q: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Conic of the image of ``Q`` under the point homography ``T`` (3, 3): ``T^-T Q T^-1``."""
    Ti = np.linalg.inv(T)
    return Ti.T @ Q @ Ti


def algebraic_distance(Q: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(M,) ``x^T Q x`` for points (M, 2)."""
    p = np.asarray(points, dtype=np.float64)
    h = np.column_stack([p, np.ones(len(p))])
    return np.einsum("ij,jk,ik->i", h, Q, h)
