"""The equidistant Kannala-Brandt fisheye of ``cv2.fisheye`` (skew ``alpha`` held 0), written once: value,
Jacobians and the inverse.

A camera-frame point ``P = (X, Y, Z)`` (any direction, behind the camera too) at angle ``theta`` from the optical
axis::

    rho = sqrt(X^2 + Y^2),  theta = atan2(rho, Z)                    (0 .. pi)
    theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
    xd = theta_d X / rho,  yd = theta_d Y / rho                      (on the axis: xd = X/Z, yd = Y/Z)
    u = fx xd + cx,  v = fy yd + cy

``dist = [k1, k2, k3, k4]`` (``cv2.fisheye``'s ``D``). ``cv2.fisheye.projectPoints`` computes ``theta`` as
``atan(r)`` with ``r = |(X, Y)| / Z``: the same for Z > 0 (tested to 1e-9 px); ``atan2`` carries the model past
90 deg, where a 180-deg-plus lens still images points. The model is valid (one-to-one) for ``theta`` up to
:func:`theta_max`, where ``theta_d`` stops increasing, or pi.
"""

from __future__ import annotations

from typing import Literal, overload

import numpy as np

__all__ = ["N_COEFFS", "theta_distort", "theta_max", "fisheye_distort", "fisheye_distort_jacobian", "fisheye_rays"]

N_COEFFS = 4
#: |(X, Y)| below this fraction of |P| counts as on the optical axis (the first-order model is then exact to
#: double precision; cv2.fisheye uses 1e-8 on |(X, Y)| / Z).
_ON_AXIS = 1e-15


def _check(dist: np.ndarray) -> np.ndarray:
    d = np.asarray(dist, dtype=np.float64).ravel()
    if d.size != N_COEFFS:
        raise ValueError(f"a fisheye distortion vector holds 4 coefficients [k1, k2, k3, k4], got {d.size}")
    return d


@overload
def theta_distort(theta: np.ndarray, dist: np.ndarray, derivative: Literal[False] = False) -> np.ndarray: ...
@overload
def theta_distort(theta: np.ndarray, dist: np.ndarray, derivative: Literal[True]) -> tuple[np.ndarray, np.ndarray]: ...


def theta_distort(
    theta: np.ndarray, dist: np.ndarray, derivative: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """The distorted angle ``theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8)``.

    Parameters
    ----------
    theta : ndarray
        Angles from the optical axis, rad (any shape).
    dist : ndarray
        (4,) ``[k1, k2, k3, k4]``.
    derivative : bool
        Also return ``d theta_d / d theta``.

    Returns
    -------
    ndarray or tuple of ndarray
        ``theta_d`` (rad, the shape of ``theta``); with ``derivative`` ``(theta_d, d theta_d / d theta)``.

    Raises
    ------
    ValueError
        ``dist`` not of 4 coefficients.
    """
    k1, k2, k3, k4 = _check(dist)
    t2 = theta * theta
    td: np.ndarray = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    if not derivative:
        return td
    return td, 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))


def theta_max(dist: np.ndarray) -> float:
    """The lens's one-to-one field: the largest angle up to which ``theta_d`` increases.

    Parameters
    ----------
    dist : ndarray
        (4,) ``[k1, k2, k3, k4]``.

    Returns
    -------
    float
        Half angle in rad, <= pi: the first positive root of ``d theta_d / d theta`` (a quartic in theta^2), else pi.

    Raises
    ------
    ValueError
        ``dist`` not of 4 coefficients.
    """
    k1, k2, k3, k4 = _check(dist)
    coeffs = np.array([9.0 * k4, 7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0])  # in u = theta^2, highest power first
    nz = np.flatnonzero(coeffs)
    roots = np.roots(coeffs[nz[0] :]) if nz[0] < 4 else np.zeros(0)
    u = roots.real[(np.abs(roots.imag) <= 1e-12 * np.maximum(1.0, np.abs(roots.real))) & (roots.real > 0)]
    t = np.sqrt(u[u <= np.pi**2])
    return float(t.min()) if t.size else float(np.pi)


