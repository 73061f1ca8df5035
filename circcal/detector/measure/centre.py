"""Projective correction of circle centres: from an imaged circle (an ellipse) to the image of its centre.

Under a perspective map ``H`` (board plane -> undistorted image) a circle images to an ellipse ``E`` (conic matrix),
but the ellipse's centre is not the image of the circle's centre. The image of the centre is the pole of the board's
vanishing line ``l = H^-T (0, 0, 1)^T`` with respect to ``E``: ``c ~ E^-1 l`` (the circle's centre is the pole of
the line at infinity w.r.t. the circle, and poles/polars are preserved by homographies).

Two independent computations are given:

* :func:`pole_centre`: the closed form ``E^-1 l``.
* :func:`tangent_chord_centre`: the classical construction (as in Chen et al. 2023): through a point ``V`` of the
  vanishing line draw secants; on each, the tangents at the two boundary points meet at a point ``P`` and the
  harmonic conjugate ``M`` of ``V`` w.r.t. the two boundary points (the "projective midpoint" of the chord; the plain
  midpoint when ``V`` is at infinity) is found; all ``P`` and ``M`` are collinear (the polar of ``V``). Two such lines
  from two points of the vanishing line are concurrent at the centre's image. Used to cross-check the closed form.

:func:`correct_centres` iterates: homography from the current centres, vanishing line, poles, until stable.
All coordinates are pixels (OpenCV convention).

A fisheye has no global perspective image (beyond 90 deg none exists, and near it the undistorted image stretches
without bound): :func:`correct_centres_on_rays` corrects each dot on a local perspective re-projection instead, a
virtual pinhole camera turned to look along the dot's own ray. There the dot's rim, carried along its rays, is the
exact perspective image of a circle (an ellipse), the board's vanishing line is ``K_v^-T R_k n`` for the board's
normal ``n`` (from the homography of the board onto the centres' rays), and the pole gives the centre's ray, which
the lens model takes back into the image. Exact for any central camera; used for the fisheye.
"""

from __future__ import annotations

import numpy as np

from circcal.detector.measure.ellipse import conic_params, conic_params_batch
from circcal.detector.measure.ellipsefit import FIT_ERRORS, fit_ellipses_direct
from circcal.model import Camera, project_camera, unproject
from circcal.model.rays import plane_normal, ray_homography

__all__ = [
    "vanishing_line",
    "pole_centre",
    "pole_centres",
    "tangent_chord_centre",
    "fit_homography",
    "correct_centres",
    "rotations_to_axis",
    "correct_centres_on_rays",
]


def vanishing_line(H: np.ndarray) -> np.ndarray:
    """The homogeneous vanishing line of the board plane, ``H^-T (0, 0, 1)``.

    Parameters
    ----------
    H : numpy.ndarray
        (3, 3) homography board (mm) -> image (px).

    Returns
    -------
    numpy.ndarray
        (3,) float64: the line ``l`` (points ``x`` px on it: ``l . (x, y, 1) = 0``), up to scale.

    Raises
    ------
    numpy.linalg.LinAlgError
        ``H`` is singular.

    Examples
    --------
    >>> vanishing_line(np.eye(3))  # an affine view: the line at infinity
    array([0., 0., 1.])
    """
    return np.linalg.solve(np.asarray(H, dtype=np.float64).T, np.array([0.0, 0.0, 1.0]))


def _local_frame(Q: np.ndarray) -> np.ndarray:
    """(3, 3) similarity T (local -> pixel) centred on the ellipse with unit = its major semi-axis (conditioning)."""
    c, (a, _), _ = conic_params(Q)
    return np.array([[a, 0.0, c[0]], [0.0, a, c[1]], [0.0, 0.0, 1.0]])


