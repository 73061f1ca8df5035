"""Plane homographies onto rays: the perspective geometry of a planar board seen by any central camera (a fisheye
beyond 90 deg included), written once for the solver's fisheye start and the detector's centre correction."""

from __future__ import annotations

import numpy as np

__all__ = ["ray_homography", "ray_homographies", "plane_normal"]


def ray_homography(board_xy: np.ndarray, rays: np.ndarray) -> np.ndarray | None:
    """The homography of a planar board onto the rays it is seen along, in any direction.

    ``H (X, Y, 1) ~ d``, with the sign that makes ``H (X, Y, 1)`` point along the rays and ``|h1| + |h2| = 2`` (so
    ``H = [r1 r2 t]`` for a pose when the points are exact). A DLT on the cross product ``d x H a = 0`` with the board
    points Hartley-normalised and the rays made unit (null vector of the normal matrix). :func:`ray_homographies`
    does many views at once.

    Parameters
    ----------
    board_xy : ndarray
        (N, 2) board coordinates, mm, N >= 4.
    rays : ndarray
        (N, 3) ray directions (any length, any direction).

    Returns
    -------
    ndarray or None
        (3, 3); None when the points are collinear or coincident (no homography is determined).
    """
    H = ray_homographies(
        np.asarray(board_xy, dtype=np.float64).reshape(1, -1, 2), np.asarray(rays, dtype=np.float64).reshape(1, -1, 3)
    )[0]
    return None if np.isnan(H[0, 0]) else H


def ray_homographies(board_xy: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """:func:`ray_homography` of V views with N points each, batched.

    Parameters
    ----------
    board_xy : ndarray
        (V, N, 2) board coordinates, mm.
    rays : ndarray
        (V, N, 3) ray directions.

    Returns
    -------
    ndarray
        (V, 3, 3); NaN for a view whose homography is not determined (N < 4, collinear or coincident points).
    """
    a = np.asarray(board_xy, dtype=np.float64)
    d = np.asarray(rays, dtype=np.float64)
    V, N = a.shape[:2]
    out = np.full((V, 3, 3), np.nan)
    if N < 4:
        return out
    d = d / np.linalg.norm(d, axis=2, keepdims=True)
    c = a.mean(axis=1)
    s = np.sqrt(2.0) / np.maximum(np.mean(np.linalg.norm(a - c[:, None], axis=2), axis=1), 1e-300)
    T = np.zeros((V, 3, 3))
    T[:, 0, 0] = T[:, 1, 1] = s
    T[:, :2, 2] = -s[:, None] * c
    T[:, 2, 2] = 1.0
    ah = np.concatenate([(a - c[:, None]) * s[:, None, None], np.ones((V, N, 1))], axis=2)
    A = np.zeros((V, N, 2, 9))
    A[:, :, 0, 0:3] = d[:, :, 2:3] * ah
    A[:, :, 0, 6:9] = -d[:, :, 0:1] * ah
    A[:, :, 1, 3:6] = d[:, :, 2:3] * ah
    A[:, :, 1, 6:9] = -d[:, :, 1:2] * ah
    ok = np.all(np.isfinite(A), axis=(1, 2, 3))
    if not ok.any():
        return out
    # the null vector from the 9x9 normal matrix (batched eigh: ~10x faster than the SVD of (2N, 9); the points are
    # normalised, so squaring the condition number costs ~1e-10 relative in H)
    Ak = A[ok].reshape(-1, 2 * N, 9)
    ev, U = np.linalg.eigh(Ak.transpose(0, 2, 1) @ Ak)
    sv = np.sqrt(np.maximum(ev[:, ::-1], 0.0))  # singular values, largest first
    H = U[:, :, 0].reshape(-1, 3, 3) @ T[ok]
    along = np.sum(
        (np.concatenate([a[ok], np.ones((len(H), N, 1))], axis=2) @ H.transpose(0, 2, 1)) * d[ok], axis=(1, 2)
    )
    H[along < 0] *= -1.0
    H *= (2.0 / (np.linalg.norm(H[:, :, 0], axis=1) + np.linalg.norm(H[:, :, 1], axis=1)))[:, None, None]
    H[sv[:, -2] <= 1e-12 * sv[:, 0]] = np.nan
    out[ok] = H
    return out


def plane_normal(H: np.ndarray) -> np.ndarray:
    """The board plane's unit normal in the camera frame, ``h1 x h2`` of a homography.

    Parameters
    ----------
    H : ndarray
        (3, 3) homography board -> rays (:func:`ray_homography`).

    Returns
    -------
    ndarray
        (3,) unit normal, its sign the board's +z.
    """
    n = np.cross(H[:, 0], H[:, 1])
    unit: np.ndarray = n / np.linalg.norm(n)
    return unit