def fisheye_distort(P: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Camera-frame points or rays -> distorted normalised coordinates.

    Parameters
    ----------
    P : ndarray
        (N, 3) camera-frame points (mm) or rays, any direction.
    dist : ndarray
        (4,) ``[k1, k2, k3, k4]``.

    Returns
    -------
    ndarray
        (N, 2) ``(xd, yd)`` (pixels are ``fx xd + cx``, ``fy yd + cy``). A point on the optical axis behind the
        camera (theta = pi) has no image: NaN.

    Raises
    ------
    ValueError
        ``dist`` not of 4 coefficients.
    """
    xd: np.ndarray = fisheye_distort_jacobian(P, dist, jacobian=False)[0]
    return xd


def fisheye_distort_jacobian(
    P: np.ndarray, dist: np.ndarray, jacobian: bool = True
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """:func:`fisheye_distort` with derivatives.

    Parameters
    ----------
    P : ndarray
        (N, 3) camera-frame points (mm) or rays.
    dist : ndarray
        (4,) ``[k1, k2, k3, k4]``.
    jacobian : bool
        Compute the Jacobians (default True).

    Returns
    -------
    xd : ndarray
        (N, 2) distorted normalised coordinates.
    J_P : ndarray or None
        (N, 2, 3): d xd / d P (None without ``jacobian``).
    J_d : ndarray or None
        (N, 2, 4): d xd / d [k1, k2, k3, k4] (None without ``jacobian``).

    Raises
    ------
    ValueError
        ``dist`` not of 4 coefficients.
    """
    P = np.asarray(P, dtype=np.float64)
    if not jacobian:
        return _fisheye(P, _check(dist)), None, None
    n = len(P)
    J_P, J_d = np.empty((n, 2, 3)), np.empty((n, 2, 4))
    return _fisheye(P, _check(dist), J_P, J_d), J_P, J_d


def _fisheye(
    P: np.ndarray,
    d: np.ndarray,
    J_P: np.ndarray | None = None,
    J_d: np.ndarray | None = None,
    scale: tuple[float, float] | None = None,
) -> np.ndarray:
    """The model, written once: ``xd`` (N, 2) of camera-frame ``P`` (N, 3); with ``J_P`` (N, 2, 3) and ``J_d``
    (N, 2, 4) given (views of a caller's arrays) also d xd / d P and d xd / d dist written into them, their row 0
    times ``scale[0]`` and row 1 times ``scale[1]`` when ``scale`` is given (the focal lengths: d uv). Every entry
    is one contiguous (N,) product written into its strided place."""
    X, Y, Z = P[:, 0], P[:, 1], P[:, 2]
    rho2 = X * X + Y * Y
    n2 = rho2 + Z * Z
    rho = np.sqrt(rho2)
    axis = rho <= _ON_AXIS * np.sqrt(n2)
    theta = np.arctan2(rho, Z)
    td, dtd = theta_distort(theta, d, True)
    rs = np.where(axis, 1.0, rho)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(axis, np.where(Z > 0, 1.0 / Z, np.nan), td / rs)  # xd = s X, yd = s Y
    xd = np.stack([s * X, s * Y], axis=-1)
    if J_P is None:
        return xd
    if J_d is None:
        raise ValueError("_fisheye: J_P and J_d are given together")
    sx, sy = (None, None) if scale is None else scale

    def put(out: np.ndarray, v: np.ndarray, f: float | None) -> None:
        if f is None:
            out[...] = v
        else:
            np.multiply(v, f, out=out)

    with np.errstate(divide="ignore", invalid="ignore"):
        g = dtd * Z / (rho2 * n2)  # d theta / d (X, Y) = Z (X, Y) / (rho n2); times dtd and / rho
        h = td / (rs * rho2)  # theta_d / rho^3
        put(J_P[:, 0, 0], g * X * X + h * Y * Y, sx)
        gh = (g - h) * X * Y
        put(J_P[:, 0, 1], gh, sx)
        put(J_P[:, 1, 0], gh, sy)
        put(J_P[:, 1, 1], g * Y * Y + h * X * X, sy)
        put(J_P[:, 0, 2], -dtd * X / n2, sx)
        put(J_P[:, 1, 2], -dtd * Y / n2, sy)
    if axis.any():  # the limit on the axis: the pinhole's d (X/Z, Y/Z) / d P
        iz = np.where(Z[axis] > 0, 1.0 / Z[axis], np.nan)
        fx, fy = (1.0, 1.0) if scale is None else scale
        J_P[axis] = 0.0
        J_P[axis, 0, 0] = iz * fx
        J_P[axis, 1, 1] = iz * fy
        J_P[axis, 0, 2] = -X[axis] * iz * iz * fx
        J_P[axis, 1, 2] = -Y[axis] * iz * iz * fy
    ux, uy = np.where(axis, 0.0, X / rs), np.where(axis, 0.0, Y / rs)
    if scale is not None:
        ux, uy = ux * sx, uy * sy
    t2 = theta * theta
    tp = theta * t2  # theta^3, ^5, ^7, ^9: d theta_d / d k_j along (X, Y) / rho
    for j in range(4):
        np.multiply(tp, ux, out=J_d[:, 0, j])
        np.multiply(tp, uy, out=J_d[:, 1, j])
        tp = tp * t2
    return xd


def fisheye_rays(xd: np.ndarray, dist: np.ndarray, *, tol: float = 1e-15, max_iter: int = 100) -> np.ndarray:
    """Distorted normalised coordinates -> unit rays: the inverse of :func:`fisheye_distort`.

    Solves ``theta_d(theta) = |xd|`` for theta in [0, :func:`theta_max`] by Newton's method kept inside a bisection
    bracket (converges for every monotonic polynomial).

    Parameters
    ----------
    xd : ndarray
        (..., 2) distorted normalised coordinates.
    dist : ndarray
        (4,) ``[k1, k2, k3, k4]``.
    tol : float
        Convergence tolerance on theta, rad.
    max_iter : int
        Iterations at most.

    Returns
    -------
    ndarray
        (..., 3) unit rays; NaN beyond the lens's one-to-one field (``|xd| > theta_d(theta_max)``).

    Raises
    ------
    ValueError
        ``dist`` not of 4 coefficients.
    """
    d = _check(dist)
    xd = np.asarray(xd, dtype=np.float64)
    shape = xd.shape[:-1]
    q = xd.reshape(-1, 2)
    target = np.hypot(q[:, 0], q[:, 1])
    tmax = theta_max(d)
    td_max = float(theta_distort(np.array(tmax), d))
    ok = np.isfinite(target) & (target <= td_max)
    lo = np.zeros_like(target)
    hi = np.full_like(target, tmax)
    th = np.where(ok, np.minimum(target, tmax), np.nan)
    active = ok & (target > 0)
    for _ in range(max_iter):
        if not active.any():
            break
        t = th[active]
        f, df = theta_distort(t, d, True)
        f = f - target[active]
        lo_a, hi_a = lo[active], hi[active]
        lo_a = np.where(f < 0, t, lo_a)
        hi_a = np.where(f > 0, t, hi_a)
        with np.errstate(divide="ignore", invalid="ignore"):
            nt = t - f / df
        bad = ~((nt > lo_a) & (nt < hi_a))
        nt = np.where(f == 0, t, np.where(bad, 0.5 * (lo_a + hi_a), nt))
        step = np.abs(nt - t)
        th[active], lo[active], hi[active] = nt, lo_a, hi_a
        idx = np.flatnonzero(active)
        active[idx[(step <= tol * np.maximum(1.0, nt)) | (f == 0)]] = False
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(target > 0, np.sin(th) / np.where(target > 0, target, 1.0), 1.0)
    rays = np.column_stack([q[:, 0] * scale, q[:, 1] * scale, np.cos(th)])
    rays[~ok] = np.nan
    return rays.reshape(shape + (3,))