def _local_frames(conics: np.ndarray) -> np.ndarray:
    """(D, 3, 3) similarities T (local -> pixel) centred on each ellipse with unit = its major semi-axis."""
    c, axes, _, ok = conic_params_batch(conics)
    if not np.all(ok):
        raise ValueError(f"conic {int(np.argmin(ok))} is not a real ellipse")
    T = np.zeros((len(c), 3, 3))
    T[:, 0, 0] = T[:, 1, 1] = axes[:, 0]
    T[:, :2, 2] = c
    T[:, 2, 2] = 1.0
    return T


def pole_centre(Q: np.ndarray, line: np.ndarray) -> np.ndarray:
    """The pole of a line with respect to an ellipse: the image of the circle's centre when the line is the board's
    vanishing line.

    Computed in a frame centred on the ellipse for conditioning.

    Parameters
    ----------
    Q : numpy.ndarray
        (3, 3) the ellipse as a conic matrix, px.
    line : numpy.ndarray
        (3,) homogeneous line, px (e.g. :func:`vanishing_line`).

    Returns
    -------
    numpy.ndarray
        (2,) float64 px ``(x, y)``.

    Raises
    ------
    ValueError
        ``Q`` is not a real ellipse.

    Examples
    --------
    >>> Q = np.array([[1.0, 0.0, -10.0], [0.0, 1.0, -20.0], [-10.0, -20.0, 475.0]])  # circle at (10, 20), r 5
    >>> pole_centre(Q, np.array([0.0, 0.0, 1.0]))  # a fronto-parallel board: the ellipse's own centre
    array([10., 20.])
    """
    return pole_centres(np.asarray(Q, dtype=np.float64)[None], line)[0]


def pole_centres(conics: np.ndarray, line: np.ndarray, frames: np.ndarray | None = None) -> np.ndarray:
    """The poles of a line, or of one line per ellipse, with respect to each ellipse (batched :func:`pole_centre`).

    Parameters
    ----------
    conics : numpy.ndarray
        (D, 3, 3) the ellipses as conic matrices, px.
    line : numpy.ndarray
        (3,) one homogeneous line for all, or (D, 3) one per ellipse, px.
    frames : numpy.ndarray or None
        The (D, 3, 3) local frames of the conics when already computed (they do not depend on ``line``).

    Returns
    -------
    numpy.ndarray
        (D, 2) float64 px ``(x, y)``.

    Raises
    ------
    ValueError
        A conic is not a real ellipse (when ``frames`` is None).
    """
    conics = np.asarray(conics, dtype=np.float64)
    T = _local_frames(conics) if frames is None else frames
    return _poles_in_frames(T, T.transpose(0, 2, 1) @ conics @ T, line)


def _poles_in_frames(T: np.ndarray, Ql: np.ndarray, line: np.ndarray) -> np.ndarray:
    """(D, 2) px :func:`pole_centres` from the local frames ``T`` (D, 3, 3) and the conics in them ``Ql = T^T Q T``
    (D, 3, 3), which do not depend on the line (computed once where the line is iterated)."""
    Tt = T.transpose(0, 2, 1)
    line = np.asarray(line, dtype=np.float64)
    ll = Tt @ line if line.ndim == 1 else np.einsum("dij,dj->di", Tt, line)
    p = T @ np.linalg.solve(Ql, ll[..., None])
    return p[:, :2, 0] / p[:, 2:, 0]


def _line_conic(Ql: np.ndarray, p0: np.ndarray, d: np.ndarray) -> tuple[float, float]:
    """Parameters t1 < t2 where ``p0 + t d`` (homogeneous p0 finite, d a direction with d[2] = 0) meets ``Ql``."""
    a = d @ Ql @ d
    b = 2.0 * (p0 @ Ql @ d)
    c = p0 @ Ql @ p0
    disc = b * b - 4.0 * a * c
    if disc <= 0:
        raise ValueError("secant misses the ellipse")
    s = np.sqrt(disc)
    q = -0.5 * (b + np.copysign(s, b))
    t1, t2 = q / a, c / q
    return (t1, t2) if t1 < t2 else (t2, t1)


