"""Candidate dots with a lens model's distortion removed: where a camera model is given, the lattice search
(:func:`circcal.detector.locate.recognise.recognise`) runs on the candidates' positions in the ideal pinhole image
of the same camera matrix, where a flat board's dots lie on an exact projective lattice however strong the lens
(the rows of a fisheye's or a wide lens's view bend far beyond what the raw-pixel checks follow).

:func:`undistorted_candidates` maps each candidate's centre through :func:`circcal.model.undistort_pixels` (the one
camera model implementation) and its ellipse (semi-axes, angle, area) through the local Jacobian of that map (central
differences of :data:`JACOBIAN_STEP_PX`): the ellipse of a dot in the undistorted image, which the lattice search
uses to de-skew the local lattice. A candidate whose position has no undistorted image is left out: beyond the
fold of a pinhole model's polynomial, beyond 90 deg off axis or beyond the one-to-one field of a fisheye, or
farther out than :data:`MAX_REACH` (a dot seen a degree short of 90 deg lies hundreds of image widths away). The
test :func:`inside_image` says which lattice positions of the undistorted image lie in the observed image (a
lattice position predicted outside it is not a missing dot).

Pixels: OpenCV's convention; undistorted pixels share the camera matrix of the observed ones.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from circcal.model import Camera, distort_pixels, undistort_pixels

__all__ = ["JACOBIAN_STEP_PX", "MAX_REACH", "inside_image", "undistorted_candidates"]

JACOBIAN_STEP_PX = 0.5
"""Half the span (px, observed image) of the central differences that give the undistortion's local Jacobian at a
candidate's centre (the map is smooth on the scale of a dot; its Jacobian changes by far less across a pixel)."""
MAX_REACH = 10.0
"""Candidates whose undistorted position lies farther from the principal point than this many half-diagonals of
the image are left out: the lattice search's neighbour grid spans the candidates' bounding box, and a few of them
thousands of image widths out (a fisheye's dots just short of 90 deg) would crowd all the others into a few of its
cells. Ten half-diagonals are ~84 deg off axis for a fisheye whose 90 deg lie at the image's short edges."""
ROUND_TRIP_PX = 0.5
"""A position of the undistorted image is in the observed image only when distorting and undistorting it again
returns it to within this (px; or 1e-4 of its distance from the principal point, when more): beyond the fold of a
polynomial the distorted position undistorts to another point."""


def undistorted_candidates(
    centres: np.ndarray, axes: np.ndarray, angle: np.ndarray, area: np.ndarray, camera: Camera
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The candidates in the undistorted image of ``camera`` (module docstring).

    Parameters
    ----------
    centres : ndarray
        (M, 2) px, observed image.
    axes : ndarray
        (M, 2) semi-axes ``(a, b)`` px of each candidate's ellipse, ``a`` along ``angle``.
    angle : ndarray
        (M,) rad, of ``a`` from the image x axis.
    area : ndarray
        (M,) px^2.
    camera : Camera
        The lens model (its image size is the image's).

    Returns
    -------
    keep : ndarray
        (K,) int64 indices of the candidates that have an undistorted image, ascending.
    centres, axes, angle, area : ndarray
        (K, 2) px, (K, 2) px (``a`` along ``angle``), (K,) rad and (K,) px^2 of those candidates, undistorted.
    """
    P = np.asarray(centres, np.float64).reshape(-1, 2)
    M = len(P)
    h = JACOBIAN_STEP_PX
    offsets = np.array([[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    Q = undistort_pixels((P[:, None, :] + offsets[None]).reshape(-1, 2), camera).reshape(M, 5, 2)
    c = np.array([camera.cx, camera.cy])
    reach = MAX_REACH * 0.5 * float(np.hypot(camera.width, camera.height))
    ok = np.all(np.isfinite(Q), axis=(1, 2)) & (np.linalg.norm(Q[:, 0] - c, axis=1) <= reach)
    keep = np.nonzero(ok)[0]
    Q = Q[keep]
    J = np.stack([Q[:, 1] - Q[:, 2], Q[:, 3] - Q[:, 4]], axis=-1) / (2.0 * h)  # (K, 2, 2): columns d/dx, d/dy
    a = np.asarray(axes, np.float64).reshape(-1, 2)[keep]
    t = np.asarray(angle, np.float64).reshape(-1)[keep]
    R = np.stack([np.stack([np.cos(t), -np.sin(t)], -1), np.stack([np.sin(t), np.cos(t)], -1)], axis=1)
    L = J @ R * a[:, None, :]  # maps the unit circle onto the undistorted ellipse: L L^T is its shape
    w, V = np.linalg.eigh(L @ L.transpose(0, 2, 1))  # ascending
    new_axes = np.sqrt(np.maximum(w[:, ::-1], 0.0))
    new_angle = np.arctan2(V[:, 1, 1], V[:, 0, 1])
    new_area = np.asarray(area, np.float64).reshape(-1)[keep] * np.abs(np.linalg.det(J))
    return keep, Q[:, 0], new_axes, new_angle, new_area


def inside_image(camera: Camera) -> Callable[[np.ndarray], np.ndarray]:
    """The test of which positions of ``camera``'s undistorted image lie inside the observed image.

    Parameters
    ----------
    camera : Camera
        The lens model; the observed image is ``camera.width`` x ``camera.height`` px.

    Returns
    -------
    callable
        ``(K, 2)`` undistorted px -> ``(K,)`` bool: the position distorted lies within the observed image's pixel
        centres, and undistorts back to itself (:data:`ROUND_TRIP_PX`); ``False`` for NaN.
    """
    W, H = camera.width, camera.height
    c = np.array([camera.cx, camera.cy])

    def inside(points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, np.float64).reshape(-1, 2)
        d = distort_pixels(p, camera)
        back = undistort_pixels(d, camera)
        tol = np.maximum(ROUND_TRIP_PX, 1e-4 * np.linalg.norm(p - c, axis=1))
        with np.errstate(invalid="ignore"):
            return (
                (d[:, 0] >= 0.0)
                & (d[:, 0] <= W - 1)
                & (d[:, 1] >= 0.0)
                & (d[:, 1] <= H - 1)
                & (np.linalg.norm(back - p, axis=1) <= tol)
            )

    return inside
