"""Plane homographies onto rays: the perspective geometry of a planar board seen by any central camera (a fisheye
beyond 90 deg included), written once for the solver's fisheye start and the detector's centre correction."""
from __future__ import annotations

import numpy as np

__all__ = ["ray_homography", "plane_normal"]


def ray_homography(board_xy: np.ndarray, rays: np.ndarray) -> np.ndarray | None:
    """The homography ``H`` (3, 3) with ``H (X, Y, 1) ~ d`` for board points ``board_xy`` (N, 2) mm (N >= 4) seen
    along rays ``d = rays`` (N, 3) in any direction, with the sign that makes ``H (X, Y, 1)`` point along the rays
    and ``|h1| + |h2| = 2`` (so ``H = [r1 r2 t]`` for a pose when the points are exact). A DLT on the cross product
    ``d x H a = 0`` with the board points Hartley-normalised and the rays made unit. None when the points are
    collinear or coincident (no homography is determined)."""
    a = np.asarray(board_xy, dtype=np.float64).reshape(-1, 2)
    d = np.asarray(rays, dtype=np.float64).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    if len(a) < 4:
        return None
    c = a.mean(axis=0)
    s = np.sqrt(2.0) / max(float(np.mean(np.linalg.norm(a - c, axis=1))), 1e-300)
    T = np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])
    ah = np.column_stack([(a - c) * s, np.ones(len(a))])
    A = np.zeros((2 * len(a), 9))
    A[0::2, 0:3] = d[:, 2:3] * ah
    A[0::2, 6:9] = -d[:, 0:1] * ah
    A[1::2, 3:6] = d[:, 2:3] * ah
    A[1::2, 6:9] = -d[:, 1:2] * ah
    _, sv, Vt = np.linalg.svd(A, full_matrices=False)
    if not np.all(np.isfinite(sv)) or sv[-2] <= 1e-12 * sv[0]:
        return None
    H = Vt[-1].reshape(3, 3) @ T
    if np.sum((np.column_stack([a, np.ones(len(a))]) @ H.T) * d) < 0:
        H = -H
    return 2.0 * H / (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1]))


def plane_normal(H: np.ndarray) -> np.ndarray:
    """(3,) unit normal of the board plane in the camera frame, ``h1 x h2`` of a homography ``H`` (3, 3) board ->
    rays (its sign: the board's +z)."""
    n = np.cross(H[:, 0], H[:, 1])
    return n / np.linalg.norm(n)
