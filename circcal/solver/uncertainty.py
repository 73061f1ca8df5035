"""Projection uncertainty as mrcal defines it (``mrcal.projection_uncertainty``, doc/uncertainty.org in dkogan/mrcal):
how far the projection of a fixed point moves when the calibration is repeated with fresh noise, to first order.

A pixel ``q`` is unprojected with the calibrated camera and placed at ``distance`` (mm along the ray), or taken as a
direction (at infinity). There is no fixed frame to hold that point in: the camera frame itself moves with the
intrinsics (an implied rotation), so, as mrcal does, the point is carried into every calibration object's frame
(``p_frame_v = T_v^-1 p``), mapped back through each perturbed pose ``T_v^+``, the results averaged over the views
("mean-frames") and projected through the perturbed intrinsics::

    q^+(b) = project(mean_v T_v^+ p_frame_v, intrinsics^+),   Var(q) = G Var(b) G^T,   G = dq^+/db at b = b*

``b`` is the whole solve state: intrinsics and every board pose (board coordinates, when refined, do not enter q^+
and are marginalised), ``Var(b) = sigma^2 (J^T J)^-1`` (:class:`circcal.solver.covariance.StateCovariance`). At
infinity only the rotations enter (mrcal's rotation-only path). Poses follow :mod:`circcal.model`
(``X_cam = R(rvec) X_board + tvec``, mm); pixels are OpenCV's (integer coordinates are pixel centres).

The standard deviation reported is mrcal's default, the worst direction: the square root of the larger eigenvalue of
the 2x2 covariance (:func:`worst_direction_stdev`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from circcal.errors import InputError
from circcal.model import Camera, project_camera_jacobian, unproject
from circcal.rotation import left_jacobian, rodrigues, rotated_jacobian
from circcal.solver.covariance import StateCovariance

if TYPE_CHECKING:  # annotations only
    from circcal.solver.result import CalibrationResult

__all__ = [
    "projection_state_jacobian",
    "projection_covariance",
    "worst_direction_stdev",
    "projection_stdev",
    "result_projection_stdev",
    "mean_frames_reprojection",
]


def projection_state_jacobian(
    camera: Camera,
    rvecs: np.ndarray,
    tvecs: np.ndarray,
    cov: StateCovariance,
    uv: np.ndarray,
    *,
    distance: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``G = d q^+ / d b`` of the mean-frames reprojection of pixels, split as the state is.

    Parameters
    ----------
    camera : Camera
    rvecs, tvecs : ndarray
        (V, 3) the solve's poses, rad and mm.
    cov : StateCovariance
    uv : ndarray
        (N, 2) px.
    distance : float or None
        mm along each pixel's ray (None: at infinity, rotations only).

    Returns
    -------
    G_global : ndarray
        (N, 2, ng) with respect to the free intrinsics (board coordinates do not enter: zero columns).
    G_pose : ndarray
        (N, 2, V, 6) with respect to every pose (rvec rad, tvec mm). Pixels whose ray cannot be unprojected (beyond
        the lens's fold) give NaN rows.
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    rays = unproject(uv, camera)  # (N, 3), z = 1 (fisheye: unit rays)
    if distance is None:
        p = rays  # a direction
    else:
        if not (np.isfinite(distance) and distance > 0):
            raise InputError(f"distance must be a positive number of mm (or None: infinity), got {distance!r}")
        p = rays / np.linalg.norm(rays, axis=1, keepdims=True) * float(distance)
    _, J_intr, J_p = project_camera_jacobian(p, camera.intrinsics, camera.lens)  # (N,2,4+nd), (N,2,3)
    rv = np.asarray(rvecs, dtype=np.float64).reshape(-1, 3)
    tv = np.asarray(tvecs, dtype=np.float64).reshape(-1, 3)
    V = len(rv)
    if V != cov.n_views:
        raise ValueError(f"{V} poses for a covariance of {cov.n_views} views")
    nf = cov.n_intrinsics
    G_global = np.zeros((len(uv), 2, cov.n_global))
    G_global[:, :, :nf] = J_intr @ cov.intrinsics_map
    G_pose = np.zeros((len(uv), 2, V, 6))
    Jl = left_jacobian(rv)  # (V, 3, 3)
    for v in range(V):
        # p_ref_v = R_v p_frame_v + t_v with p_frame_v fixed: d/d rvec = -[R_v p_frame_v]x J_l, d/d t = I; the
        # rotated point R_v p_frame_v is p - t_v (a direction at infinity: p itself)
        Y = p if distance is None else p - tv[v]
        G_pose[:, :, v, :3] = rotated_jacobian(J_p, Y) @ Jl[v] / V
        if distance is not None:
            G_pose[:, :, v, 3:] = J_p / V
    return G_global, G_pose


def projection_covariance(
    camera: Camera,
    rvecs: np.ndarray,
    tvecs: np.ndarray,
    cov: StateCovariance,
    uv: np.ndarray,
    *,
    distance: float | None = None,
    sigma_px: float | None = None,
) -> np.ndarray:
    """First-order covariance of the projection of pixels (see the module).

    ``sigma^2 G C G^T`` with ``C`` the unit covariance of the whole state (:meth:`StateCovariance.quadratic`).

    Parameters
    ----------
    camera : Camera
    rvecs, tvecs : ndarray
        (V, 3) the solve's poses, rad and mm.
    cov : StateCovariance
    uv : ndarray
        (N, 2) px.
    distance : float or None
        mm along each ray (None: infinity).
    sigma_px : float or None
        Per-coordinate observation noise, px (default: the solve's estimate ``cov.sigma_px``).

    Returns
    -------
    ndarray
        (N, 2, 2) px^2.
    """
    G_global, G_pose = projection_state_jacobian(camera, rvecs, tvecs, cov, uv, distance=distance)
    s = cov.sigma_px if sigma_px is None else float(sigma_px)
    return s * s * cov.quadratic(G_global, G_pose)


def worst_direction_stdev(cov2: np.ndarray) -> np.ndarray:
    """The standard deviation in the worst direction of each 2x2 covariance (mrcal.worst_direction_stdev).

    Parameters
    ----------
    cov2 : ndarray
        (..., 2, 2) px^2.

    Returns
    -------
    ndarray
        (...) px: the square root of the larger eigenvalue.
    """
    a, b, c = cov2[..., 0, 0], cov2[..., 1, 0], cov2[..., 1, 1]
    stdev: np.ndarray = np.sqrt(np.maximum((a + c) / 2 + np.sqrt((a - c) ** 2 / 4 + b * b), 0.0))
    return stdev


def projection_stdev(
    camera: Camera,
    rvecs: np.ndarray,
    tvecs: np.ndarray,
    cov: StateCovariance,
    uv: np.ndarray,
    *,
    distance: float | None = None,
    sigma_px: float | None = None,
) -> np.ndarray:
    """Worst-direction standard deviation of the projection of pixels.

    :func:`projection_covariance` then :func:`worst_direction_stdev`.

    Parameters
    ----------
    camera : Camera
    rvecs, tvecs : ndarray
        (V, 3) rad and mm.
    cov : StateCovariance
    uv : ndarray
        (N, 2) px.
    distance : float or None
        mm along each ray (None: infinity).
    sigma_px : float or None
        Per-coordinate noise, px (default ``cov.sigma_px``).

    Returns
    -------
    ndarray
        (N,) px; NaN where a ray cannot be unprojected.
    """
    return worst_direction_stdev(
        projection_covariance(camera, rvecs, tvecs, cov, uv, distance=distance, sigma_px=sigma_px)
    )


def result_projection_stdev(
    result: CalibrationResult, uv: np.ndarray, *, distance: float | None = None, sigma_px: float | None = None
) -> np.ndarray:
    """:func:`projection_stdev` of a calibration result (its camera, poses and state covariance).

    Parameters
    ----------
    result : CalibrationResult
    uv : ndarray
        (N, 2) px.
    distance : float or None
        mm along each ray (None: infinity).
    sigma_px : float or None
        Per-coordinate noise, px (default: the solve's estimate).

    Returns
    -------
    ndarray
        (N,) px.

    Raises
    ------
    CalibrationError
        The solve has no finite covariance.

    Examples
    --------
    >>> result_projection_stdev(res, np.array([[639.5, 479.5]]), distance=1000.0)  # doctest: +SKIP
    """
    from circcal.errors import CalibrationError

    if result.covariance is None:
        raise CalibrationError(
            "this calibration has no finite covariance (its information matrix was singular): no projection uncertainty"
        )
    return projection_stdev(
        result.camera, result.rvecs, result.tvecs, result.covariance, uv, distance=distance, sigma_px=sigma_px
    )


def mean_frames_reprojection(
    camera0: Camera,
    rvecs0: np.ndarray,
    tvecs0: np.ndarray,
    camera1: Camera,
    rvecs1: np.ndarray,
    tvecs1: np.ndarray,
    uv: np.ndarray,
    *,
    distance: float | None = None,
) -> np.ndarray:
    """The quantity whose spread :func:`projection_covariance` predicts, exactly (not linearised).

    Pixels ``uv`` unprojected with solve 0 to ``distance``, carried into each view's board frame with solve 0's pose,
    back out with solve 1's pose, averaged over the views and projected with ``camera1``. Monte-Carlo studies compare
    its spread over re-solves with the prediction.

    Parameters
    ----------
    camera0, camera1 : Camera
        The two solves' cameras.
    rvecs0, tvecs0, rvecs1, tvecs1 : ndarray
        (V, 3) their poses, rad and mm.
    uv : ndarray
        (N, 2) px.
    distance : float or None
        mm along each ray (None: a direction).

    Returns
    -------
    ndarray
        (N, 2) px; equals ``uv`` when both solves are the same.
    """
    from circcal.model import project_camera

    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    rays = unproject(uv, camera0)
    p = rays if distance is None else rays / np.linalg.norm(rays, axis=1, keepdims=True) * float(distance)
    R0, R1 = rodrigues(np.asarray(rvecs0, float).reshape(-1, 3)), rodrigues(np.asarray(rvecs1, float).reshape(-1, 3))
    t0, t1 = np.asarray(tvecs0, float).reshape(-1, 3), np.asarray(tvecs1, float).reshape(-1, 3)
    acc = np.zeros_like(p)
    for v in range(len(R0)):
        if distance is None:
            acc += (p @ R0[v]) @ R1[v].T  # R1 R0^T p: directions ignore translation
        else:
            acc += ((p - t0[v]) @ R0[v]) @ R1[v].T + t1[v]
    return project_camera(acc / len(R0), camera1)