def tangent_chord_centre(Q: np.ndarray, line: np.ndarray, n_secants: int = 4) -> np.ndarray:
    """The image of the circle's centre by the tangent/chord construction (see the module docstring).

    Two points of ``line`` are taken where it meets the ellipse's two axes; through each, ``n_secants`` secants cross
    the ellipse; per secant the tangent intersection and the harmonic conjugate give two points of the polar line,
    which is fitted through all of them; the two polar lines meet at the result. Used to cross-check
    :func:`pole_centre`.

    Parameters
    ----------
    Q : numpy.ndarray
        (3, 3) the ellipse as a conic matrix, px.
    line : numpy.ndarray
        (3,) the vanishing line, px (may be the line at infinity, (0, 0, 1)).
    n_secants : int
        Secants through each of the two points.

    Returns
    -------
    numpy.ndarray
        (2,) float64 px ``(x, y)``.

    Raises
    ------
    ValueError
        ``Q`` is not a real ellipse, or a secant misses it.
    """
    T = _local_frame(Q)
    Ql = T.T @ Q @ T
    Ql = Ql / np.linalg.norm(Ql)
    ll = T.T @ np.asarray(line, dtype=np.float64)
    _, _, ang = conic_params(Ql)
    axes = [np.array([np.cos(ang), np.sin(ang)]), np.array([-np.sin(ang), np.cos(ang)])]
    polars = []
    for u in axes:
        axis_line = np.cross([0.0, 0.0, 1.0], [u[0], u[1], 0.0])  # line through the local origin along u
        V = np.cross(ll, axis_line)
        V = V / np.linalg.norm(V)
        pts = []
        # secants through V and points spread across the ellipse interior, along the other axis
        w = np.array([-u[1], u[0]])
        for k in range(n_secants):
            off = (k + 0.5) / n_secants - 0.5  # in (-0.5, 0.5): inside the ellipse (axes >= its minor semi-axis)
            scale = 0.9 * min(conic_params(Ql)[1])
            X = np.array([off * scale * w[0], off * scale * w[1], 1.0])
            if abs(V[2]) > 1e-12 * np.linalg.norm(V[:2]):
                Ve = V / V[2]
                d = np.array([Ve[0] - X[0], Ve[1] - X[1], 0.0])
                tv = (1.0, 1.0)  # V = X + 1 * d
            else:
                d = np.array([V[0], V[1], 0.0])
                tv = (1.0, 0.0)  # V at infinity along d
            ta, tb = _line_conic(Ql, X, d)
            A = X + ta * d
            B = X + tb * d
            # tangents at the two boundary points, and where they meet
            P = np.cross(Ql @ A, Ql @ B)
            if abs(P[2]) > 1e-12 * np.linalg.norm(P):
                pts.append(P[:2] / P[2])
            # harmonic conjugate of V w.r.t. A, B on this secant (t in homogeneous form s / w)
            s, wv = tv
            num = s * (ta + tb) - 2.0 * wv * ta * tb
            den = 2.0 * s - wv * (ta + tb)
            if abs(den) > 1e-12:
                pts.append((X + (num / den) * d)[:2])
        pts = np.asarray(pts)
        # total-least-squares line through the points
        m = pts.mean(axis=0)
        _, _, vt = np.linalg.svd(pts - m)
        nrm = vt[-1]
        polars.append(np.array([nrm[0], nrm[1], -nrm @ m]))
    c = T @ np.cross(polars[0], polars[1])
    return c[:2] / c[2]


def fit_homography(board_xy: np.ndarray, image_xy: np.ndarray) -> np.ndarray:
    """The least-squares homography from board points to their images.

    ``cv2.findHomography`` on all points, with OpenCV's Levenberg-Marquardt refinement of the reprojection error.

    Parameters
    ----------
    board_xy : numpy.ndarray
        (N, 2) board coordinates, mm (N >= 4).
    image_xy : numpy.ndarray
        (N, 2) their images, px.

    Returns
    -------
    numpy.ndarray
        (3, 3) float64 homography board -> image.

    Raises
    ------
    ValueError
        The configuration is degenerate (no finite homography).
    """
    import cv2

    H, _ = cv2.findHomography(np.asarray(board_xy, np.float64), np.asarray(image_xy, np.float64), 0)
    if H is None or not np.all(np.isfinite(H)):
        raise ValueError("could not fit a board homography to the centres (degenerate configuration)")
    return H


def correct_centres(
    conics: np.ndarray,
    board_xy: np.ndarray,
    *,
    init: np.ndarray | None = None,
    H0: np.ndarray | None = None,
    max_iter: int = 10,
    tol_px: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """The images of the circle centres from their ellipses, iterating homography and poles until no centre moves
    ``tol_px``.

    The iteration contracts fast (the poles depend on the centres only through the vanishing line: steps of ~1e-2,
    1e-7, 0 px on the paper's views), so after a step below 1e-6 px the centres are within ~4e-7 px of the fixed
    point (tested; one iteration fewer than a 1e-9 px tolerance).

    Parameters
    ----------
    conics : numpy.ndarray
        (N, 3, 3) ellipses (undistorted pixel coordinates), in board order.
    board_xy : numpy.ndarray
        (N, 2) board coordinates of the circle centres, mm.
    init : numpy.ndarray or None
        (N, 2) px starting centres (default: the ellipse centres).
    H0 : numpy.ndarray or None
        (3, 3) :func:`fit_homography` of ``board_xy`` to those starting centres, where the caller has it (the
        detector's lattice check fits it).
    max_iter : int
        Most iterations.
    tol_px : float
        px: the iteration stops after a step that moves no centre this far.

    Returns
    -------
    centres : numpy.ndarray
        (N, 2) float64 px.
    H : numpy.ndarray
        (3, 3) board -> image, fitted to the centres of the last iteration's start, which lie within ``tol_px`` of
        the returned ones (not fitted again to the final step: a step below ``tol_px`` moves ``H``'s images by as
        little), or to the returned centres when ``max_iter`` ran out first.

    Raises
    ------
    ValueError
        A conic is not a real ellipse, or the centres fit no homography (degenerate configuration).
    """
    conics = np.asarray(conics, dtype=np.float64)
    frames = _local_frames(conics)
    local = frames.transpose(0, 2, 1) @ conics @ frames
    c = frames[:, :2, 2].copy() if init is None else np.asarray(init, np.float64).copy()
    H = fit_homography(board_xy, c) if H0 is None else np.asarray(H0, np.float64)
    for _ in range(max_iter):
        line = vanishing_line(H)
        new = _poles_in_frames(frames, local, line)
        step = np.max(np.abs(new - c))
        c = new
        if step < tol_px:
            break
        H = fit_homography(board_xy, c)
    return c, H


def rotations_to_axis(d: np.ndarray) -> np.ndarray:
    """The smallest rotations taking each direction to the optical axis (0, 0, 1).

    ``I + [v]x + [v]x^2 / (1 + c)``, ``v = d x z``, ``c = d . z``.

    Parameters
    ----------
    d : numpy.ndarray
        (K, 3) unit directions, none straight backwards (0, 0, -1).

    Returns
    -------
    numpy.ndarray
        (K, 3, 3) float64 rotations ``R`` with ``R d_k = (0, 0, 1)``.

    Examples
    --------
    >>> R = rotations_to_axis(np.array([[1.0, 0.0, 0.0]]))
    >>> bool(np.allclose(R[0] @ [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]))
    True
    """
    d = np.asarray(d, dtype=np.float64)
    v = np.stack([d[:, 1], -d[:, 0], np.zeros(len(d))], axis=1)
    c = d[:, 2]
    V = np.zeros((len(d), 3, 3))
    V[:, 0, 1], V[:, 0, 2], V[:, 1, 0] = -v[:, 2], v[:, 1], v[:, 2]
    V[:, 1, 2], V[:, 2, 0], V[:, 2, 1] = -v[:, 0], -v[:, 1], v[:, 0]
    return np.eye(3) + V + (V @ V) / (1.0 + c)[:, None, None]


def correct_centres_on_rays(
    edge_points: np.ndarray,
    mask: np.ndarray,
    board_xy: np.ndarray,
    camera: Camera,
    *,
    init: np.ndarray | None = None,
    max_iter: int = 10,
    tol_px: float = 1e-9,
) -> tuple[np.ndarray, np.ndarray]:
    """The images of the circle centres under any lens model, each dot corrected on a local perspective
    re-projection (see the module docstring).

    Iterates: board homography onto the centres' rays, per-dot virtual camera along the centre's ray, ellipse fit
    there, pole of the vanishing line, until no centre moves ``tol_px``.

    Parameters
    ----------
    edge_points : numpy.ndarray
        (K, M, 2) px: each dot's rim points in the observed image (board order).
    mask : numpy.ndarray
        (K, M) bool: the valid ones.
    board_xy : numpy.ndarray
        (K, 2) mm: the dots' board coordinates.
    camera : circcal.model.Camera
        The lens model.
    init : numpy.ndarray or None
        (K, 2) px starting centres (default: the mean of each dot's rim rays).
    max_iter : int
        Most iterations.
    tol_px : float
        px: the iteration stops after a step that moves no centre this far.

    Returns
    -------
    centres : numpy.ndarray
        (K, 2) float64 px in the observed image.
    H : numpy.ndarray
        (3, 3) board -> rays of the final centres.

    Raises
    ------
    ValueError
        A rim point has no ray (beyond the lens model's field), an ellipse cannot be fitted, or the centres fix no
        board plane.
    """
    P = np.asarray(edge_points, dtype=np.float64)
    M = np.asarray(mask, bool)
    E = np.full(P.shape[:2] + (3,), np.nan)
    E[M] = unproject(P[M], camera)
    E /= np.linalg.norm(E, axis=2, keepdims=True)
    if not np.all(np.isfinite(E[M])):
        raise ValueError("a rim point lies beyond the lens model's field (no ray)")
    if init is None:
        d = np.where(M[..., None], E, 0.0).sum(axis=1)
    else:
        d = unproject(np.asarray(init, dtype=np.float64), camera)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = project_camera(d, camera)
    f = float(camera.fx)  # the virtual cameras' focal length: pixel-sized units
    H = None
    for _ in range(max_iter):
        H = ray_homography(board_xy, d)
        if H is None:
            raise ValueError("could not fit a board homography to the centres' rays (degenerate configuration)")
        n = plane_normal(H)
        R = rotations_to_axis(d)
        q = np.einsum("kij,kmj->kmi", R, np.where(M[..., None], E, 0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            x = f * q[..., :2] / q[..., 2:3]
        conics, err = fit_ellipses_direct(x, M & (q[..., 2] > 0))
        if np.any(err):
            raise ValueError(FIT_ERRORS[int(err[np.argmax(err != 0)])])
        ln = R @ n  # the vanishing line, K_v^-T R_k n
        ln[:, :2] /= f
        p = pole_centres(conics, ln)
        new_d = np.einsum("kji,kj->ki", R, np.column_stack([p / f, np.ones(len(p))]))
        new_d /= np.linalg.norm(new_d, axis=1, keepdims=True)
        new_c = project_camera(new_d, camera)
        step = float(np.max(np.abs(new_c - c)))
        c, d = new_c, new_d
        if step < tol_px:
            break
    return c, ray_homography(board_xy, d)
